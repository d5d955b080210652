"""The command-line flags every command that loads an env shares (``hub-envs load``, ``hub-envs reproduce``).

A light module (no lerobot, no torch): the CLI's ``--help`` imports it.

    >>> flags = EnvFlags(repo_id="user/name", isolation="process")
    >>> flags.load_kwargs()["isolation"], flags.load_kwargs()["trust_remote_code"]
    ('process', False)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass
class EnvFlags:
    """Which env (``--repo_id``, ``--revision``), the consent to run its code, and how it runs."""

    repo_id: str | None = None
    revision: str | None = None
    trust_remote_code: bool = False
    isolation: str = "none"  # "process": the env's code runs in worker processes; "venv": in a venv built from its requirements
    sandbox: bool = False  # the workers in a sandbox (no network, read-only files, no secrets, limits)
    versions: str = "current"  # "publisher" (with --isolation=venv): the publisher's recorded package versions
    step_timeout: float | None = None  # seconds a call into an isolated env may take (sandbox default 60)

    def load_kwargs(self) -> dict[str, Any]:
        """The keyword arguments of ``load_env`` / ``reproduce`` these flags give (all but ``repo_id``)."""
        return {
            "revision": self.revision,
            "trust_remote_code": self.trust_remote_code,
            "isolation": self.isolation,
            "sandbox": self.sandbox,
            "versions": self.versions,
            "step_timeout": self.step_timeout,
        }
