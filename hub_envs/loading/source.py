"""The first stages of ``load_env``: resolve a repo id (or a local folder) to a commit, fetch it, verify every file
against its manifest, and the trust gate, before anything of the repo is imported."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import re
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from hub_envs._text import safe_text
from hub_envs.envcode.code_copy import code_files
from hub_envs.errors import (
    ConfigError,
    EnvFolderError,
    HubEnvsError,
    IntegrityError,
    InvalidRepoFormatError,
    OfflineNotCachedError,
    UnpinnedRevisionWarning,
    UntrustedCodeError,
)
from hub_envs.loading.loaded import LoadReport
from hub_envs.repo import hub_cache, trust_list
from hub_envs.repo.format import (
    DATASET_DIR,
    MANIFEST_FILE,
    SINGLE_TASK_FORMAT_VERSION,
    SUITE_FORMAT_VERSION,
    EnvFolder,
    Manifest,
    check_names_belong_to,
    content_digest,
    hash_files,
    is_code_file,
    is_on_demand_file,
)
from hub_envs.repo.refs import local_path, parse_repo_ref


def _local_manifest(folder: EnvFolder) -> Manifest:
    """The manifest a local folder would be published with (minus the generated parts)."""
    files = hash_files(folder.root, list(folder.files))
    slug = re.sub(r"[^A-Za-z0-9_.-]", "_", folder.root.name) or "env"  # a gym id and a draccus choice name
    return Manifest(
        name=folder.name,
        version=folder.version,
        description=folder.description,
        env_entry_point=folder.env_entry_point,
        config_entry_point=folder.config_entry_point,
        gym_id=f"local/{slug}",
        env_type=f"local/{slug}",
        requirements=folder.requirements,
        processors=folder.processors,
        files=files,
        content_digest=content_digest(files),
        # a suite's tasks by name (push_env records each one's instruction, episodes, seeds and fingerprint)
        tasks=tuple(
            {"task": t, "task_index": i, "instruction": "", "episodes": [], "seeds": []} for i, t in enumerate(folder.tasks)
        ),
        format_version=SUITE_FORMAT_VERSION if folder.tasks else SINGLE_TASK_FORMAT_VERSION,
    )


def _trust_gate(
    repo_id: str, sha: str, manifest: Manifest, path: Path, trust_remote_code: bool, trusted: trust_list.TrustList
) -> str:
    """Consent for exactly this commit and content: the call's flag, or an entry of the trust list as it was
    read before anything was downloaded (``trusted``), never a re-read of a file a download could have written."""
    if trust_remote_code:
        return "trust_remote_code=True"
    if trusted.covers(repo_id, sha, manifest.content_digest):
        return f"trust list ({trusted.path})"
    code = sorted(safe_text(p) for p in manifest.files if is_code_file(p))
    previous = [e for e in trusted.previous(repo_id) if e.sha != sha]
    changed = ""
    if any(e.sha == sha for e in trusted.previous(repo_id)):
        changed = (
            f"\nYou trusted {repo_id}@{sha[:12]} for other content (manifest digest "
            f"{next(e.content_digest for e in trusted.previous(repo_id) if e.sha == sha)[:16]}…); the endpoint now serves "
            f"{manifest.content_digest[:16]}… under the same commit id. Do not trust it again unless you know why."
        )
    elif trust_list.legacy_trusted(repo_id, sha):
        changed = (
            "\nAn older hub-envs trusted this commit by its sha alone; trust now also binds the content. "
            "Confirm it once more (command below)."
        )
    elif previous:
        prev_dir = path.parent / previous[-1].sha
        if (prev_dir / MANIFEST_FILE).is_file():
            try:
                old = Manifest.read(prev_dir).files
                diff = [p for p in sorted(set(old) | set(manifest.files)) if old.get(p) != manifest.files.get(p)]
                code = [safe_text(p) for p in diff if is_code_file(p)]
                other = [safe_text(p) for p in diff if not is_code_file(p)]
                changed = (
                    f"\nYou trusted {previous[-1].sha[:12]} before; since then code changed in: {', '.join(code) or 'no code file'}"
                    f"{'; other files: ' + ', '.join(other[:8]) + (' …' if len(other) > 8 else '') if other else ''}."
                )
            except HubEnvsError:
                pass
        else:
            changed = f"\nYou trusted {repo_id}@{previous[-1].sha[:12]} before, not this commit."
    raise UntrustedCodeError(
        f"{repo_id}@{sha} contains Python code that would run on this machine ({', '.join(code)}); nothing was imported.{changed}\n"
        f"Read it in {path}, then either pass trust_remote_code=True:\n"
        f'  load_env("{repo_id}@{sha}", trust_remote_code=True)\n'
        f"or trust this exact commit and content once (remembered):\n"
        f"  hub-envs trust {repo_id}@{sha}"
    )


_CONTENT_TAG = re.compile(r"sha256-([0-9a-f]{16})")


def _check_content_tag(requested: str | None, manifest: Manifest, where: str) -> None:
    """``@sha256-<digest16>`` (the tag push_env gives every push, and the card pins) names content: hold it to that."""
    m = _CONTENT_TAG.fullmatch(requested or "")
    if m and not manifest.content_digest.startswith(m.group(1)):
        raise IntegrityError(
            f"{where}: the tag {requested} names content {m.group(1)}…, but the commit it points at holds content "
            f"{manifest.content_digest[:16]}…. The tag was moved or the endpoint lies; nothing was imported. Pin the commit "
            f"sha you meant instead."
        )


def _check_content_digest(expected: str | None, manifest: Manifest, where: str) -> None:
    """``content_digest=`` binds a load to the content consent was given for (a Ray worker gets the driver's): a
    commit that holds other content is refused before anything of it is imported."""
    if expected is None or manifest.content_digest == expected:
        return
    raise UntrustedCodeError(
        f"{where} holds content {manifest.content_digest[:16]}…, not the content {expected[:16]}… this load was bound to "
        f"(content_digest=, the digest consent was given for); nothing was imported. The endpoint {hub_cache.endpoint()}, or "
        f"the network path to it, serves other files under this commit id than the ones that were consented to. Do not "
        f"run it: compare the endpoint with the one the consent was given through (HF_ENDPOINT), or use TLS."
    )


def needed_first(path: str) -> bool:
    """Whether a file is one the stages before ``load_env``'s checks read: the manifest, the code and its assets (what
    :func:`~hub_envs.envcode.code_copy.code_copy` copies) and the dataset's ``meta/info.json`` (the feature check). The
    card and the rest of ``meta/`` download meanwhile, and are verified before load_env returns.

    Args:
        path: a file of the repo.

    Returns:
        True for a file fetched before the others.
    """
    return path in (MANIFEST_FILE, f"{DATASET_DIR}/meta/info.json") or bool(code_files({path: ""}))


def _hub_io():
    """:mod:`hub_envs.repo.hub_io`, imported when a load needs the Hub (a pinned commit in the cache does not): it
    installs its endpoint check on huggingface_hub's client before any request."""
    from hub_envs.repo import hub_io  # heavy: huggingface_hub's client and its HTTP stack (httpx or requests)

    return hub_io


def _fetch_and_verify(repo: str, requested: str | None, *, token, cache_dir) -> tuple[hub_cache.Snapshot, Manifest]:
    """Resolve, download and verify a snapshot; a snapshot that fails is removed from the cache (so nothing,
    LeRobot's own loader included, later runs what it holds). The files :func:`needed_first` does not accept
    may still be downloading (``snap.pending``): :func:`finish_fetch` waits for them and verifies them."""
    fetch = dict(token=token, cache_dir=cache_dir, lazy=True, first=needed_first)
    # a pinned commit in the cache needs no request: no Hub client is imported for it
    snap = hub_cache.cached_snapshot(repo, requested, cache_dir) or _hub_io().resolve_snapshot(repo, requested, **fetch)
    where = f"{repo}@{snap.sha}"

    def verify(s: hub_cache.Snapshot) -> Manifest:
        manifest = Manifest.read(s.path, where=f"{where}: hub_env.json")
        check_names_belong_to(manifest, repo)  # the names it registers live under this repo's namespace
        # the dataset's data and the media: when they are needed; the card and meta/: once they are here
        _verify_fetched(manifest, s, skip=s.pending, token=token, cache_dir=cache_dir)
        hub_cache.check_snapshot_layout(s.path, set(manifest.files), where=where)
        return manifest

    try:
        try:
            return snap, verify(snap)
        except (IntegrityError, InvalidRepoFormatError):
            snap.cancel()
            if snap.from_cache and hub_cache.offline():
                _raise_if_partly_cached(snap.path, where)
            if not snap.from_cache or hub_cache.offline():
                raise
            # a cached snapshot may be damaged locally: fetch it again once, then judge
            hub_cache.drop_snapshot(snap.path)
            snap = _hub_io().resolve_snapshot(repo, snap.sha, force_download=True, **fetch)
            return snap, verify(snap)
    except IntegrityError:
        snap.cancel()
        hub_cache.drop_snapshot(snap.path)
        raise
    except BaseException:
        snap.cancel()
        raise


def _verify_fetched(manifest: Manifest, snap: hub_cache.Snapshot, *, skip, token, cache_dir) -> None:
    """``manifest.verify_files`` (lazy) of a snapshot; files found *missing* are fetched once more before judging:
    huggingface_hub re-links a snapshot file (remove, then symlink) when another process sharing the cache downloads
    it at the same time, so a file can be absent for an instant, and a snapshot found in the cache may be one that
    other processes are still filling (its manifest came first). For a fresh download only files it fetched are
    retried: a file the manifest lists and the Hub does not hold is the repo's fault (IntegrityError, not a 404 from
    a second request). Tampered files are never retried (the caller judges them; a cached snapshot is then dropped
    and fetched again)."""
    where = f"{snap.repo_id}@{snap.sha}"
    try:
        manifest.verify_files(snap.path, where=where, lazy=True, skip=skip)
    except IntegrityError as first:
        if hub_cache.offline():
            raise
        missing = [
            p
            for p in manifest.files
            if (snap.from_cache or p in snap.fetched)
            and not is_on_demand_file(p)
            and p not in skip
            and not (snap.path / p).is_file()
        ]
        if not missing:
            raise
        try:
            _hub_io().fetch_files(snap.repo_id, snap.sha, missing, token=token, cache_dir=cache_dir)
        except HubEnvsError:
            if snap.from_cache:  # the caller drops the cached snapshot and fetches it whole: judged there
                raise first from None
            raise
        manifest.verify_files(snap.path, where=where, lazy=True, skip=skip)


def finish_fetch(src: Source, *, token: str | None, cache_dir: str | Path | None) -> None:
    """Wait for the files still downloading since :func:`resolve_source` and verify them, and the snapshot's layout
    (unlisted code included) again.

    Args:
        src: the load's source.
        token, cache_dir: as for :func:`resolve_source`.

    Raises:
        IntegrityError: a file differs from the manifest (the snapshot is removed from the cache).
    """
    snap = src.snapshot
    if snap is None or not snap.pending:
        return
    where = f"{src.repo}@{src.sha}"
    snap.wait()
    try:
        verified = set(src.manifest.files) - set(snap.pending)  # by resolve_source
        _verify_fetched(src.manifest, snap, skip=verified, token=token, cache_dir=cache_dir)
        hub_cache.check_snapshot_layout(src.path, set(src.manifest.files), where=where)
    except IntegrityError:
        hub_cache.drop_snapshot(src.path)
        raise


def _resolve_local(path: Path) -> tuple[str, str, Path, Manifest, EnvFolder | None]:
    if (path / "hub_env.json").is_file():  # a published repo checked out locally
        manifest = Manifest.read(path)
        return manifest.repo_id or f"local/{path.name}", f"local-{manifest.content_digest[:12]}", path, manifest, None
    folder = EnvFolder.read(path)
    manifest = _local_manifest(folder)
    return f"local/{path.name}", f"local-{manifest.content_digest[:12]}", path, manifest, folder


@dataclasses.dataclass(frozen=True)
class Source:
    """Where a load's env comes from, resolved, verified and its code consented to (nothing of it imported yet)."""

    repo: str
    sha: str
    path: Path
    manifest: Manifest
    local_folder: Path | None
    requested: str | None
    snapshot: hub_cache.Snapshot | None = None  # a Hub snapshot, maybe with files still downloading (``pending``)

    @property
    def where(self) -> str:
        """``user/name@<sha>``, as messages name it."""
        return f"{self.repo}@{self.sha}"

    def cancel(self) -> None:
        """Stop what is still downloading (nothing of a failed or refused load keeps downloading)."""
        if self.snapshot is not None:
            self.snapshot.cancel()


def resolve_source(
    repo_id: str | os.PathLike,
    *,
    revision: str | None,
    trust_remote_code: bool,
    config: Mapping[str, Any] | None,
    token: str | None,
    cache_dir: str | Path | None,
    report: LoadReport,
    content_digest: str | None = None,
) -> Source:
    """The first stages of a load: resolve (a local folder, or a Hub repo@revision to a commit), fetch, verify every
    file against the manifest, and pass the trust gate. Nothing of the repo is imported.

    Args:
        repo_id, revision, trust_remote_code, config, token, cache_dir, content_digest: as :func:`hub_envs.load_env`
            takes them.
        report: the load's report, whose ``integrity`` and ``trust`` lines this fills.

    Returns:
        The :class:`Source`; a Hub snapshot's card and ``meta/`` may still be downloading (:func:`finish_fetch`).

    Raises:
        EnvFolderError: a path names no folder.
        ConfigError: ``config`` given for a Hub repo.
        IntegrityError: a file differs from the manifest, or a content tag names other content.
        UntrustedCodeError: no consent for this commit and content.
    """
    local_folder = None
    # a folder's code runs without consent: 'user/name' names a Hub repo even if a folder of that name exists here
    path_candidate = local_path(repo_id, stacklevel=3)
    use_local = path_candidate is not None
    if use_local and not path_candidate.is_dir():
        raise EnvFolderError(
            f"Env folder {safe_text(os.fspath(repo_id))} does not exist. Pass a folder holding pyproject.toml and the "
            f"env's code, or a Hub repo id such as 'user/name'."
        )
    repo_id = os.fspath(repo_id)
    if config and not use_local:
        raise ConfigError(
            f"load_env({repo_id!r}, config=...): config fields can be set for a local folder only; a Hub repo's config "
            f"is the one it published. Publish a variant with push_env --config.<field>=<value>."
        )
    if use_local:
        repo, sha, path, manifest, folder = _resolve_local(path_candidate.resolve())
        if config:  # another variant of the folder: other names, so both can be loaded at once
            variant = json.dumps(dict(config), sort_keys=True, default=str)
            sha = "local-" + hashlib.sha256(f"{manifest.content_digest}\0{variant}".encode()).hexdigest()[:12]
            manifest = dataclasses.replace(manifest, config_overrides=dict(config))
        local_folder = path
        requested = None
        _check_content_digest(content_digest, manifest, str(path))
        if folder is None:
            manifest.verify_files(path, where=str(path))
            report.integrity = f"{len(manifest.files)} files match the manifest"
        else:
            report.integrity = "local folder (hashed, not verified)"
        report.trust = "local folder"
    else:
        repo, at_rev = parse_repo_ref(repo_id)
        requested = revision or at_rev
        trusted = trust_list.read_trust_list()  # before any download: nothing a download writes can change it
        snap, manifest = _fetch_and_verify(repo, requested, token=token, cache_dir=cache_dir)
        report.integrity = f"{len(manifest.files)} files match the manifest"
        sha, path = snap.sha, snap.path
        try:
            _check_content_tag(requested, manifest, f"{repo}@{sha}")
            _check_content_digest(content_digest, manifest, f"{repo}@{sha}")
            if not snap.pinned and not _CONTENT_TAG.fullmatch(requested or ""):
                warnings.warn(
                    f"{repo}: revision {requested or 'main'!r} resolved to {sha}. Pin it for reproducible results: "
                    f'load_env("{repo}@{sha}")',
                    UnpinnedRevisionWarning,
                    stacklevel=3,
                )
            report.trust = _trust_gate(repo, sha, manifest, path, trust_remote_code, trusted)
        except BaseException:
            snap.cancel()  # nothing of a refused load keeps downloading
            raise
        return Source(repo, sha, path, manifest, local_folder, requested, snap)
    return Source(repo, sha, path, manifest, local_folder, requested)


def _raise_if_partly_cached(path: Path, where: str) -> None:
    """Offline, a snapshot left incomplete by an interrupted download is a cache problem, not tampering."""
    try:
        files = Manifest.read(path).files
    except HubEnvsError:
        files = {}
    missing = sorted(p for p in files if not is_on_demand_file(p) and not (path / p).is_file()) if files else ["hub_env.json"]
    if missing:
        raise OfflineNotCachedError(
            f"{where} is only partly in the local cache ({len(missing)} file(s) missing, e.g. {missing[0]}; an interrupted "
            f"download?). Load it once online (unset HF_HUB_OFFLINE) to complete it."
        )
