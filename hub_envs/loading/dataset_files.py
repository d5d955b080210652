"""The files ``load_env`` leaves on the Hub until they are asked for: the bundled dataset's data files and the card's
media, fetched on first use and checked against the manifest."""

from __future__ import annotations

import os
from pathlib import Path

from hub_envs._text import safe_text
from hub_envs.errors import DatasetNotCachedError, IntegrityError, InvalidRepoFormatError, OfflineNotCachedError
from hub_envs.repo import hub_cache
from hub_envs.repo.format import DATASET_DIR, MEDIA_DIR, Manifest, is_lazy_file, is_media_file, sha256_file


def ensure_dataset_files(
    repo_id: str, sha: str, path: Path, manifest: Manifest, *, token: str | None = None, cache_dir: str | Path | None = None
) -> None:
    """Make the dataset's data files of a snapshot present and verified against its manifest.

    Args:
        repo_id: the env repo (``user/name``).
        sha: the commit the snapshot holds.
        path: the snapshot folder.
        manifest: the commit's manifest (the files' sha256).
        token: the Hub token to download with (None: huggingface_hub's own).
        cache_dir: the Hugging Face cache to use (None: the default).

    Raises:
        DatasetNotCachedError: offline, with files missing from the cache.
        IntegrityError: a file differs from the manifest (it was removed from the cache: fetch again).
    """
    where = f"{repo_id}@{sha}"
    lazy = sorted(p for p in manifest.files if is_lazy_file(p))
    missing = [p for p in lazy if not (path / p).is_file()]
    if missing:
        if hub_cache.offline():
            raise DatasetNotCachedError(
                f"{where}: {len(missing)} of the dataset's {len(lazy)} data file(s) are not in the local cache "
                f"(e.g. {safe_text(missing[0])}), and the Hub cannot be used (HF_HUB_OFFLINE is set). load_env "
                f"fetches the code and the dataset's meta/ only; fetch the data once online: unset HF_HUB_OFFLINE and "
                f"call loaded.fetch_dataset() (or open_dataset()), or "
                f'huggingface_hub.snapshot_download("{repo_id}", revision="{sha}", allow_patterns=["{DATASET_DIR}/*"]).'
            )
        from hub_envs.repo import hub_io  # heavy: huggingface_hub's client (httpx or requests): only to download

        hub_io.fetch_dataset_files(repo_id, sha, token=token, cache_dir=cache_dir)
    bad = [p for p in lazy if not (path / p).is_file() or sha256_file(path / p) != manifest.files[p]]
    if bad:
        for p in bad:
            drop_cached_file(path / p)
        raise IntegrityError(
            f"{where}: {len(bad)} dataset file(s) are missing or differ from the manifest (sha256), e.g. {safe_text(bad[0])}. They "
            f"were removed from the cache; fetch again (loaded.fetch_dataset()). If it persists, the endpoint serves "
            f"other bytes than the publisher pushed: check HF_ENDPOINT."
        )
    hub_cache.check_snapshot_layout(path, set(manifest.files), where=where)


def drop_cached_file(path: Path) -> None:
    """Remove one file of a cache snapshot and the blob it links to, so that the next fetch downloads it again.

    Args:
        path: the file in a snapshot folder (a symlink into ``blobs/``, or a file).
    """
    try:
        if path.is_symlink():
            target = Path(os.path.realpath(path))
            if target.parent.name == "blobs":
                target.unlink(missing_ok=True)
        path.unlink(missing_ok=True)
    except OSError:
        pass


def ensure_media_file(
    repo_id: str,
    sha: str,
    path: Path,
    manifest: Manifest,
    name: str,
    *,
    local: bool = False,
    token: str | None = None,
    cache_dir: str | Path | None = None,
) -> Path:
    """The card's media file ``media/<name>`` of a snapshot, fetched on first use and checked against the manifest.

    load_env leaves the media on the Hub: only the card and the web page show them.

    Args:
        repo_id, sha, path, manifest, token, cache_dir: as for :func:`ensure_dataset_files`.
        name: ``rollout.gif``; ``rollout.mp4`` when the dataset stores video.
        local: ``path`` is a local folder (nothing to fetch or check).

    Returns:
        The file's path.

    Raises:
        InvalidRepoFormatError: the repo has no such media file.
        OfflineNotCachedError: offline, and the file is not in the cache.
        IntegrityError: the file differs from the manifest (it was removed from the cache).
    """
    rel = f"{MEDIA_DIR}/{name}"
    where = f"{repo_id}@{sha}"
    if rel not in manifest.files or not is_media_file(rel):
        media = sorted(p for p in manifest.files if is_media_file(p))
        raise InvalidRepoFormatError(
            f"{where} has no {safe_text(rel)}; its media: {', '.join(media) or 'none'} (push_env renders them)."
        )
    file = path / rel
    if local:
        return file
    if not file.is_file():
        if hub_cache.offline():
            raise OfflineNotCachedError(
                f"{where}: {safe_text(rel)} is not in the local cache and the Hub cannot be used (HF_HUB_OFFLINE is "
                f"set); load_env does not fetch the media. Unset HF_HUB_OFFLINE and call loaded.media_file({name!r})."
            )
        from hub_envs.repo import hub_io  # heavy: huggingface_hub's client (httpx or requests): only to download

        hub_io.fetch_files(repo_id, sha, [rel], token=token, cache_dir=cache_dir)
    if sha256_file(file) != manifest.files[rel]:
        drop_cached_file(file)
        raise IntegrityError(
            f"{where}: {safe_text(rel)} differs from the manifest (sha256); it was removed from the cache. Call "
            f"loaded.media_file({name!r}) again; if it persists, the endpoint serves other bytes than the publisher "
            f"pushed: check HF_ENDPOINT."
        )
    return file
