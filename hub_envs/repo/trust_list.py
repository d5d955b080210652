"""Trust on first use: the local list of the commits, each bound to its content digest, whose code the user agreed to
run (``hub-envs trust user/name@<sha>``).

Example:
    >>> import os, tempfile
    >>> os.environ["HUB_ENVS_HOME"] = tempfile.mkdtemp()
    >>> from hub_envs.repo.trust_list import read_trust_list, trust
    >>> trust("user/pendulum", "a" * 40, content_digest="b" * 64)
    >>> read_trust_list().covers("user/pendulum", "a" * 40, "b" * 64)
    True
    >>> read_trust_list().covers("user/pendulum", "a" * 40, "c" * 64)   # other content under the same sha
    False

From the shell: ``hub-envs trust user/pendulum-lerobot@<sha>``.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import re
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from hub_envs.errors import ConfigError, EnvRepoNotFoundError
from hub_envs.paths import hub_envs_home, legacy_hub_envs_home
from hub_envs.repo.format import Manifest, content_digest, hash_files, is_commit_sha
from hub_envs.repo.refs import check_repo_id, parse_repo_ref

TRUST_FILE = "trusted.json"
FORMAT = 2
#: a manifest content digest: 64 lowercase hex digits
DIGEST_RE = re.compile(r"[0-9a-f]{64}")


def _hub_io():
    """:mod:`hub_envs.repo.hub_io`, imported when the Hub is asked (reading the trust list does not): it installs its
    endpoint check on huggingface_hub's client before any request."""
    from hub_envs.repo import hub_io  # heavy: huggingface_hub's client and its HTTP stack (httpx or requests)

    return hub_io


def trust_file() -> Path:
    """The trust list's file: ``trusted.json`` in :func:`hub_envs.paths.hub_envs_home`."""
    return hub_envs_home() / TRUST_FILE


@dataclass(frozen=True)
class TrustEntry:
    """Consent to run ``repo_id`` at commit ``sha`` whose manifest has ``content_digest``."""

    repo_id: str
    sha: str
    content_digest: str
    trusted_at: str


@dataclass(frozen=True)
class TrustList:
    """The trust list as read at one moment: decisions use this copy, never a later re-read."""

    entries: tuple[TrustEntry, ...]
    path: Path

    def covers(self, repo_id: str, sha: str, content_digest: str) -> bool:
        """Whether an entry names exactly this repo, commit and content.

        Args:
            repo_id: the repo.
            sha: the commit.
            content_digest: the content digest.

        Returns:
            True when one does.
        """
        return any(e.repo_id == repo_id and e.sha == sha and e.content_digest == content_digest for e in self.entries)

    def previous(self, repo_id: str) -> list[TrustEntry]:
        """The entries of ``repo_id``, oldest first.

        Args:
            repo_id: a repo.

        Returns:
            Its :class:`TrustEntry` s.
        """
        return sorted((e for e in self.entries if e.repo_id == repo_id), key=lambda e: e.trusted_at)


def _parse(data: object, path: Path) -> list[TrustEntry]:
    bad = ConfigError(
        f"The trust list {path} is not in the format hub-envs writes. Fix or delete it, then trust repos again "
        f"(hub-envs trust user/name@<sha>)."
    )
    if not isinstance(data, dict) or data.get("format") != FORMAT or not isinstance(data.get("entries"), dict):
        raise bad
    out = []
    for repo_id, shas in data["entries"].items():
        if not isinstance(shas, dict):
            raise bad
        for sha, entry in shas.items():
            if not (
                is_commit_sha(sha)
                and isinstance(entry, dict)
                and isinstance(entry.get("content_digest"), str)
                and DIGEST_RE.fullmatch(entry["content_digest"])
            ):
                raise bad
            out.append(TrustEntry(str(repo_id), sha, entry["content_digest"], str(entry.get("trusted_at", ""))))
    return out


def _load(path: Path) -> list[TrustEntry]:
    if not path.is_file():
        return []
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError, RecursionError):
        raise ConfigError(f"The trust list {path} is not valid JSON. Fix or delete it, then trust repos again.") from None
    return _parse(data, path)


def read_trust_list() -> TrustList:
    """The trust list now (an empty one when there is no file yet)."""
    path = trust_file()
    return TrustList(tuple(_load(path)), path)


def legacy_trusted(repo_id: str, sha: str) -> bool:
    """Whether an older hub-envs (sha-only entries, kept under ``$HF_HOME/hub_envs``) trusted ``repo_id@sha``: never
    honoured, only said (consent must now bind the content too).

    Args:
        repo_id: the repo.
        sha: the commit.

    Returns:
        True when such an entry exists.
    """
    path = legacy_hub_envs_home() / TRUST_FILE
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError, RecursionError):
        return False
    entry = data.get(repo_id) if isinstance(data, dict) else None
    return isinstance(entry, dict) and sha in entry


@contextlib.contextmanager
def _locked() -> Iterator[Path]:
    path = trust_file()
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path.parent / f".{TRUST_FILE}.lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield path
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def _write(path: Path, entries: list[TrustEntry]) -> None:
    data: dict = {"format": FORMAT, "entries": {}}
    for e in entries:
        data["entries"].setdefault(e.repo_id, {})[e.sha] = {"content_digest": e.content_digest, "trusted_at": e.trusted_at}
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".trusted-")
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        json.dump(data, f, indent=2, sort_keys=True)
    os.replace(tmp, path)


def manifest_digest(repo_id: str, sha: str, *, token: str | None = None) -> str:
    """The content digest the manifest of ``repo_id@sha`` records (read from the cache, else the Hub).

    Args:
        repo_id: the env repo.
        sha: the commit.
        token: the Hub token.

    Returns:
        64 hex digits.

    Raises:
        EnvRepoNotFoundError: the commit has no manifest.
        ManifestError: the manifest cannot be read.
    """
    return Manifest.from_json(
        _hub_io().read_manifest_text(repo_id, sha, token=token), where=f"{repo_id}@{sha}: hub_env.json"
    ).content_digest


def snapshot_digest(path: Path) -> str:
    """The content digest of a downloaded snapshot that has no manifest (a policy checkpoint): sha256 over the sha256 of
    every file it holds, as a manifest's ``content_digest`` is over the files it lists.

    Args:
        path: the snapshot folder.

    Returns:
        64 hex digits.
    """
    files = sorted(p.relative_to(path).as_posix() for p in path.rglob("*") if p.is_file() and p.name != ".gitattributes")
    return content_digest(hash_files(path, files))


def commit_digest(repo_id: str, sha: str, *, token: str | None = None) -> str:
    """What consent to ``repo_id@sha`` binds: its manifest's content digest (an env repo), else the digest of the files of
    the commit (any other repo, e.g. a LeRobot policy a benchmark names).

    Args:
        repo_id: the repo.
        sha: the commit.
        token: the Hub token.

    Returns:
        64 hex digits.

    Raises:
        EnvRepoNotFoundError, HubError: the repo or commit cannot be read.
    """
    try:
        return manifest_digest(repo_id, sha, token=token)
    except EnvRepoNotFoundError as e:
        if "has no hub_env.json" not in str(e):
            raise

    hub_io = _hub_io()
    from huggingface_hub import snapshot_download  # heavy: huggingface_hub's client (hub_io installed its endpoint check)

    with hub_io.translate_hub_errors(repo_id, sha):
        return snapshot_digest(Path(snapshot_download(repo_id, revision=sha, token=token)))


def trust(repo_id: str, sha: str, *, content_digest: str | None = None, token: str | None = None) -> None:
    """Record consent to run the code of ``repo_id`` at commit ``sha``, bound to its content digest.

    Args:
        repo_id: the repo.
        sha: the commit (40 hex).
        content_digest: what the consent covers; None: the one the commit's manifest records (read from the local cache
            when load_env already fetched it, which is what you looked at, else from the Hub), or, for a repo without a
            manifest (a policy checkpoint), the digest of the commit's files (:func:`commit_digest`).
        token: the Hub token.

    Raises:
        ConfigError: ``sha`` is not a commit sha, a digest is malformed, or ``repo_id`` is no repo id.
    """

    repo_id, _ = parse_repo_ref(repo_id)
    if not is_commit_sha(sha):
        raise ConfigError(
            f"Trust is given to an exact commit, not {sha!r}. Resolve it first, e.g. "
            f"`hub-envs trust {repo_id}@<40-hex sha>` (load_env prints the sha it resolved)."
        )
    digest = content_digest if content_digest is not None else commit_digest(repo_id, sha, token=token)
    if not DIGEST_RE.fullmatch(digest):
        raise ConfigError(f"content_digest {digest!r} is not a sha256 hex digest.")
    with _locked() as path:
        entries = [e for e in _load(path) if not (e.repo_id == repo_id and e.sha == sha)]
        entries.append(TrustEntry(repo_id, sha, digest, datetime.now(UTC).isoformat()))
        _write(path, entries)


def untrust(repo_id: str, sha: str | None = None) -> int:
    """Withdraw consent for one commit, or for every commit of a repo.

    Args:
        repo_id: the repo.
        sha: the commit (None: every commit).

    Returns:
        How many entries were removed.

    Raises:
        ConfigError: ``repo_id`` is no repo id.
    """

    check_repo_id(repo_id)  # a mistyped id would remove nothing and say so as if it were done
    with _locked() as path:
        entries = _load(path)
        keep = [e for e in entries if not (e.repo_id == repo_id and (sha is None or e.sha == sha))]
        _write(path, keep)
    return len(entries) - len(keep)


def is_trusted(repo_id: str, sha: str, content_digest: str | None = None) -> bool:
    """Whether ``repo_id@sha``, with that content, is in the trust list.

    Args:
        repo_id: the repo.
        sha: the commit.
        content_digest: the content (None: the one its manifest records).

    Returns:
        True when an entry covers it.

    Raises:
        ConfigError: ``repo_id`` is no repo id.
    """

    check_repo_id(repo_id)
    digest = content_digest if content_digest is not None else commit_digest(repo_id, sha)
    return read_trust_list().covers(repo_id, sha, digest)
