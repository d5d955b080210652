"""The check cache: the load checks that passed, remembered under a key of everything their outcome depends on (the
commit's content, the check settings, every installed distribution, hub-envs' own code, the interpreter, the platform).

Example:
    >>> from hub_envs.loading.check_cache import check_key
    >>> len(check_key(owner="u/n@" + "0" * 40, content_digest="0" * 64, requirements=(), settings={"steps": 8}))
    64
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import sys
import tempfile
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from hub_envs.harness.features import FeatureReport
from hub_envs.paths import PACKAGE_DIR, hub_envs_home

CACHE_DIR = "checks"


def recheck_forced() -> bool:
    """Whether ``HUB_ENVS_RECHECK`` (``1``, ``true``, ``yes``) asks every load to run its checks again."""
    return os.environ.get("HUB_ENVS_RECHECK", "").lower() in {"1", "true", "yes"}


def _installed_distributions() -> list[str]:
    """Every ``name-version.dist-info`` on ``sys.path``: all installed packages and versions, from one listdir each."""
    found = []
    for entry in sys.path:
        if not entry or not os.path.isabs(entry):  # the working directory: where you run from must not matter
            continue
        try:
            names = os.listdir(entry)
        except OSError:
            continue
        found += [f"{entry}:{n}" for n in names if n.endswith((".dist-info", ".egg-info"))]
    return sorted(found)


def _checker_source_digest(root: Path | None = None) -> str:
    """All of hub-envs' own code (every ``.py`` file of the package, by path, size, inode, modification and change
    time), so an edited (editable-installed) checker never reuses old verdicts. Derived from the tree, not a
    hand-kept list of the modules that check. The files' stat, not their bytes: reading all the sources on every
    load would cost a warm load a good part of its time, a stat almost nothing. An edit in place sets the change time (which ``utime``,
    ``tar`` and ``cp -p`` cannot set back), an editor's or installer's atomic replace gives a new inode. Not a
    security boundary: whoever can rewrite hub-envs' sources need not fool its check cache."""
    root = root or PACKAGE_DIR
    h = hashlib.sha256(os.fsencode(root))
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = sorted(d for d in dirnames if d != "__pycache__")
        rel = Path(dirpath).relative_to(root).as_posix()
        for name in sorted(filenames):
            if not name.endswith(".py"):
                continue
            try:
                st = os.stat(os.path.join(dirpath, name))
            except OSError:
                continue
            h.update(f"{rel}/{name}\0{st.st_size}\0{st.st_ino}\0{st.st_mtime_ns}\0{st.st_ctime_ns}\n".encode())
    return h.hexdigest()


def machine_identity() -> dict[str, Any]:
    """What, besides the code, its data and its declared requirements, can change a check's outcome: every
    installed package version, hub-envs' own checking code, the interpreter, the OS, libc and CPU architecture.
    A listdir per ``sys.path`` entry and a stat of hub-envs' sources: load_env computes it while it downloads.

    Returns:
        JSON-ready data, part of every check key (:func:`check_key`).
    """
    uname = platform.uname()
    return {
        "distributions": hashlib.sha256("\n".join(_installed_distributions()).encode()).hexdigest(),
        "checker": _checker_source_digest(),
        "python": sys.version,
        "os": [uname.system, uname.release, uname.machine],
        "libc": os.confstr("CS_GNU_LIBC_VERSION") if hasattr(os, "confstr") and "CS_GNU_LIBC_VERSION" in os.confstr_names else "",
    }


def venv_identity(venv: str | os.PathLike) -> dict[str, Any]:
    """What a venv worker's checks run with, besides this process.

    Args:
        venv: the worker's venv folder.

    Returns:
        Digests of the ``*.dist-info`` folders of the venv's site-packages (every package and version it holds, as they
        are now, not as its build record says) and of its ``pyvenv.cfg`` (the Python it was made with).
    """
    root = Path(venv)
    found = []
    for site in sorted(root.glob("lib*/python*/site-packages")):
        try:
            found += [f"{site.relative_to(root)}:{n}" for n in os.listdir(site) if n.endswith((".dist-info", ".egg-info"))]
        except OSError:
            continue
    try:
        cfg = (root / "pyvenv.cfg").read_text(encoding="utf-8", errors="replace")
    except OSError:
        cfg = ""
    return {
        "distributions": hashlib.sha256("\n".join(sorted(found)).encode()).hexdigest(),
        "interpreter": hashlib.sha256(cfg.encode()).hexdigest(),
    }


def environment_identity(requirements: tuple[str, ...] | list[str] = (), machine: dict[str, Any] | None = None) -> dict[str, Any]:
    """The environment part of a check key.

    Args:
        requirements: the env's declared requirements.
        machine: a :func:`machine_identity` computed during this load (None: computed now).

    Returns:
        :func:`machine_identity` with ``requirements``.
    """
    return {**(machine if machine is not None else machine_identity()), "requirements": list(requirements)}


def check_key(
    *, owner: str, content_digest: str, requirements, settings: dict[str, Any], machine: dict[str, Any] | None = None
) -> str:
    """The key a check's result is stored under.

    Args:
        owner: ``user/name@<sha>``.
        content_digest: the manifest's content digest.
        requirements: the env's declared requirements.
        settings: the check settings (steps, seed, fingerprint policy, recorded fingerprint).
        machine: a :func:`machine_identity` computed during this load (None: computed now).

    Returns:
        64 hex digits.
    """
    payload = {
        "owner": owner,
        "content_digest": content_digest,
        "settings": settings,
        "environment": environment_identity(requirements, machine),
    }
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()


def _path(key: str) -> Path:
    return hub_envs_home() / CACHE_DIR / f"{key}.json"


def _body_digest(entry: dict[str, Any]) -> str:
    """sha256 of an entry without its own ``digest`` field (canonical JSON)."""
    body = {k: v for k, v in entry.items() if k != "digest"}
    return hashlib.sha256(json.dumps(body, sort_keys=True, allow_nan=False).encode()).hexdigest()


def _valid(entry: Any, key: str) -> bool:
    """An entry exactly as :func:`store` writes it, for ``key``, recording a passing check: anything
    else (truncated, hand-edited, an older layout, a failing feature report) is a miss."""
    if not isinstance(entry, dict) or entry.get("key") != key:
        return False
    if not (isinstance(entry.get("digest"), str) and entry["digest"] == _body_digest(entry)):
        return False
    if not (isinstance(entry.get("checked_at"), str) and isinstance(entry.get("fingerprint"), str)):
        return False
    if entry["fingerprint"].startswith("DRIFTED"):
        return False

    features = entry.get("features")
    if not isinstance(features, dict) or not isinstance(features.get("rows"), list):
        return False
    if not all(
        isinstance(row, dict)
        and all(isinstance(v, str) for k, v in row.items() if k != "problems")
        and row.get("problems", []) == []
        for row in features["rows"]
    ):
        return False
    try:
        report = FeatureReport.from_dict(features)
    except (KeyError, TypeError, ValueError, AttributeError, OverflowError):
        return False
    return report.ok and features.get("ok") is True


def lookup(key: str) -> dict[str, Any] | None:
    """The stored result for ``key``.

    Missing, unreadable, corrupt or hand-edited entries are misses (the checks run again and the entry is rewritten): an
    entry counts only if it has exactly the shape :func:`store` writes, its own digest matches its content, and it
    records a passing feature report.

    Args:
        key: a :func:`check_key`.

    Returns:
        The result :func:`store` recorded, or None.
    """
    try:
        data = json.loads(_path(key).read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError):
        return None
    try:
        return data if _valid(data, key) else None
    except (RecursionError, ValueError, TypeError):  # nested too deeply, NaN, ...: not what store writes
        return None


def store(key: str, result: dict[str, Any]) -> None:
    """Atomically record a passing result (best effort: a read-only home only costs speed).

    Args:
        key: a :func:`check_key`.
        result: the feature report (``to_dict``) and the fingerprint line; not JSON: never stored.
    """
    path = _path(key)
    entry = {"key": key, "checked_at": datetime.now(UTC).isoformat(timespec="seconds"), **result}
    try:
        entry["digest"] = _body_digest(entry)
    except (TypeError, ValueError):  # not JSON: never stored
        return
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".check-")
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            json.dump(entry, f)
        os.replace(tmp, path)
    except OSError:
        pass
