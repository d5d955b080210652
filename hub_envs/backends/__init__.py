"""Where episodes run: this machine's processes (:mod:`~hub_envs.backends.local`) or a Ray cluster
(:mod:`~hub_envs.backends.ray`), both :class:`~hub_envs.backends.base.Backend` s."""

from hub_envs.backends.base import BACKENDS, Backend, EnvSource, LocalBackend, make_backend

__all__ = ["BACKENDS", "Backend", "EnvSource", "LocalBackend", "make_backend"]
