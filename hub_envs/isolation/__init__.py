"""Isolated envs: a hub env's code in worker processes, optionally sandboxed, behind a normal ``gym.Env``.

``load_env(repo, trust_remote_code=True, isolation="process")`` (or ``"venv"``, or ``sandbox=True``) runs the env
this way; the trust gate runs first, exactly as in-process. How the parts fit: ``docs/isolation.md``.

Example:
    >>> from hub_envs.isolation import IsolationOptions
    >>> IsolationOptions(isolation="process").isolated, IsolationOptions(sandbox=True).call_timeout
    (True, 60.0)
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "IsolationOptions": "hub_envs.isolation.options",
    "IsolatedEnv": "hub_envs.isolation.proxy",
    "EnvTarget": "hub_envs.isolation.proxy",
    "Worker": "hub_envs.isolation.proxy",
    "IsolatedVectorEnv": "hub_envs.isolation.vector",
    "sandbox_support": "hub_envs.isolation.sandbox",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'hub_envs.isolation' has no attribute {name!r}")
