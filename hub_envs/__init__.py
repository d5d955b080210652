"""hub-envs: share simulation environments on the Hugging Face Hub and reproduce results from them.

    >>> from hub_envs import load_env, push_env                                   # doctest: +SKIP
    >>> push_env("envs/pendulum", "user/pendulum-lerobot")                         # doctest: +SKIP
    >>> loaded = load_env("user/pendulum-lerobot@<sha>", trust_remote_code=True)   # doctest: +SKIP
    >>> env = loaded.make()                                                        # doctest: +SKIP

The public API is re-exported here and imported lazily, so ``hub-envs serve`` starts without
importing lerobot or torch.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from hub_envs._version import __version__

_EXPORTS = {
    "load_env": "hub_envs.loading.load",
    "LoadedEnv": "hub_envs.loading.loaded",
    "LoadReport": "hub_envs.loading.loaded",
    "push_env": "hub_envs.publishing.push",
    "PushResult": "hub_envs.publishing.push",
    "trust": "hub_envs.repo.trust_list",
    "untrust": "hub_envs.repo.trust_list",
    "is_trusted": "hub_envs.repo.trust_list",
    "Manifest": "hub_envs.repo.format",
    "reproduce": "hub_envs.operations.reproduce",
    "evaluate": "hub_envs.operations.evaluate",
    "EvalResult": "hub_envs.operations.evaluate",
    "make_backend": "hub_envs.backends",
    "diff": "hub_envs.operations.diff",
    "DiffReport": "hub_envs.operations.diff",
    "compare": "hub_envs.operations.compare",
    "CompareReport": "hub_envs.operations.compare",
    "attest": "hub_envs.operations.attest",
    "Attestation": "hub_envs.repo.attestations",
    "env_from_dataset": "hub_envs.operations.from_dataset",
    "audit": "hub_envs.loading.audit",
    "AuditReport": "hub_envs.loading.audit",
    "adopt": "hub_envs.publishing.adopt",
    "IsolationOptions": "hub_envs.isolation.options",
    "IsolatedEnv": "hub_envs.isolation.proxy",
    "IsolatedVectorEnv": "hub_envs.isolation.vector",
    "sandbox_support": "hub_envs.isolation.sandbox",
}

__all__ = sorted(_EXPORTS) + ["errors", "__version__"]

if TYPE_CHECKING:  # pragma: no cover
    from hub_envs.backends import make_backend  # noqa: F401
    from hub_envs.isolation.options import IsolationOptions  # noqa: F401
    from hub_envs.isolation.proxy import IsolatedEnv  # noqa: F401
    from hub_envs.isolation.sandbox import sandbox_support  # noqa: F401
    from hub_envs.isolation.vector import IsolatedVectorEnv  # noqa: F401
    from hub_envs.loading.audit import AuditReport, audit  # noqa: F401
    from hub_envs.loading.load import load_env  # noqa: F401
    from hub_envs.loading.loaded import LoadedEnv, LoadReport  # noqa: F401
    from hub_envs.operations.attest import attest  # noqa: F401
    from hub_envs.operations.compare import CompareReport, compare  # noqa: F401
    from hub_envs.operations.diff import DiffReport, diff  # noqa: F401
    from hub_envs.operations.evaluate import EvalResult, evaluate  # noqa: F401
    from hub_envs.operations.from_dataset import env_from_dataset  # noqa: F401
    from hub_envs.operations.reproduce import reproduce  # noqa: F401
    from hub_envs.publishing.adopt import adopt  # noqa: F401
    from hub_envs.publishing.push import PushResult, push_env  # noqa: F401
    from hub_envs.repo.attestations import Attestation  # noqa: F401
    from hub_envs.repo.format import Manifest  # noqa: F401
    from hub_envs.repo.trust_list import is_trusted, trust, untrust  # noqa: F401


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    if name == "errors":
        return importlib.import_module("hub_envs.errors")
    raise AttributeError(f"module 'hub_envs' has no attribute {name!r}")
