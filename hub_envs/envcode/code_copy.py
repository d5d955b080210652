"""The real-file copy of a snapshot's code and assets, per repo@sha, that a published env is imported from (a cache
snapshot holds symlinks, where ``Path(__file__).resolve()`` would land in ``blobs/``).

Example:
    >>> import tempfile, hashlib
    >>> from pathlib import Path
    >>> snap = Path(tempfile.mkdtemp()); (snap / "a.py").write_text("x = 1\\n")
    6
    >>> files = {"a.py": hashlib.sha256(b"x = 1\\n").hexdigest(), "dataset/x": "0" * 64}
    >>> copy = code_copy(snap, files, "user/name", "f" * 40, home=Path(tempfile.mkdtemp()))
    >>> sorted(p.name for p in copy.iterdir()), (copy / "a.py").is_symlink()
    (['a.py'], False)
"""

from __future__ import annotations

import hashlib
import os
import shutil
import uuid
from pathlib import Path

from hub_envs.errors import IntegrityError
from hub_envs.paths import hub_envs_home
from hub_envs.repo.format import CARD_FILE, DATASET_DIR, MEDIA_DIR, is_code_file, safe_text

__all__ = ["code_copy", "code_files"]


def code_files(files: dict[str, str]) -> dict[str, str]:
    """The manifest's files an env's code may read: all but the card and the dataset's and media's data (code a hand-made
    repo placed under ``dataset/`` is code: copied, and imported from its source only).

    Args:
        files: the manifest's ``{path: sha256}``.

    Returns:
        The subset, ``{path: sha256}``.
    """
    generated = (f"{DATASET_DIR}/", f"{MEDIA_DIR}/")
    return {p: h for p, h in files.items() if p != CARD_FILE and (is_code_file(p) or not p.startswith(generated))}


def _matches(folder: Path, files: dict[str, str]) -> bool:
    try:
        present = {p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file() or p.is_symlink()}
        if present != set(files):
            return False
        return all(not (folder / p).is_symlink() and _sha256(folder / p) == h for p, h in files.items())
    except OSError:
        return False


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def code_copy(snapshot: Path, files: dict[str, str], repo_id: str, sha: str, *, home: Path | None = None) -> Path:
    """The folder of real files holding a snapshot's code and assets: made on first use, checked on every use.

    Args:
        snapshot: the verified snapshot folder.
        files: the manifest's ``files``.
        repo_id: the repo (the folder's name).
        sha: the commit (the subfolder's name).
        home: hub-envs' state folder (None: :func:`hub_envs.paths.hub_envs_home`).

    Returns:
        ``<home>/code/models--<user>--<name>/<sha>``.

    Raises:
        IntegrityError: a snapshot file does not have the manifest's sha256 (the snapshot was verified before, so it
            changed since).
    """
    wanted = code_files(files)
    root = (home or hub_envs_home()) / "code" / ("models--" + repo_id.replace("/", "--"))
    target = root / sha
    if target.is_dir() and _matches(target, wanted):
        return target
    root.mkdir(parents=True, exist_ok=True)
    tmp = root / f".{sha}.partial-{uuid.uuid4().hex[:12]}"
    try:
        for rel, expected in sorted(wanted.items()):
            dest = tmp / rel
            dest.parent.mkdir(parents=True, exist_ok=True)
            with open(snapshot / rel, "rb") as src, open(dest, "wb") as out:
                h = hashlib.sha256()
                for block in iter(lambda: src.read(1 << 20), b""):
                    h.update(block)
                    out.write(block)
            if h.hexdigest() != expected:
                raise IntegrityError(
                    f"{repo_id}@{sha}: {safe_text(rel)} in the cached snapshot no longer has the sha256 in the manifest. "
                    f"Load again: the snapshot is downloaded afresh."
                )
        if target.exists() and _matches(target, wanted):  # another loader made it meanwhile (and may be importing it)
            return target
        if target.exists():  # an outdated or tampered copy: replaced whole
            old = root / f".{sha}.old-{uuid.uuid4().hex[:12]}"
            try:
                os.rename(target, old)
            except OSError:
                pass
            shutil.rmtree(old, ignore_errors=True)
        try:
            os.rename(tmp, target)
        except OSError:  # another loader made it first
            if not _matches(target, wanted):
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return target
