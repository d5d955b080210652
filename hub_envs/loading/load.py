"""``load_env``: an env repo id in, a registered, checked, ready-to-make environment out.

Stages, in order (each can stop the load with its own error, and a failure after registration
started leaves gymnasium's registry and draccus' choices exactly as they were):

1. resolve the revision to a commit sha and fetch the snapshot (cached shas need no network);
2. verify every file against the manifest's sha256 (tampered, missing or unlisted code is refused);
3. trust gate: no code runs without ``trust_remote_code=True`` or a trust-list entry for repo@sha;
4. requirements preflight (nothing is installed for you);
5. import the code under a module name unique to repo+sha, register with gymnasium and draccus;
6. checks: the three-way feature check and the golden-rollout fingerprint.

Example:
    >>> import gymnasium as gym
    >>> from hub_envs import load_env
    >>> env = load_env("user/pendulum-lerobot@<sha>", trust_remote_code=True)   # doctest: +SKIP
    >>> obs, info = gym.make(env.gym_id).reset(seed=0)                          # doctest: +SKIP
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import hashlib
import json
import logging
import os
import re
import threading
import time
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import gymnasium as gym

from hub_envs._text import safe_text
from hub_envs.dataset.reader import read_info
from hub_envs.envcode import registration
from hub_envs.envcode.code_copy import code_copy, code_files
from hub_envs.envcode.envconfig import config_differences, encode_config, instantiate_config, validate_config_class
from hub_envs.envcode.importing import forget_env_folder, import_env_folder, is_imported, module_key, resolve_entry_point
from hub_envs.errors import (
    ConfigError,
    DatasetError,
    DatasetNotCachedError,
    EnvCodeError,
    EnvFolderError,
    FingerprintMismatchError,
    HubEnvsError,
    IntegrityError,
    InvalidRepoFormatError,
    IsolationUnavailableError,
    OfflineNotCachedError,
    RegistrationConflictError,
    UntrustedCodeError,
)
from hub_envs.harness.checks import verify_fingerprint
from hub_envs.harness.features import FeatureReport, check_features
from hub_envs.harness.provenance import drift_note
from hub_envs.loading import check_cache
from hub_envs.repo import hub_io, trust_list
from hub_envs.repo.format import (
    DATASET_DIR,
    MANIFEST_FILE,
    MEDIA_DIR,
    EnvFolder,
    Manifest,
    check_names_belong_to,
    content_digest,
    hash_files,
    is_code_file,
    is_lazy_file,
    is_media_file,
    is_on_demand_file,
    sha256_file,
)
from hub_envs.repo.requirements import check_requirements

FingerprintPolicy = Literal["error", "warn", "off"]
_log = logging.getLogger(__name__)


class UnpinnedRevisionWarning(UserWarning):
    """load_env was given a branch or tag: the result is pinned to the sha it resolved to, but the call is not."""


@dataclass
class LoadReport:
    """What load_env checked, and how long each stage took (seconds)."""

    integrity: str = "not checked"
    trust: str = "not needed"
    requirements: list[str] = field(default_factory=list)
    features: FeatureReport | None = None
    fingerprint: str = "not checked"
    timings: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {
            "integrity": self.integrity,
            "trust": self.trust,
            "requirements": self.requirements,
            "features": self.features.to_dict() if self.features else None,
            "fingerprint": self.fingerprint,
            "timings": self.timings,
        }


class LoadedEnv:
    """An env loaded from the Hub (or a local folder): registered, checked, and ready to make.

    Attributes:
        repo_id: ``user/name`` (``local/<folder>`` for a local folder).
        revision: the resolved 40-hex commit sha (``local-<digest>`` for a local folder).
        gym_id: the id registered with gymnasium (``gym.make(loaded.gym_id)``), unique per revision.
        env_type: the draccus choice name (``--env.type=<env_type>``), unique per revision.
        config: an instance of the repo's EnvConfig subclass, with its published defaults.
        manifest: the parsed ``hub_env.json``.
        path: the local snapshot folder.
        report: the :class:`LoadReport`.
    """

    def __init__(
        self,
        *,
        repo_id,
        revision,
        requested_revision,
        path,
        manifest,
        env_class,
        config_class,
        config,
        registration_,
        report,
        local_folder=None,
        isolation=None,
        token=None,
        cache_dir=None,
    ):
        self.repo_id: str = repo_id
        self.revision: str = revision
        self.requested_revision: str | None = requested_revision
        self.path: Path = Path(path)
        self.manifest: Manifest = manifest
        self.env_class = env_class
        self.config_class = config_class
        self.config = config
        self._registration: registration.Registration = registration_
        self.report: LoadReport = report
        self.local_folder: Path | None = local_folder
        #: how the env's code runs (:class:`hub_envs.isolation.IsolationOptions`); None: in this process
        self.isolation = isolation if isolation is not None and isolation.isolated else None
        self._token = token
        self._cache_dir = cache_dir
        self._dataset_verified = False
        self._unregistered = False
        self._earlier: LoadedEnv | None = None  # the load of the same env_type this one replaced in _LOADED

    @property
    def worker_venv(self) -> dict[str, Any] | None:
        """For an ``isolation="venv"`` load: the worker's venv record (``path``, ``python``, ``installed``, ``notes``)."""
        return worker_versions(self)

    @property
    def runs_as(self) -> str:
        """How the env's code runs, as reports record it: ``none`` (in this process), ``process``, ``venv``,
        ``process+sandbox``, ``venv+publisher`` (the publisher's package versions), ..."""
        return "none" if self.isolation is None else self.isolation.label

    # -- names --
    @property
    def gym_id(self) -> str:
        return self._registration.gym_id

    @property
    def env_type(self) -> str:
        return self._registration.env_type

    @property
    def is_local(self) -> bool:
        return self.local_folder is not None

    @property
    def dataset_root(self) -> Path | None:
        """The bundled dataset's folder, its data files fetched and verified (see :meth:`fetch_dataset`);
        None if the repo has no dataset."""
        return self.fetch_dataset()

    @property
    def dataset_meta_root(self) -> Path | None:
        """The bundled dataset's folder with its ``meta/`` only (what load_env fetches); no download."""
        root = self.path / DATASET_DIR
        return root if (root / "meta" / "info.json").is_file() else None

    def fetch_dataset(self) -> Path | None:
        """Fetch the bundled dataset's data files (``dataset/data/``, videos: load_env fetched its
        ``meta/`` only), verify each against the manifest's sha256, and return the dataset folder.

        Once per LoadedEnv; files already in the cache are not downloaded again. None if the repo
        has no dataset. Raises :class:`~hub_envs.errors.DatasetNotCachedError` offline when files
        are missing, and :class:`~hub_envs.errors.IntegrityError` (the bad files are removed from
        the cache) when a file differs from the manifest.
        """
        root = self.dataset_meta_root
        if root is None or self._dataset_verified or self.is_local:
            return root
        ensure_dataset_files(self.repo_id, self.revision, self.path, self.manifest, token=self._token, cache_dir=self._cache_dir)
        self._dataset_verified = True
        return root

    def media_file(self, name: str = "rollout.gif") -> Path:
        """The card's media file ``media/<name>`` (``rollout.gif``; ``rollout.mp4`` when the dataset stores video),
        fetched on first use (load_env leaves the media on the Hub: only the card and the web page show them) and
        checked against the manifest's sha256. Raises :class:`~hub_envs.errors.InvalidRepoFormatError` when the
        repo has no such file, :class:`~hub_envs.errors.OfflineNotCachedError` offline when it is not cached,
        and :class:`~hub_envs.errors.IntegrityError` (the file is removed from the cache) when it differs."""
        rel = f"{MEDIA_DIR}/{name}"
        where = f"{self.repo_id}@{self.revision}"
        if rel not in self.manifest.files or not is_media_file(rel):
            media = sorted(p for p in self.manifest.files if is_media_file(p))
            raise InvalidRepoFormatError(
                f"{where} has no {safe_text(rel)}; its media: {', '.join(media) or 'none'} (push_env renders them)."
            )
        local = self.path / rel
        if self.is_local:
            return local
        if not local.is_file():
            if hub_io.offline():
                raise OfflineNotCachedError(
                    f"{where}: {safe_text(rel)} is not in the local cache and the Hub cannot be used (HF_HUB_OFFLINE is "
                    f"set); load_env does not fetch the media. Unset HF_HUB_OFFLINE and call loaded.media_file({name!r})."
                )
            hub_io.fetch_files(self.repo_id, self.revision, [rel], token=self._token, cache_dir=self._cache_dir)
        if sha256_file(local) != self.manifest.files[rel]:
            _drop_cached_file(local)
            raise IntegrityError(
                f"{where}: {safe_text(rel)} differs from the manifest (sha256); it was removed from the cache. Call "
                f"loaded.media_file({name!r}) again; if it persists, the endpoint serves other bytes than the publisher "
                f"pushed: check HF_ENDPOINT."
            )
        return local

    def config_with(self, fields: Mapping[str, Any]) -> Any:
        """The config with ``fields`` set (values decoded as LeRobot's ``--env.<field>=<value>`` flags are), on
        top of a published variant's own (``manifest.config_overrides``), before the config's ``__post_init__``.

        In-process: an instance of :attr:`config_class`. Isolated: the repo's config class runs in a worker
        (the parent never imports the repo's code) and what it computed comes back as a read-only
        :class:`~hub_envs.isolation.config.ManifestConfig`; the envs made from it follow it the same way.
        A field the config does not have is a :class:`~hub_envs.errors.ConfigError` naming its fields.
        """
        where = str(self.local_folder) if self.is_local else f"{self.repo_id}@{self.revision}"
        fields = {**self.manifest.config_overrides, **fields}
        if self.config_class is not None:
            return instantiate_config(self.config_class, where=where, overrides=fields)
        from hub_envs import errors
        from hub_envs.isolation.config import ManifestConfig
        from hub_envs.isolation.proxy import Worker

        factory = gym.spec(self.gym_id).entry_point
        worker = Worker(factory.target, self.isolation)
        try:
            answer = worker.request("config", self.manifest.config_entry_point, fields, timeout=self.isolation.start_timeout)
        finally:
            worker.close()
        if "error" in answer:
            name, message = answer["error"]
            error = getattr(errors, name, None)
            if not (isinstance(error, type) and issubclass(error, errors.HubEnvsError)):
                error = errors.EnvCodeError
            from hub_envs._text import safe_lines

            raise error(safe_lines(message))  # text from the env's code: escaped
        return ManifestConfig(answer["values"], where=f"{where}: its config with {sorted(fields)}")

    def load_line(self) -> str:
        if self.is_local:
            return f'load_env("{self.local_folder}")'
        return f'load_env("{self.repo_id}@{self.revision}", trust_remote_code=True)'

    # -- making envs --
    def make(self, cfg=None, **kwargs) -> gym.Env:
        """``gym.make`` this env; ``cfg`` (an instance of :attr:`config_class`) overrides the defaults."""
        if cfg is not None:
            kwargs = {**cfg.gym_kwargs, "max_episode_steps": cfg.episode_length, **kwargs}
        return gym.make(self.gym_id, **kwargs)

    def make_vec(self, n_envs: int = 1, use_async: bool = False, cfg=None, **kwargs) -> gym.vector.VectorEnv:
        """A vector env of ``n_envs`` copies (async: one process each, forked so the registration carries over).

        Isolated (``load_env(..., isolation="process")``): an :class:`~hub_envs.isolation.vector.IsolatedVectorEnv`
        (``use_async`` does not apply: its workers always step side by side)."""
        if n_envs < 1:
            raise ConfigError(f"n_envs must be at least 1, got {n_envs}.")
        if self.isolation is not None:
            from hub_envs.isolation.vector import IsolatedVectorEnv

            spec = gym.spec(self.gym_id)
            if cfg is not None:
                kwargs = {**cfg.gym_kwargs, "max_episode_steps": cfg.episode_length, **kwargs}
            kwargs = {**spec.kwargs, **kwargs}
            max_steps = kwargs.pop("max_episode_steps", spec.max_episode_steps)
            return IsolatedVectorEnv(
                spec.entry_point.target,
                self.isolation,
                n_envs,
                gym_id=self.gym_id,
                kwargs=kwargs,
                max_episode_steps=max_steps,
                disable_env_checker=spec.disable_env_checker,
            )
        fns = [lambda: self.make(cfg, **kwargs) for _ in range(n_envs)]
        if use_async:
            return gym.vector.AsyncVectorEnv(fns, context="fork")
        return gym.vector.SyncVectorEnv(fns)

    def open_dataset(self, **kwargs):
        """The bundled random-action dataset as a ``LeRobotDataset``, read from the snapshot; its data
        files are fetched and verified first if load_env left them out (see :meth:`fetch_dataset`). Video
        features decode with the backend that works here (torchcodec if it loads, else pyav:
        :func:`hub_envs._compat.video_backend`) unless ``video_backend=`` is given. The MP4s of video features
        are checked to decode (a truncated or damaged file raises :class:`IntegrityError`, not a decode crash
        inside a DataLoader)."""
        from lerobot.datasets.lerobot_dataset import LeRobotDataset

        from hub_envs._compat import video_backend
        from hub_envs.dataset.reader import check_videos

        root = self.fetch_dataset()
        if root is None:
            raise InvalidRepoFormatError(
                f"{self.repo_id}@{self.revision} has no dataset/ (a local folder gets one from push_env)."
            )
        if check_videos(root):
            kwargs.setdefault("video_backend", video_backend())
        return LeRobotDataset(self.repo_id, root=root, **kwargs)

    def processors(self, cfg=None):
        """Fresh ``(env_preprocessor, env_postprocessor)`` LeRobot pipelines of the steps the repo declares.

        Empty pipelines when it declares none. See :mod:`hub_envs.loading.processors`.
        """
        from hub_envs.loading.processors import pipelines_for

        return pipelines_for(self, cfg)

    def unregister(self) -> None:
        """Release this load's gym id and draccus choice (the imported modules stay cached). Another load of the
        same repo@sha shares them: they go when the last of those is unregistered. A second call does nothing."""
        if self._unregistered:
            return
        self._unregistered = True
        registration.unregister(self._registration)
        if _LOADED.get(self.env_type) is self:
            earlier = self._earlier
            if earlier is not None and not earlier._unregistered:
                _LOADED[self.env_type] = earlier  # the user's own load of it is what LeRobot's make_env finds again
            else:
                del _LOADED[self.env_type]

    def __enter__(self) -> LoadedEnv:
        return self

    def __exit__(self, *exc: object) -> None:
        """``with load_env(...) as loaded:`` unregisters at the end: what a command that loads an env for one run
        (reproduce, diff, evaluate, compare) wants."""
        self.unregister()

    def __repr__(self) -> str:
        return f"LoadedEnv({self.repo_id}@{self.revision[:12]}, gym_id={self.gym_id!r}, env_type={self.env_type!r})"


# --- stages -----------------------------------------------------------------------------------


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
        f"(content_digest=, the digest consent was given for); nothing was imported. The endpoint {hub_io.endpoint()}, or "
        f"the network path to it, serves other files under this commit id than the ones that were consented to. Do not "
        f"run it: compare the endpoint with the one the consent was given through (HF_ENDPOINT), or use TLS."
    )


def _needed_first(path: str) -> bool:
    """The files the stages before ``load_env``'s checks read: the manifest, the code and its assets (what
    :func:`~hub_envs.envcode.code_copy.code_copy` copies) and the dataset's ``meta/info.json`` (the feature check). The
    card and the rest of ``meta/`` download meanwhile, and are verified before load_env returns."""
    return path in (MANIFEST_FILE, f"{DATASET_DIR}/meta/info.json") or bool(code_files({path: ""}))


def _fetch_and_verify(repo: str, requested: str | None, *, token, cache_dir) -> tuple[hub_io.Snapshot, Manifest]:
    """Resolve, download and verify a snapshot; a snapshot that fails is removed from the cache (so nothing,
    LeRobot's own loader included, later runs what it holds). The files :func:`_needed_first` does not accept
    may still be downloading (``snap.pending``): :func:`_finish_fetch` waits for them and verifies them."""
    fetch = dict(token=token, cache_dir=cache_dir, lazy=True, first=_needed_first)
    snap = hub_io.resolve_snapshot(repo, requested, **fetch)
    where = f"{repo}@{snap.sha}"

    def verify(s: hub_io.Snapshot) -> Manifest:
        manifest = Manifest.read(s.path, where=f"{where}: hub_env.json")
        check_names_belong_to(manifest, repo)  # the names it registers live under this repo's namespace
        # the dataset's data and the media: when they are needed; the card and meta/: once they are here
        _verify_fetched(manifest, s, skip=s.pending, token=token, cache_dir=cache_dir)
        hub_io.check_snapshot_layout(s.path, set(manifest.files), where=where)
        return manifest

    try:
        try:
            return snap, verify(snap)
        except (IntegrityError, InvalidRepoFormatError):
            snap.cancel()
            if snap.from_cache and hub_io.offline():
                _raise_if_partly_cached(snap.path, where)
            if not snap.from_cache or hub_io.offline():
                raise
            # a cached snapshot may be damaged locally: fetch it again once, then judge
            hub_io.drop_snapshot(snap.path)
            snap = hub_io.resolve_snapshot(repo, snap.sha, force_download=True, **fetch)
            return snap, verify(snap)
    except IntegrityError:
        snap.cancel()
        hub_io.drop_snapshot(snap.path)
        raise
    except BaseException:
        snap.cancel()
        raise


def _verify_fetched(manifest: Manifest, snap: hub_io.Snapshot, *, skip, token, cache_dir) -> None:
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
        if hub_io.offline():
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
            hub_io.fetch_files(snap.repo_id, snap.sha, missing, token=token, cache_dir=cache_dir)
        except HubEnvsError:
            if snap.from_cache:  # the caller drops the cached snapshot and fetches it whole: judged there
                raise first from None
            raise
        manifest.verify_files(snap.path, where=where, lazy=True, skip=skip)


def _finish_fetch(src: _Source, *, token, cache_dir) -> None:
    """Wait for the files still downloading since :func:`_fetch_and_verify` and verify them (and the snapshot's
    layout, unlisted code included, again); a mismatch removes the snapshot from the cache."""
    snap = src.snapshot
    if snap is None or not snap.pending:
        return
    where = f"{src.repo}@{src.sha}"
    snap.wait()
    try:
        verified = set(src.manifest.files) - set(snap.pending)  # by _fetch_and_verify
        _verify_fetched(src.manifest, snap, skip=verified, token=token, cache_dir=cache_dir)
        hub_io.check_snapshot_layout(src.path, set(src.manifest.files), where=where)
    except IntegrityError:
        hub_io.drop_snapshot(src.path)
        raise


def _resolve_local(path: Path) -> tuple[str, str, Path, Manifest, EnvFolder | None]:
    if (path / "hub_env.json").is_file():  # a published repo checked out locally
        manifest = Manifest.read(path)
        return manifest.repo_id or f"local/{path.name}", f"local-{manifest.content_digest[:12]}", path, manifest, None
    folder = EnvFolder.read(path)
    manifest = _local_manifest(folder)
    return f"local/{path.name}", f"local-{manifest.content_digest[:12]}", path, manifest, folder


def _checked_config(config_class: type, manifest: Manifest, set_fields: Mapping[str, Any], where: str) -> Any:
    """The env's config (its defaults with ``set_fields``), refused when it is not what the manifest recorded."""
    validate_config_class(config_class, where=where)
    config = instantiate_config(config_class, where=where, overrides=set_fields)
    if manifest.config:
        diffs = config_differences(manifest.config, encode_config(config))
        if diffs:
            what = "the code's defaults" if not set_fields else f"what the code computes from {dict(set_fields)}"
            raise InvalidRepoFormatError(
                f"{where}: the manifest's config values differ from {what}:\n  "
                + "\n  ".join(diffs)
                + "\nRe-publish with push_env so the manifest matches the code."
            )
    return config


def _check_processors(loaded: LoadedEnv, *, dry: bool, where: str) -> None:
    """The env processors the repo declares: well formed, buildable, and (``dry``) run once on a live observation."""
    from hub_envs.loading.processors import specs_for, validate_for

    if loaded.isolation is not None and loaded.isolation.isolated:
        own = [sp.name for sp in specs_for(loaded) if ":" in sp.entry_point]
        if own:
            raise IsolationUnavailableError(
                f"{where} declares env processors from its own code ({', '.join(own)}), which would run in this "
                f"process; isolation does not support those yet (built-in and LeRobot-registry steps work). "
                f"Load it with isolation='none'."
            )
    validate_for(loaded, dry=dry)  # ProcessorError names the malformed field


@dataclasses.dataclass(frozen=True)
class _Source:
    """Stages 1-3 of a load, done: where the env comes from (resolved), verified, and its code consented to."""

    repo: str
    sha: str
    path: Path
    manifest: Manifest
    local_folder: Path | None
    requested: str | None
    snapshot: hub_io.Snapshot | None = None  # a Hub snapshot, maybe with files still downloading (``pending``)


def _resolve_source(
    repo_id: str | os.PathLike,
    *,
    revision: str | None,
    trust_remote_code: bool,
    config: Mapping[str, Any] | None,
    token: str | None,
    cache_dir: str | Path | None,
    report: LoadReport,
    timings: dict[str, float],
    t0: float,
    content_digest: str | None = None,
) -> _Source:
    """Resolve (a local folder, or a Hub repo@revision to a commit), verify (every file against the manifest)
    and pass the trust gate; nothing of the repo is imported. Fills ``report``'s integrity and trust lines."""
    local_folder = None
    # a folder's code runs without consent: 'user/name' names a Hub repo even if a folder of that name exists here
    path_candidate = hub_io.local_path(repo_id, stacklevel=3)
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
        repo, at_rev = hub_io.parse_repo_ref(repo_id)
        requested = revision or at_rev
        trusted = trust_list.read_trust_list()  # before any download: nothing a download writes can change it
        snap, manifest = _fetch_and_verify(repo, requested, token=token, cache_dir=cache_dir)
        timings["fetch_verify"] = time.perf_counter() - t0
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
        return _Source(repo, sha, path, manifest, local_folder, requested, snap)
    return _Source(repo, sha, path, manifest, local_folder, requested)


def load_env(
    repo_id: str,
    *,
    revision: str | None = None,
    trust_remote_code: bool = False,
    check: bool = True,
    fingerprint: FingerprintPolicy = "error",
    check_steps: int = 8,
    recheck: bool = False,
    token: str | None = None,
    cache_dir: str | Path | None = None,
    config: Mapping[str, Any] | None = None,
    isolation: str = "none",
    sandbox: bool = False,
    versions: str = "current",
    step_timeout: float | None = None,
    restart: bool = False,
    envs_per_worker: int = 0,
    sandbox_limits: dict[str, int] | None = None,
    content_digest: str | None = None,
) -> LoadedEnv:
    """Load an env repo by id (``"user/name"``, ``"user/name@rev"``) or from a local folder.

    The stages, in order: resolve, verify and trust (:func:`_resolve_source`), requirements, import (from
    :func:`hub_envs.envcode.code_copy.code_copy`) and register with the config checked against the manifest
    (:func:`_checked_config`), then the load checks and the env processors (:func:`_check_processors`).

    Args:
        repo_id: a Hub repo id, optionally ``@revision``, or the path of a local env folder.
        revision: a branch, tag or 40-hex commit sha (overrides ``@rev``). Pin a sha for reproducibility.
        trust_remote_code: consent to import and run the repo's code for this call. Without it, the
            repo@sha must be in the trust list (``hub-envs trust user/name@sha``). Local folders are yours.
        check: run the three-way feature check and the fingerprint check after registering.
        fingerprint: what a drifted golden-rollout fingerprint does: ``"error"``, ``"warn"`` or ``"off"``.
        check_steps: random-action steps of the feature check.
        recheck: run the checks even if they already passed for this repo@sha with the same packages
            and platform (a venv worker's: those of its venv; see :mod:`hub_envs.loading.check_cache`;
            ``hub-envs load --recheck=true`` and ``HUB_ENVS_RECHECK=1`` do the same).
        token, cache_dir: passed to huggingface_hub.
        config: for a local folder, config fields to set (``{"obs_type": "pixels_agent_pos"}``; values are
            decoded as LeRobot's ``--env.<field>=<value>`` flags are), the variant ``push_env --config.*``
            publishes. A Hub repo's config is the one it published (its own variant included).
        isolation: ``"none"`` (the env's code runs in this process), ``"process"`` (each env, or each group of
            ``envs_per_worker`` envs of ``make_vec``, runs in a worker process; this process never imports the
            env's code) or ``"venv"`` (the same, with the worker in a venv built with uv from the env's
            requirements, cached under ``$HUB_ENVS_HOME/venvs``). See :mod:`hub_envs.isolation`.
        sandbox: run the workers in a sandbox (implies ``isolation="process"``): no network, a read-only view
            of the files, no secrets in the environment, resource limits; fails closed where the machine does
            not allow a part of it (:class:`~hub_envs.errors.SandboxUnavailableError`).
        versions: ``"current"`` (the packages installed here); ``"publisher"`` (with ``isolation="venv"``): the
            venv pins the versions the publisher recorded.
        step_timeout: seconds a call into an isolated env may take before its worker is killed
            (:class:`~hub_envs.errors.EnvTimeoutError`); None: no limit (a sandbox: 60 s).
        restart: with isolation, ``reset()`` after a crash or timeout starts a fresh worker.
        envs_per_worker: with isolation, envs of one ``make_vec`` per worker process (0: spread over all CPUs but
            one; with fewer workers than CPUs both sides busy-wait, see :mod:`hub_envs.isolation.vector`).
        sandbox_limits: the sandbox's resource limits, any of ``memory_mb`` (default 4096: all its processes
            together, by a memory cgroup; asked for where none can be made, it is refused; the default then holds
            each process alone), ``open_files`` (256, per process) and ``processes`` (64, threads included, counted
            for the sandbox's uid).
        content_digest: the manifest content digest (64 hex, ``loaded.manifest.content_digest``) the load must find: a
            commit holding other content is refused with :class:`~hub_envs.errors.UntrustedCodeError` before anything
            of it is imported. A Ray worker gets the driver's, so consent given on the driver covers only that content.

    Returns:
        A :class:`LoadedEnv`.

    Raises:
        hub_envs.errors.HubEnvsError: a subclass naming what failed and what to do next.
    """
    if fingerprint not in ("error", "warn", "off"):
        raise ConfigError(f"fingerprint={fingerprint!r} is not a policy: pass 'error' (the default), 'warn' or 'off'.")
    if content_digest is not None and not (isinstance(content_digest, str) and trust_list._DIGEST.fullmatch(content_digest)):
        raise ConfigError(f"content_digest={content_digest!r}: pass a manifest's content digest (64 lowercase hex digits).")
    iso = _isolation_options(isolation, sandbox, versions, step_timeout, restart, envs_per_worker, sandbox_limits)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    report = LoadReport()
    if not isinstance(repo_id, (str, os.PathLike)) or not str(repo_id).strip():
        raise ConfigError(
            f"load_env needs a Hub repo id such as 'user/name' or 'user/name@<sha>', or an env folder; got {repo_id!r}."
        )
    machine = _in_background(check_cache.machine_identity)  # what the check cache keys on, while the files download
    src = _resolve_source(
        repo_id,
        revision=revision,
        trust_remote_code=trust_remote_code,
        config=config,
        token=token,
        cache_dir=cache_dir,
        report=report,
        timings=timings,
        t0=t0,
        content_digest=content_digest,
    )
    repo, sha, path, manifest = src.repo, src.sha, src.path, src.manifest
    local_folder, requested = src.local_folder, src.requested
    where = f"{repo}@{sha}"

    key = module_key(repo, sha)
    imported_before = is_imported(key)  # an earlier successful load of this repo@sha keeps its modules
    try:
        t = time.perf_counter()
        use_cache = check and local_folder is None and not (recheck or check_cache.recheck_forced())
        checks_key, cached_checks = "", None
        if iso.isolation != "venv":  # a venv worker brings the requirements itself: keyed once its venv is known
            checks_key = _checks_key(where, manifest, steps=check_steps, fingerprint=fingerprint, machine=machine.result())
            cached_checks = check_cache.lookup(checks_key) if use_cache else None
            if cached_checks is None:
                check_requirements(manifest.requirements, repo=where)
            # else: this repo@sha passed every stage before with exactly these installed distributions
        report.requirements = list(manifest.requirements)
        timings["requirements"] = time.perf_counter() - t

        t = time.perf_counter()
        # a published env's code runs from real files (its own folder for __file__.resolve()), not cache symlinks
        code = path if local_folder is not None else code_copy(path, manifest.files, repo, sha)
        owner = f"{repo}@{sha}"
        if iso.isolated:
            owner = f"{owner} ({_isolation_suffix(iso).lstrip('-')})"  # not the same registration as in-process
        try:
            with registration.registry_transaction() as txn:
                if iso.isolated:
                    env_class, config_class, isolated_config = _isolated_parts(
                        repo, sha, code, key, manifest, local_folder, iso, overrides=dict(config or {})
                    )
                    iso = env_class.options
                    if iso.isolation == "venv" and check:  # the checks run with the venv's packages: part of the key
                        worker = {**machine.result(), "worker_venv": check_cache.venv_identity(_VENVS[iso]["path"])}
                        checks_key = _checks_key(where, manifest, steps=check_steps, fingerprint=fingerprint, machine=worker)
                        cached_checks = check_cache.lookup(checks_key) if use_cache else None
                else:
                    package = import_env_folder(code, key)
                    env_class = resolve_entry_point(package, manifest.env_entry_point, where=f"{where}: env entry point")
                    config_class = resolve_entry_point(package, manifest.config_entry_point, where=f"{where}: config entry point")
                replaced, by_packages = txn.replaced_by(code)
                if replaced:
                    raise RegistrationConflictError(
                        f"{where}: its code replaced {', '.join(replaced)}, already registered by another package, with "
                        f"an entry of its own. Remove the env code's own gym.register / @EnvConfig.register_subclass calls: "
                        f"hub-envs registers the env itself, under names unique to the repo and commit."
                    )
                for distribution, names in by_packages.items():  # what importing that package does in any process
                    _log.info("%s: importing %s re-registered %s", where, distribution, ", ".join(names))
                if iso.isolated:
                    config = isolated_config
                else:
                    set_fields = manifest.config_overrides if local_folder is None else dict(config or {})
                    config = _checked_config(config_class, manifest, set_fields, where)
                qualifier = sha[:12] if not sha.startswith("local-") else sha
                suffix = _isolation_suffix(iso) if iso.isolated else ""
                reg = registration.register(
                    gym_id=f"{manifest.gym_id}-{qualifier.replace('local-', 'local')}{suffix}",
                    env_type=f"{manifest.env_type}@{qualifier}{suffix}",
                    owner=owner,
                    entry_point=env_class,
                    config_class=config_class,
                    max_episode_steps=int(config.episode_length),
                    kwargs=config.gym_kwargs,
                    disable_env_checker=bool(getattr(config, "disable_env_checker", True)),
                    register_choice=not iso.isolated or config_class is not None,
                )
                timings["import_register"] = time.perf_counter() - t
                loaded = LoadedEnv(
                    repo_id=repo,
                    revision=sha,
                    requested_revision=requested,
                    path=path,
                    manifest=manifest,
                    env_class=env_class,
                    config_class=config_class,
                    config=config,
                    registration_=reg,
                    report=report,
                    local_folder=local_folder,
                    isolation=iso,
                    token=token,
                    cache_dir=cache_dir,
                )
                if check:
                    t = time.perf_counter()
                    _run_load_checks(loaded, fingerprint=fingerprint, steps=check_steps, key=checks_key, cached=cached_checks)
                    timings["checks"] = time.perf_counter() - t
                if manifest.processors:
                    _check_processors(loaded, dry=check, where=where)
                t = time.perf_counter()
                _finish_fetch(
                    src, token=token, cache_dir=cache_dir
                )  # the card and meta/ downloaded while the code was imported and checked
                timings["fetch_rest"] = time.perf_counter() - t
        except BaseException:
            if not imported_before and not iso.isolated:
                forget_env_folder(key)
            raise
    except BaseException:
        if src.snapshot is not None:
            src.snapshot.cancel()  # nothing of a failed load keeps downloading
        raise
    timings["total"] = time.perf_counter() - t0
    report.timings = timings
    loaded._earlier = _LOADED.get(loaded.env_type)
    _LOADED[loaded.env_type] = loaded
    return loaded


def _in_background(fn: Callable[[], Any]) -> concurrent.futures.Future:
    """``fn()`` in a daemon thread of its own; its result (or exception) in the returned future."""
    future: concurrent.futures.Future = concurrent.futures.Future()

    def run() -> None:
        try:
            future.set_result(fn())
        except BaseException as e:  # noqa: BLE001 - handed to whoever asks for the result
            future.set_exception(e)

    threading.Thread(target=run, name="hub-envs-load-identity", daemon=True).start()
    return future


def _isolation_options(isolation, sandbox, versions, step_timeout, restart, envs_per_worker, sandbox_limits=None):
    """Validate load_env's isolation keywords; every option either works or is refused with a typed error."""
    from hub_envs.isolation.options import IsolationOptions

    if isolation not in ("none", "process", "venv"):
        raise ConfigError(f"isolation={isolation!r} is not an isolation mode: pass 'none' (the default), 'process' or 'venv'.")
    if versions not in ("current", "publisher"):
        raise ConfigError(f"versions={versions!r}: pass 'current' (the default) or 'publisher'.")
    if versions == "publisher" and isolation != "venv":
        raise ConfigError(
            f"versions='publisher' runs the env in a venv of the publisher's package versions: pass isolation='venv' "
            f"with it (isolation={isolation!r} runs the packages installed here)."
        )
    if step_timeout is not None and not (isinstance(step_timeout, (int, float)) and step_timeout > 0):
        raise ConfigError(f"step_timeout={step_timeout!r}: pass a positive number of seconds (or None for no limit).")
    if not isinstance(envs_per_worker, int) or envs_per_worker < 0:
        raise ConfigError(f"envs_per_worker={envs_per_worker!r}: pass a positive number (or 0 for the default).")
    limits = dict(sandbox_limits or {})
    names = {"memory_mb": "memory_limit_mb", "open_files": "max_open_files", "processes": "max_processes"}
    bad = {k: v for k, v in limits.items() if k not in names or not isinstance(v, int) or v < 1}
    if bad:
        raise ConfigError(
            f"sandbox_limits={bad!r}: pass positive integers for any of {', '.join(names)} (e.g. {{'memory_mb': 2048}})."
        )
    if limits and not sandbox:
        raise ConfigError("sandbox_limits only apply with sandbox=True (a worker without the sandbox has no limits).")
    if sandbox:
        isolation = "process" if isolation == "none" else isolation
        from hub_envs.isolation.sandbox import require_sandbox

        require_sandbox(limits.get("memory_mb"))  # SandboxUnavailableError naming what this machine does not allow
    return IsolationOptions(
        isolation=isolation,
        sandbox=bool(sandbox),
        step_timeout=step_timeout,
        restart=bool(restart),
        envs_per_worker=envs_per_worker,
        versions=versions,
        **{names[k]: v for k, v in limits.items()},
    )


def _isolation_suffix(iso) -> str:
    """What an isolated load's gym id and draccus name end with: the mode, and a digest of any non-default
    setting (two loads of one repo@sha with other settings are two registrations, never a conflict)."""
    import dataclasses
    import hashlib

    from hub_envs.isolation.options import IsolationOptions

    mode = iso.isolation + ("-sandbox" if iso.sandbox else "")
    mode = "sandbox" if mode == "process-sandbox" else mode
    settings = {f.name: getattr(iso, f.name) for f in dataclasses.fields(iso) if f.name not in ("python", "pythonpath")}
    default = dataclasses.asdict(IsolationOptions(isolation=iso.isolation, sandbox=iso.sandbox))
    if any(default[k] != v for k, v in settings.items()):
        mode += "-" + hashlib.sha256(repr(sorted(settings.items())).encode()).hexdigest()[:8]
    return f"-{mode}"


def _isolated_parts(repo, sha, path, key, manifest, local_folder, iso, overrides=None):
    """``(entry point, config class or None, config)`` of an isolated load: the gym entry point is a factory of
    proxies; the config comes from the verified manifest (a local folder's, which is your own code, is imported)."""
    from hub_envs.isolation.config import ManifestConfig
    from hub_envs.isolation.proxy import EnvTarget, IsolatedEnvFactory

    where = f"{repo}@{sha}"
    config_class = None
    if manifest.config:
        config = ManifestConfig(manifest.config, where=f"{where}: hub_env.json")
    elif local_folder is not None:
        package = import_env_folder(path, key)
        config_class = resolve_entry_point(package, manifest.config_entry_point, where=f"{where}: config entry point")
        validate_config_class(config_class, where=where)
        config = instantiate_config(config_class, where=where, overrides=overrides or None)
    else:
        raise InvalidRepoFormatError(
            f"{where}: the manifest records no config values, which an isolated load reads instead of importing the "
            f"env's code. Re-publish with push_env."
        )
    if iso.isolation == "venv":
        import dataclasses

        from hub_envs.isolation.venvs import hub_envs_path, venv_for, venv_python

        notes: list[str] = []
        if iso.versions == "publisher":
            from hub_envs.isolation.venvs import publisher_pins

            reqs, constraints, python, minor, notes = publisher_pins(
                manifest.requirements, dict(manifest.versions), dict(manifest.resolved), where=where
            )
            venv, record = venv_for(
                reqs, where=where, python=python, minor=minor, constraints=constraints, wheels_only=iso.sandbox
            )
        else:  # a sandboxed env's venv holds wheels only: building a package runs its code, outside the sandbox
            venv, record = venv_for(manifest.requirements, where=where, wheels_only=iso.sandbox)
        iso = dataclasses.replace(iso, python=str(venv_python(venv)), pythonpath=hub_envs_path())
        _VENVS[iso] = {**record, "path": str(venv), "notes": notes}
    target = EnvTarget(
        repo_id=repo,
        revision=sha,
        path=Path(path),
        key=key,
        entry_point=manifest.env_entry_point,
        files=tuple(sorted(code_files(manifest.files).items())),  # what ``path`` (the code copy) holds
        requirements=tuple(manifest.requirements),
    )
    factory = _FACTORIES.setdefault((target, iso), IsolatedEnvFactory(target, iso))  # one entry point per load setting
    return factory, config_class, config


#: What each venv worker setting runs: the venv's record (python, installed packages) and notes.
_VENVS: dict[Any, dict] = {}


def worker_versions(loaded: LoadedEnv) -> dict[str, Any] | None:
    """For an ``isolation="venv"`` load: the worker's venv record (``python``, ``installed``, ``notes``), else None."""
    return _VENVS.get(loaded.isolation) if loaded.isolation is not None else None


#: The gym entry point of each isolated repo@sha and setting (load_env's registration is idempotent per entry point).
_FACTORIES: dict[Any, Any] = {}


#: The envs load_env returned in this process, by draccus choice name (for integrations such as the LeRobot bridge).
_LOADED: dict[str, LoadedEnv] = {}


def loaded_env_for_type(env_type: str) -> LoadedEnv | None:
    """The :class:`LoadedEnv` whose draccus choice is ``env_type``, if load_env registered it in this process."""
    return _LOADED.get(env_type)


def ensure_dataset_files(
    repo_id: str, sha: str, path: Path, manifest: Manifest, *, token: str | None = None, cache_dir: str | Path | None = None
) -> None:
    """Make the dataset's data files of the snapshot ``path`` (``repo_id@sha``) present and verified against
    ``manifest``: fetch the missing ones (offline: :class:`DatasetNotCachedError`), check every sha256 (a
    mismatch removes the file from the cache and raises :class:`IntegrityError`)."""
    where = f"{repo_id}@{sha}"
    lazy = sorted(p for p in manifest.files if is_lazy_file(p))
    missing = [p for p in lazy if not (path / p).is_file()]
    if missing:
        if hub_io.offline():
            raise DatasetNotCachedError(
                f"{where}: {len(missing)} of the dataset's {len(lazy)} data file(s) are not in the local cache "
                f"(e.g. {safe_text(missing[0])}), and the Hub cannot be used (HF_HUB_OFFLINE is set). load_env "
                f"fetches the code and the dataset's meta/ only; fetch the data once online: unset HF_HUB_OFFLINE and "
                f"call loaded.fetch_dataset() (or open_dataset()), or "
                f'huggingface_hub.snapshot_download("{repo_id}", revision="{sha}", allow_patterns=["{DATASET_DIR}/*"]).'
            )
        hub_io.fetch_dataset_files(repo_id, sha, token=token, cache_dir=cache_dir)
    bad = [p for p in lazy if not (path / p).is_file() or sha256_file(path / p) != manifest.files[p]]
    if bad:
        for p in bad:
            _drop_cached_file(path / p)
        raise IntegrityError(
            f"{where}: {len(bad)} dataset file(s) are missing or differ from the manifest (sha256), e.g. {safe_text(bad[0])}. They "
            f"were removed from the cache; fetch again (loaded.fetch_dataset()). If it persists, the endpoint serves "
            f"other bytes than the publisher pushed: check HF_ENDPOINT."
        )
    hub_io.check_snapshot_layout(path, set(manifest.files), where=where)


def _drop_cached_file(path: Path) -> None:
    """Remove one file of a cache snapshot and the blob it links to (so the next fetch downloads it again)."""
    try:
        if path.is_symlink():
            target = Path(os.path.realpath(path))
            if target.parent.name == "blobs":
                target.unlink(missing_ok=True)
        path.unlink(missing_ok=True)
    except OSError:
        pass


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


def _checks_key(
    where: str, manifest: Manifest, *, steps: int, fingerprint: FingerprintPolicy, machine: dict | None = None
) -> str:
    recorded = manifest.fingerprint
    return check_cache.check_key(
        machine=machine,
        owner=where,
        content_digest=manifest.content_digest,
        requirements=manifest.requirements,
        settings={
            "steps": steps,
            "seed": int(manifest.seeds.get("check", 0)),
            "fingerprint": fingerprint,
            "recorded": recorded.get("digest") if recorded else None,
        },
    )


def _run_load_checks(loaded: LoadedEnv, *, fingerprint: FingerprintPolicy, steps: int, key: str, cached: dict | None) -> None:
    where = f"{loaded.repo_id}@{loaded.revision}"
    recorded = loaded.manifest.fingerprint
    if cached is not None:
        loaded.report.features = FeatureReport.from_dict(cached["features"])
        venv = " in the same worker venv" if loaded.worker_venv is not None else ""
        loaded.report.fingerprint = (
            f"{cached['fingerprint']} (cached: passed on {cached['checked_at']} with the same packages{venv}; "
            f"recheck=True, or hub-envs load --recheck=true, runs the checks again)"
        )
        return
    dataset_features = None
    dataset_dir = loaded.manifest.dataset.get("path") if loaded.manifest.dataset else None
    if loaded.dataset_meta_root is not None or dataset_dir:  # meta/info.json: no data file is fetched
        try:
            info = read_info(loaded.path / (dataset_dir or DATASET_DIR))
        except DatasetError as e:
            raise DatasetError(f"{where}: the manifest lists a dataset, but {e} Re-publish with push_env.") from e
        dataset_features = info.get("features", {})
    try:
        env = loaded.make()
    except HubEnvsError:
        raise
    except Exception as e:
        raise EnvCodeError(
            f"{where}: making the env ({loaded.manifest.env_entry_point} with its config's gym_kwargs) raised "
            f"{type(e).__name__}: {e}. Fix the env's __init__."
        ) from e
    handed_over = False  # the fingerprint's rollouts reuse this env (reset(seed) determines an episode) and close it
    try:
        report = check_features(
            loaded.config, env, dataset_features, steps=steps, seed=int(loaded.manifest.seeds.get("check", 0)), where=where
        )
        loaded.report.features = report
        report.raise_if_mismatch(where)
        if fingerprint == "off" or not recorded:
            loaded.report.fingerprint = "off" if fingerprint == "off" else "none recorded"
            check_cache.store(key, {"features": report.to_dict(), "fingerprint": loaded.report.fingerprint})
            return

        handed_over = True
        try:  # the versions are read only for the error message (milliseconds)
            verify_fingerprint(lambda: env, recorded, where=where, versions_note=lambda: drift_note(loaded))
            loaded.report.fingerprint = f"matches ({len(recorded['seeds'])} seeds x {recorded['steps']} steps)"
            check_cache.store(key, {"features": report.to_dict(), "fingerprint": loaded.report.fingerprint})
        except FingerprintMismatchError as e:
            if fingerprint == "error":
                raise
            loaded.report.fingerprint = f"DRIFTED: {e}"
            warnings.warn(str(e), stacklevel=3)
    finally:
        if not handed_over:
            env.close()
