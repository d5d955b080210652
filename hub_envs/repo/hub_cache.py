"""The Hugging Face cache as hub-envs reads it without the Hub client: where a repo's snapshots live, a pinned commit
already there (:func:`cached_snapshot`), a snapshot's layout. Only ``huggingface_hub.constants`` (milliseconds) is
imported: a load served from the cache never imports the client's HTTP stack; :mod:`hub_envs.repo.hub_io`, which talks
to the Hub, re-exports all of this.

Example:
    >>> from pathlib import Path
    >>> cache_snapshots_dir("alice/tiny", "/c")
    PosixPath('/c/models--alice--tiny/snapshots')
"""

from __future__ import annotations

import concurrent.futures
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

from huggingface_hub import constants

from hub_envs._text import safe_text
from hub_envs.errors import IntegrityError
from hub_envs.repo.format import MANIFEST_FILE, beyond_manifest, is_commit_sha

REPO_TYPE = "model"  # model type, so LeRobot's EnvHub loader (hf_hub_download default) finds it
#: The type of the repo of the same name push_env also publishes the dataset to (what ``LeRobotDataset(repo_id)`` reads).
DATASET_REPO_TYPE = "dataset"


@dataclass(frozen=True)
class Snapshot:
    """A repo at one commit, on local disk."""

    repo_id: str
    requested: str | None  # what the caller asked for (branch, tag, sha or None for main)
    sha: str  # the resolved 40-hex commit id
    path: Path
    from_cache: bool  # True when no network request was made
    #: files still downloading in the background (``resolve_snapshot(first=...)``), by repo path
    pending: dict[str, concurrent.futures.Future] = field(default_factory=dict, compare=False, repr=False)
    #: the files the Hub listed for the commit and this download fetched (empty when served from the cache)
    fetched: frozenset[str] = field(default=frozenset(), compare=False, repr=False)
    _pool: concurrent.futures.ThreadPoolExecutor | None = field(default=None, compare=False, repr=False)

    @property
    def pinned(self) -> bool:
        return self.requested == self.sha

    def wait(self) -> None:
        """Wait for the files still downloading in the background (the caller verifies them)."""
        try:
            for future in self.pending.values():
                future.result()
        finally:
            self.cancel()  # done (or failed): the download threads end here

    def cancel(self) -> None:
        """Give up the background downloads: the ones not started are dropped, the running ones are waited
        for (so nothing writes into the cache afterwards); their errors are ignored."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)  # joins its threads


def offline() -> bool:
    """Whether the client is offline (``HF_HUB_OFFLINE``, as huggingface_hub read it)."""
    return bool(constants.HF_HUB_OFFLINE)


def endpoint() -> str:
    """The Hub's URL the client uses (``HF_ENDPOINT``, as huggingface_hub resolved it)."""
    return constants.ENDPOINT


def cache_snapshots_dir(repo_id: str, cache_dir: str | Path | None = None) -> Path:
    """The ``snapshots/`` folder of ``repo_id`` in the HF cache (huggingface_hub's own naming, ``file_download.repo_folder_name``,
    which ``tests/test_first_step.py`` holds this to; it may not exist). The one place hub-envs names a cache path:
    everything else asks ``snapshot_download`` / ``try_to_load_from_cache`` or goes through here.

    Args:
        repo_id: an env repo.
        cache_dir: the cache (None: ``HF_HUB_CACHE``).

    Returns:
        The folder's path.
    """
    cache = Path(cache_dir or constants.HF_HUB_CACHE)
    folder = f"{REPO_TYPE}s{constants.REPO_ID_SEPARATOR}" + constants.REPO_ID_SEPARATOR.join(repo_id.split("/"))
    return cache / folder / "snapshots"


def snapshot_origin(folder: Path) -> tuple[str, str] | None:
    """(repo_id, sha) when ``folder`` is a snapshot folder of a model repo in an HF cache, else None.

    >>> snapshot_origin(Path("/c/models--alice--tiny/snapshots/" + "a" * 40))
    ('alice/tiny', 'aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa')
    >>> snapshot_origin(Path("/tmp/tiny")) is None
    True
    """
    sha, snapshots, repo_dir = folder.name, folder.parent, folder.parent.parent
    if snapshots.name != "snapshots" or not is_commit_sha(sha):
        return None
    kind, _, name = repo_dir.name.partition("--")
    if kind != "models" or not name:
        return None
    return name.replace("--", "/"), sha


def snapshot_cache_dir(repo_id: str, sha: str, cache_dir: str | Path | None = None) -> Path:
    """Where huggingface_hub keeps ``repo_id`` at commit ``sha``.

    Args:
        repo_id: the env repo.
        sha: the commit.
        cache_dir: the cache (None: ``HF_HUB_CACHE``).

    Returns:
        The folder's path (it may not exist).
    """
    return cache_snapshots_dir(repo_id, cache_dir) / sha


def normalized_revision(revision: str | None) -> str | None:
    """A 40-hex commit sha in lower case (a sha written in upper case names the same commit); anything else as it is.

    >>> normalized_revision("A" * 40) == "a" * 40, normalized_revision("main")
    (True, 'main')
    """
    if revision is not None and len(revision) == 40 and all(c in "0123456789abcdefABCDEF" for c in revision):
        return revision.lower()
    return revision


def cached_snapshot(repo_id: str, revision: str | None, cache_dir: str | Path | None = None) -> Snapshot | None:
    """A pinned commit whose manifest is in the cache, served without any request (a pinned warm load works offline,
    and imports no HTTP client); None for anything else (a branch, a tag, a commit not cached).

    Args:
        repo_id: the env repo.
        revision: what was asked for.
        cache_dir: the cache (None: ``HF_HUB_CACHE``).

    Returns:
        The :class:`Snapshot` (not verified: the caller checks it against its manifest), or None.
    """
    revision = normalized_revision(revision)
    if not is_commit_sha(revision):
        return None
    cached = snapshot_cache_dir(repo_id, revision, cache_dir)
    if (cached / MANIFEST_FILE).is_file():
        return Snapshot(repo_id, revision, revision, cached, from_cache=True)
    return None


def check_snapshot_layout(path: Path, listed: set[str], *, where: str) -> None:
    """Refuse a cache snapshot that holds anything but the manifest's files, each a link into its repo's ``blobs/``.

    huggingface_hub makes every snapshot file a symlink to ``<repo>/blobs/<etag>``. A link resolving anywhere else, or a
    file the manifest does not list (but those the Hub workflow adds after publication:
    :func:`hub_envs.repo.format.beyond_manifest`), was not put there by a download of this commit.

    Args:
        path: the snapshot folder.
        listed: the manifest's files.
        where: names the snapshot in messages.

    Raises:
        IntegrityError: naming the links and files that do not belong.
    """
    blobs = path.parent.parent / "blobs"
    bad = []
    for dirpath, dirnames, filenames in os.walk(path):
        for name in dirnames + filenames:
            full = Path(dirpath, name)
            rel = full.relative_to(path).as_posix()
            if full.is_symlink():
                target = Path(os.path.realpath(full))
                if blobs.resolve() not in target.parents:
                    bad.append(f"{rel} -> {target} (a link outside the cache's blobs/)")
                    continue
            if name in filenames and rel not in listed and not beyond_manifest(rel):
                bad.append(f"{rel} (not in the manifest)")
    if bad:
        raise IntegrityError(
            f"{where}: the cached snapshot {path} holds what no download of this commit puts there:\n  "
            + "\n  ".join(safe_text(b) for b in bad[:20])
            + "\nNot importing it. It was removed from the cache; load again to download the commit afresh."
        )


def drop_snapshot(path: Path) -> None:
    """Remove one snapshot folder of the cache (its blobs stay: they are content-addressed).

    Args:
        path: ``.../snapshots/<sha>`` (anything else is left alone).
    """
    if path.parent.name == "snapshots" and is_commit_sha(path.name):
        shutil.rmtree(path, ignore_errors=True)
