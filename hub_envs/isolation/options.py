"""How load_env runs an env's code (:class:`IsolationOptions`), in a module of its own so that a load without
isolation does not import the worker machinery.

Example:
    >>> from hub_envs.isolation.options import IsolationOptions
    >>> IsolationOptions().isolated, IsolationOptions(isolation="venv", versions="publisher").label
    (False, 'venv+publisher')
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

#: the sandbox's memory limit when none is asked for (MB)
DEFAULT_MEMORY_MB = 4096


@dataclass(frozen=True)
class IsolationOptions:
    """How load_env runs an env's code: ``isolation`` ("none", "process", "venv"),
    ``sandbox`` (implies a worker process), the per-call watchdog ``step_timeout`` (seconds, None: none; a
    sandbox defaults to 60), ``start_timeout`` for a worker to import the env's code, ``restart`` (a fresh
    worker on ``reset()`` after a crash), ``envs_per_worker`` for ``make_vec`` (0: spread over all CPUs but one), and
    the sandbox's resource limits (``memory_limit_mb`` None: the default, :data:`DEFAULT_MEMORY_MB`, not asked for:
    where no memory cgroup can be made it covers each process alone instead of being refused)."""

    isolation: str = "none"
    sandbox: bool = False
    step_timeout: float | None = None
    start_timeout: float = 120.0
    restart: bool = False
    envs_per_worker: int = 0
    memory_limit_mb: int | None = None
    max_open_files: int = 256
    max_processes: int = 64
    versions: str = "current"  # "publisher": the venv pins the publisher's recorded versions
    python: str | None = None  # the worker's interpreter (isolation="venv": the venv's), default this one
    pythonpath: str | None = None  # the worker's PYTHONPATH (isolation="venv": only hub-envs), default sys.path

    @property
    def isolated(self) -> bool:
        return self.isolation != "none" or self.sandbox

    @property
    def label(self) -> str:
        """How the code runs, as reports record it: ``none``, ``process``, ``venv``, ``process+sandbox``, ..."""
        return self.isolation + ("+sandbox" if self.sandbox else "") + ("+publisher" if self.versions == "publisher" else "")

    @property
    def memory_mb(self) -> int:
        """The sandbox's memory limit in MB (the one asked for, else the default)."""
        return DEFAULT_MEMORY_MB if self.memory_limit_mb is None else int(self.memory_limit_mb)

    @property
    def call_timeout(self) -> float | None:
        if self.step_timeout is not None:
            return float(self.step_timeout)
        return 60.0 if self.sandbox else None

    def load_kwargs(self) -> dict[str, Any]:
        """The :func:`~hub_envs.load_env` keywords that give these options again (in another process or on another
        machine: a Ray worker loads the env the way the driver did; a venv worker's interpreter is found there).

        >>> IsolationOptions(isolation="process", step_timeout=5.0).load_kwargs()["step_timeout"]
        5.0
        >>> sorted(IsolationOptions(sandbox=True, isolation="process", memory_limit_mb=2048).load_kwargs()["sandbox_limits"])
        ['memory_mb', 'open_files', 'processes']
        """
        kwargs: dict[str, Any] = {
            "isolation": self.isolation,
            "sandbox": self.sandbox,
            "versions": self.versions,
            "step_timeout": self.step_timeout,
            "restart": self.restart,
            "envs_per_worker": self.envs_per_worker,
        }
        if self.sandbox:
            kwargs["sandbox_limits"] = {"open_files": self.max_open_files, "processes": self.max_processes}
            if self.memory_limit_mb is not None:  # asked for: required there too
                kwargs["sandbox_limits"]["memory_mb"] = self.memory_limit_mb
        return kwargs
