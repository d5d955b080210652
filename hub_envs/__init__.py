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
    "load_env": "hub_envs.load",
    "LoadedEnv": "hub_envs.load",
    "LoadReport": "hub_envs.load",
    "push_env": "hub_envs.push",
    "PushResult": "hub_envs.push",
    "trust": "hub_envs.trust_list",
    "untrust": "hub_envs.trust_list",
    "is_trusted": "hub_envs.trust_list",
    "Manifest": "hub_envs.repo_format",
    "reproduce": "hub_envs.reproduction",
    "evaluate": "hub_envs.evaluation",
    "EvalResult": "hub_envs.evaluation",
    "make_backend": "hub_envs.backends",
    "diff": "hub_envs.revision_diff",
    "DiffReport": "hub_envs.revision_diff",
    "compare": "hub_envs.policy_compare",
    "CompareReport": "hub_envs.policy_compare",
    "attest": "hub_envs.attestation",
    "Attestation": "hub_envs.attestation",
    "env_from_dataset": "hub_envs.from_dataset",
    "IsolationOptions": "hub_envs.isolation.options",
    "IsolatedEnv": "hub_envs.isolation.proxy",
    "IsolatedVectorEnv": "hub_envs.isolation.vector",
    "sandbox_support": "hub_envs.isolation.sandbox",
}

__all__ = sorted(_EXPORTS) + ["errors", "__version__"]

if TYPE_CHECKING:  # pragma: no cover
    from hub_envs.attestation import Attestation, attest  # noqa: F401
    from hub_envs.backends import make_backend  # noqa: F401
    from hub_envs.evaluation import EvalResult, evaluate  # noqa: F401
    from hub_envs.from_dataset import env_from_dataset  # noqa: F401
    from hub_envs.isolation.options import IsolationOptions  # noqa: F401
    from hub_envs.isolation.proxy import IsolatedEnv  # noqa: F401
    from hub_envs.isolation.sandbox import sandbox_support  # noqa: F401
    from hub_envs.isolation.vector import IsolatedVectorEnv  # noqa: F401
    from hub_envs.load import LoadedEnv, LoadReport, load_env  # noqa: F401
    from hub_envs.policy_compare import CompareReport, compare  # noqa: F401
    from hub_envs.push import PushResult, push_env  # noqa: F401
    from hub_envs.repo_format import Manifest  # noqa: F401
    from hub_envs.reproduction import reproduce  # noqa: F401
    from hub_envs.revision_diff import DiffReport, diff  # noqa: F401
    from hub_envs.trust_list import is_trusted, trust, untrust  # noqa: F401


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    if name == "errors":
        return importlib.import_module("hub_envs.errors")
    raise AttributeError(f"module 'hub_envs' has no attribute {name!r}")
