"""Trust on first use: the local list of ``repo@sha`` whose code the user agreed to run.

Consent is keyed by the exact commit sha, never by a branch: trusting ``user/env@<sha1>`` says
nothing about ``<sha2>``. The list is a JSON file under :func:`hub_envs.paths.hub_envs_home`.

Example:
    >>> from hub_envs.trust import trust, is_trusted
    >>> trust("user/pendulum-lerobot", "0" * 40)                      # doctest: +SKIP
    >>> is_trusted("user/pendulum-lerobot", "0" * 40)                 # doctest: +SKIP
    True

From the shell: ``hub-envs trust user/pendulum-lerobot@<sha>``.
"""

from __future__ import annotations

import json
import os
import tempfile
from datetime import datetime, timezone
from pathlib import Path

from hub_envs.errors import ConfigError
from hub_envs.paths import hub_envs_home
from hub_envs.repo_format import is_commit_sha

TRUST_FILE = "trusted.json"


def trust_file() -> Path:
    return hub_envs_home() / TRUST_FILE


def _read() -> dict[str, dict[str, str]]:
    path = trust_file()
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError):
        raise ConfigError(f"The trust list {path} is not valid JSON. Fix or delete it, then trust repos again.") from None
    if not isinstance(data, dict):
        raise ConfigError(f"The trust list {path} must be a JSON object. Fix or delete it.")
    return data


def _write(data: dict) -> None:
    path = trust_file()
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".trusted-")
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        json.dump(data, f, indent=2, sort_keys=True)
    os.replace(tmp, path)


def _check_sha(repo_id: str, sha: str) -> None:
    if not is_commit_sha(sha):
        raise ConfigError(
            f"Trust is given to an exact commit, not {sha!r}. Resolve it first, e.g. "
            f"`hub-envs trust {repo_id}@<40-hex sha>` (load_env prints the sha it resolved)."
        )


def is_trusted(repo_id: str, sha: str) -> bool:
    return sha in _read().get(repo_id, {})


def trusted_revisions(repo_id: str) -> list[str]:
    """The shas of ``repo_id`` trusted before, oldest first."""
    entries = _read().get(repo_id, {})
    return sorted(entries, key=lambda s: entries[s])


def trust(repo_id: str, sha: str) -> None:
    """Record consent to run the code of ``repo_id`` at commit ``sha``."""
    _check_sha(repo_id, sha)
    data = _read()
    data.setdefault(repo_id, {})[sha] = datetime.now(timezone.utc).isoformat()
    _write(data)


def untrust(repo_id: str, sha: str | None = None) -> int:
    """Withdraw consent for one sha (or every sha when ``sha`` is None). Returns how many were removed."""
    data = _read()
    entries = data.get(repo_id, {})
    removed = len(entries) if sha is None else int(sha in entries)
    if sha is None:
        data.pop(repo_id, None)
    else:
        entries.pop(sha, None)
        if not entries:
            data.pop(repo_id, None)
    _write(data)
    return removed
