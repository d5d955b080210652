"""Isolated envs: a hub env's code in its own worker process, optionally sandboxed, behind a normal gym.Env.

``load_env(repo, trust_remote_code=True, isolation="process")`` (or ``sandbox=True``) registers an env
whose ``loaded.make()`` / ``gym.make(loaded.gym_id)`` / ``loaded.make_vec(n)`` run it in worker processes;
the parent never imports the env's code (its config comes from the verified manifest). Isolation does not
replace consent: the trust gate runs first, exactly as in-process.

* :mod:`~hub_envs.isolation.protocol`: the messages between parent and worker;
* :mod:`~hub_envs.isolation.wire`: what a worker sends back (data in msgpack, never a pickle), checked as it is decoded;
* :mod:`~hub_envs.isolation.worker`: the worker process;
* :mod:`~hub_envs.isolation.proxy`: the worker handle, typed faults, :class:`IsolatedEnv`;
* :mod:`~hub_envs.isolation.vector`: :class:`IsolatedVectorEnv` (several envs per worker, shared memory);
* :mod:`~hub_envs.isolation.affinity`: parent and worker wait for each other on one CPU (cheap wake-ups);
* :mod:`~hub_envs.isolation.sandbox`: namespaces, read-only mounts, scrubbed environment, resource limits;
* :mod:`~hub_envs.isolation.venvs`: ``isolation="venv"``: a venv per requirements digest, built with uv
  (``versions="publisher"`` pins the publisher's recorded versions);
* :mod:`~hub_envs.isolation.config`: the isolated env's config, read from the verified manifest;
* :mod:`~hub_envs.isolation.options`: :class:`IsolationOptions` (what a load without isolation imports of all this).

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
