"""The flags every command that loads an env shares: which env, the consent to run its code, and how it runs."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass
class CodeFlags:
    """The consent to run an env repo's code, and how it runs (``hub-envs diff`` loads two, so has no ``--repo_id``)."""

    trust_remote_code: bool = False  # consent to run the env repo's code (or once for all: hub-envs trust user/name@<sha>)
    isolation: str = "none"  # "process": the env's code runs in worker processes; "venv": in a venv built from its requirements
    sandbox: bool = False  # the workers in a sandbox (no network, read-only files, no secrets, limits)
    versions: str = "current"  # "publisher" (with --isolation=venv): the publisher's recorded package versions
    step_timeout: float | None = None  # seconds a call into an isolated env may take (sandbox default 60)


@dataclass
class EnvFlags(CodeFlags):
    """Which env (``--repo_id``, ``--revision``), the consent to run its code, and how it runs."""

    repo_id: str | None = None  # the env: user/name[@revision], or a local folder (./path); may come first, without the flag
    revision: str | None = None  # branch, tag or commit sha of --repo_id (overrides its @revision); pin a sha to get exactly it


def code_run(flags: CodeFlags) -> dict[str, Any]:
    """How the env's code runs, as :func:`hub_envs.load_env` and the operations take it (``**run``: a
    :class:`~hub_envs.loading.isolated.CodeRun`).

    >>> code_run(EnvFlags(repo_id="user/name", isolation="process"))
    {'isolation': 'process', 'sandbox': False, 'versions': 'current', 'step_timeout': None}
    """
    return {
        "isolation": flags.isolation,
        "sandbox": flags.sandbox,
        "versions": flags.versions,
        "step_timeout": flags.step_timeout,
    }
