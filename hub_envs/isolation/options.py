"""How load_env runs an env's code: the isolation options, on their own so that a load without isolation does
not import the worker machinery (:mod:`~hub_envs.isolation.proxy` and what it imports cost a warm load ~9 ms).

Example:
    >>> from hub_envs.isolation.options import IsolationOptions
    >>> IsolationOptions().isolated, IsolationOptions(isolation="venv", versions="publisher").label
    (False, 'venv+publisher')
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class IsolationOptions:
    """How load_env runs an env's code: ``isolation`` ("none", "process", "venv"),
    ``sandbox`` (implies a worker process), the per-call watchdog ``step_timeout`` (seconds, None: none; a
    sandbox defaults to 60), ``start_timeout`` for a worker to import the env's code, ``restart`` (a fresh
    worker on ``reset()`` after a crash), ``envs_per_worker`` for ``make_vec`` (0: spread over all CPUs but one), and
    the sandbox's resource limits."""

    isolation: str = "none"
    sandbox: bool = False
    step_timeout: float | None = None
    start_timeout: float = 120.0
    restart: bool = False
    envs_per_worker: int = 0
    memory_limit_mb: int = 4096
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
    def call_timeout(self) -> float | None:
        if self.step_timeout is not None:
            return float(self.step_timeout)
        return 60.0 if self.sandbox else None

    def load_kwargs(self) -> dict[str, Any]:
        """The :func:`~hub_envs.load_env` keywords that give these options again (in another process or on another
        machine: a Ray worker loads the env the way the driver did; a venv worker's interpreter is found there).

        >>> IsolationOptions(isolation="process", step_timeout=5.0).load_kwargs()["step_timeout"]
        5.0
        >>> sorted(IsolationOptions(sandbox=True, isolation="process").load_kwargs()["sandbox_limits"])
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
            kwargs["sandbox_limits"] = {
                "memory_mb": self.memory_limit_mb,
                "open_files": self.max_open_files,
                "processes": self.max_processes,
            }
        return kwargs
