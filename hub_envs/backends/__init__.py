"""Where episodes run: this machine's processes (:class:`LocalBackend`) or a Ray cluster
(:class:`~hub_envs.backends.ray.RayBackend`), both :class:`Backend` s.

Example:
    >>> from hub_envs.backends import make_backend
    >>> make_backend("local", workers=2)
    LocalBackend(workers=2)
    >>> make_backend("spark")
    Traceback (most recent call last):
    ...
    hub_envs.errors.ConfigError: backend='spark': choose 'local' (this machine's processes) or 'ray' (a Ray cluster).
"""

from __future__ import annotations

from pathlib import Path

from hub_envs.backends.base import Backend, EnvSource
from hub_envs.backends.local import LocalBackend, default_local_workers
from hub_envs.backends.ray import RayBackend
from hub_envs.errors import ConfigError

__all__ = ["Backend", "LocalBackend", "RayBackend", "EnvSource", "make_backend", "BACKENDS"]

BACKENDS = ("local", "ray")


def make_backend(
    backend: str | Backend = "local",
    *,
    workers: int | None = None,
    ray_address: str | None = None,
    checkpoint_dir: str | Path | None = None,
) -> Backend:
    """The backend named by ``backend`` (``"local"`` or ``"ray"``), or ``backend`` itself if it is one.

    Args:
        workers: processes (local; default up to 2) or Ray actors (default: the cluster's CPUs).
        ray_address: the Ray cluster (``host:port`` or ``ray://host:port``); default ``$RAY_ADDRESS`` if set,
            else a local Ray started for the run and stopped after it. Ray only.
        checkpoint_dir: where a Ray run keeps its finished shards; the same run started again skips them.

    Returns:
        A :class:`LocalBackend` or a :class:`~hub_envs.backends.ray.RayBackend` (not connected yet: ``with backend:``
        keeps one connection for several runs).

    Raises:
        ConfigError: an unknown backend, or a Ray setting for the local one.
        MissingRequirementsError: ``"ray"`` without Ray installed (``pip install 'hub-envs[ray]'``).
    """
    if isinstance(backend, Backend):
        return backend
    if backend == "local":
        if ray_address is not None:
            raise ConfigError(f"ray_address={ray_address!r} is for --backend=ray; drop it or pass --backend=ray.")
        return LocalBackend(workers=int(workers) if workers else default_local_workers())
    if backend == "ray":
        return RayBackend(address=ray_address, workers=workers, checkpoint_dir=checkpoint_dir)
    raise ConfigError(f"backend={backend!r}: choose 'local' (this machine's processes) or 'ray' (a Ray cluster).")
