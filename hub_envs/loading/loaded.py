"""The handle ``load_env`` returns: :class:`LoadedEnv` (make envs, the dataset, the media, the processors) and its
:class:`LoadReport`; the envs loaded in this process, by draccus choice."""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym

from hub_envs._compat import video_backend
from hub_envs.dataset.reader import check_videos
from hub_envs.envcode.envconfig import instantiate_config
from hub_envs.envcode.registration import Registration, unregister
from hub_envs.errors import ConfigError, InvalidRepoFormatError
from hub_envs.harness.features import FeatureReport
from hub_envs.loading.dataset_files import ensure_dataset_files, ensure_media_file
from hub_envs.loading.isolated import config_in_worker, isolated_vector_env, worker_versions
from hub_envs.repo.format import DATASET_DIR, Manifest


@dataclass
class LoadReport:
    """What load_env checked, and how long each stage took (seconds).

    Attributes:
        integrity: how the files were verified (``"41 files match the manifest"``).
        trust: what the consent to run the code was (``"trust_remote_code=True"``, ``"trust list (...)"``).
        requirements: the requirements the preflight checked.
        features: the three-way feature check (declared / live / dataset), None if not run.
        fingerprint: what the golden-rollout fingerprint check found.
        timings: seconds per stage (``fetch_verify``, ``requirements``, ``import_register``, ``checks``, ...).
    """

    integrity: str = "not checked"
    trust: str = "not needed"
    requirements: list[str] = field(default_factory=list)
    features: FeatureReport | None = None
    fingerprint: str = "not checked"
    timings: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """The report as JSON-ready data (``hub-envs load --json``)."""
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
        config_class: the repo's EnvConfig subclass (None when isolated: this process never imports the env's code).
        config: an instance of the repo's EnvConfig subclass, with its published defaults (isolated: a read-only
            :class:`~hub_envs.isolation.config.ManifestConfig` of the manifest's values). A load whose checks passed before
            (cached) imports the config's module, and LeRobot with it, only when one of these two is first asked for.
        manifest: the parsed ``hub_env.json``.
        path: the local snapshot folder.
        report: the :class:`LoadReport`.
        local_folder: the env folder it was loaded from (None: from the Hub).
        isolation: how the env's code runs (:class:`hub_envs.isolation.IsolationOptions`); None: in this process.
        token: the Hub token this load downloaded with (None: huggingface_hub's own); a Ray worker downloads with it.
        plain_source: for a plain LeRobot EnvHub repo (no ``hub_env.json``): ``user/name@<sha>[:path]``; else None.
        missing_guarantees: what this load cannot guarantee (a plain repo: no manifest digest, no dataset, no
            fingerprint, no declared features); empty for a repo published by push_env.
    """

    plain_source: str | None = None
    missing_guarantees: tuple[str, ...] = ()

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
        registration: Registration,
        report,
        local_folder=None,
        isolation=None,
        token=None,
        cache_dir=None,
        deferred_config=None,
    ):
        self.repo_id: str = repo_id
        self.revision: str = revision
        self.requested_revision: str | None = requested_revision
        self.path: Path = Path(path)
        self.manifest: Manifest = manifest
        self.env_class = env_class
        self._config_class = config_class
        self._config = config
        self._deferred_config = deferred_config  # imports the config class and computes the config on first use
        self._registration = registration
        self.report: LoadReport = report
        self.local_folder: Path | None = local_folder
        self.isolation = isolation if isolation is not None and isolation.isolated else None
        self.token = token
        self._cache_dir = cache_dir
        self._dataset_verified = False
        self._unregistered = False
        self._earlier: LoadedEnv | None = None  # the load of the same env_type this one replaced in _LOADED (remember)
        self._task: str | None = None  # a suite's task this handle makes (for_task); None: the published config's

    # -- a benchmark suite --
    @property
    def tasks(self) -> list[str]:
        """A suite's tasks (values of the config's ``task`` field, in task-id order); ``[]`` for a one-task env."""
        return self.manifest.task_names

    @property
    def is_suite(self) -> bool:
        """Whether the repo is a benchmark suite (several tasks, ``[tool.hub-envs] tasks``)."""
        return bool(self.manifest.tasks)

    @property
    def task(self) -> str | None:
        """The suite task this handle makes (:meth:`for_task`); None: the published config's own."""
        return self._task

    def for_task(self, task: str) -> LoadedEnv:
        """This env, making one task of its suite: ``make``, ``make_vec``, ``config`` and the backends follow it.

        Shares this load's registration and imported code (releasing it stays with this handle).

        Args:
            task: one of :attr:`tasks`.

        Returns:
            A :class:`LoadedEnv` whose config has ``task`` set.

        Raises:
            ConfigError: not one of the suite's tasks (the message lists them).
        """
        self.manifest.task_record(task)  # ConfigError naming the tasks
        view = copy.copy(self)
        view._config = self.config_with({"task": task})
        view._task = task
        view._unregistered = True  # this handle's unregister() does nothing: the load it came from owns the names
        return view

    def make_suite(
        self, n_envs: int = 1, use_async: bool = False, tasks: Sequence[str] | None = None
    ) -> dict[str, dict[Any, gym.vector.VectorEnv]]:
        """The suite as LeRobot's ``make_env`` returns one: ``{suite name: {task id: VectorEnv}}``, task ids being each
        task's index in :attr:`tasks` (a one-task env: ``{name: {0: VectorEnv}}``; a plain EnvHub repo's suite: the suite
        names and task ids its ``make_env`` gives).

        Args:
            n_envs: envs per task.
            use_async: as :meth:`make_vec`.
            tasks: the tasks to make (default: all).

        Returns:
            The mapping.

        Raises:
            ConfigError: a task that is not the suite's, or ``n_envs`` below 1.
        """
        if not self.is_suite:
            return {self.manifest.name: {0: self.make_vec(n_envs, use_async)}}
        chosen = list(self.tasks if tasks is None else tasks)
        views = [self.for_task(t) for t in chosen]  # every name checked before any env is made
        suite: dict[str, dict[Any, gym.vector.VectorEnv]] = {}
        for view in views:  # a plain repo's suite keeps its own suite names and task ids (its records say them)
            record = self.manifest.task_record(view.task)
            key = record.get("suite", self.manifest.name)
            suite.setdefault(key, {})[record.get("task_id", record["task_index"])] = view.make_vec(n_envs, use_async)
        return suite

    @property
    def config_class(self) -> type | None:
        """The repo's EnvConfig subclass (None when isolated), its module imported on first use."""
        if self._config_class is None and self._deferred_config is not None:
            self._config_class = self._deferred_config.config_class()
        return self._config_class

    @property
    def config(self) -> Any:
        """The repo's EnvConfig instance with its published defaults (isolated: a ``ManifestConfig``), computed on first use
        and checked against the manifest's values then (:class:`~hub_envs.errors.InvalidRepoFormatError` if they differ)."""
        if self._config is None and self._deferred_config is not None:
            self._config = self._deferred_config.config()
        return self._config

    @property
    def worker_venv(self) -> dict[str, Any] | None:
        """For an ``isolation="venv"`` load: the worker's venv record (``path``, ``python``, ``installed``, ``notes``)."""
        return worker_versions(self.isolation)

    @property
    def runs_as(self) -> str:
        """How the env's code runs, as reports record it: ``none`` (in this process), ``process``, ``venv``,
        ``process+sandbox``, ``venv+publisher`` (the publisher's package versions), ..."""
        return "none" if self.isolation is None else self.isolation.label

    # -- names --
    @property
    def gym_id(self) -> str:
        """The id registered with gymnasium (``gym.make(loaded.gym_id)``), unique per revision."""
        return self._registration.gym_id

    @property
    def env_type(self) -> str:
        """The draccus choice name (``--env.type=<env_type>``), unique per revision."""
        return self._registration.env_type

    @property
    def is_local(self) -> bool:
        """Whether it was loaded from a local folder."""
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

        Once per LoadedEnv; files already in the cache are not downloaded again.

        Returns:
            The dataset folder of the snapshot, or None if the repo has no dataset.

        Raises:
            DatasetNotCachedError: offline, and files are missing from the cache.
            IntegrityError: a file differs from the manifest (the bad files are removed from the cache).
        """
        root = self.dataset_meta_root
        if root is None or self._dataset_verified or self.is_local:
            return root
        ensure_dataset_files(self.repo_id, self.revision, self.path, self.manifest, token=self.token, cache_dir=self._cache_dir)
        self._dataset_verified = True
        return root

    def media_file(self, name: str = "rollout.gif") -> Path:
        """The card's media file ``media/<name>``, fetched on first use and checked against the manifest's sha256 (load_env
        leaves the media on the Hub: only the card and the web page show them).

        Args:
            name: ``rollout.gif``; ``rollout.mp4`` when the dataset stores video.

        Returns:
            The file's path.

        Raises:
            InvalidRepoFormatError: the repo has no such media file.
            OfflineNotCachedError: offline, and the file is not in the cache.
            IntegrityError: the file differs from the manifest (it was removed from the cache).
        """
        return ensure_media_file(
            self.repo_id,
            self.revision,
            self.path,
            self.manifest,
            name,
            local=self.is_local,
            token=self.token,
            cache_dir=self._cache_dir,
        )

    def config_with(self, fields: Mapping[str, Any]) -> Any:
        """The config with ``fields`` set, on top of a published variant's own (``manifest.config_overrides``), before the
        config's ``__post_init__``.

        Args:
            fields: config fields, values decoded as LeRobot's ``--env.<field>=<value>`` flags are.

        Returns:
            In-process: an instance of :attr:`config_class`. Isolated: the repo's config class runs in a worker (this
            process never imports the repo's code) and what it computed comes back as a read-only
            :class:`~hub_envs.isolation.config.ManifestConfig`; the envs made from it follow it the same way.

        Raises:
            ConfigError: a field the config does not have (the message names its fields).
        """
        where = str(self.local_folder) if self.is_local else f"{self.repo_id}@{self.revision}"
        fields = {**self.manifest.config_overrides, **fields}
        if self.config_class is not None:
            return instantiate_config(self.config_class, where=where, overrides=fields)
        return config_in_worker(self.gym_id, self.isolation, self.manifest.config_entry_point, fields, where=where)

    def load_line(self) -> str:
        """The Python line that loads this env again, pinned (``load_env("user/name@<sha>", trust_remote_code=True)``)."""
        if self.is_local:
            return f'load_env("{self.local_folder}")'
        return f'load_env("{self.plain_source or f"{self.repo_id}@{self.revision}"}", trust_remote_code=True)'

    # -- making envs --
    def make(self, cfg=None, **kwargs) -> gym.Env:
        """``gym.make`` this env.

        Args:
            cfg: an instance of :attr:`config_class` whose ``gym_kwargs`` and ``episode_length`` override the defaults.
            kwargs: more ``gym.make`` keywords.

        Returns:
            The env (isolated: a proxy of one running in a worker process).
        """
        cfg = cfg if cfg is not None or self._task is None else self.config  # a suite task's own config
        if cfg is not None:
            kwargs = {**cfg.gym_kwargs, "max_episode_steps": cfg.episode_length, **kwargs}
        return gym.make(self.gym_id, **kwargs)

    def make_vec(self, n_envs: int = 1, use_async: bool = False, cfg=None, **kwargs) -> gym.vector.VectorEnv:
        """A vector env of ``n_envs`` copies.

        Args:
            n_envs: how many envs.
            use_async: one process each, forked so the registration carries over (isolated: does not apply, the workers
                always step side by side).
            cfg: as for :meth:`make`.
            kwargs: more ``gym.make`` keywords.

        Returns:
            A ``SyncVectorEnv`` or ``AsyncVectorEnv``; isolated, an :class:`~hub_envs.isolation.vector.IsolatedVectorEnv`.

        Raises:
            ConfigError: ``n_envs`` below 1.
        """
        if n_envs < 1:
            raise ConfigError(f"n_envs must be at least 1, got {n_envs}.")
        cfg = cfg if cfg is not None or self._task is None else self.config  # a suite task's own config
        if cfg is not None:
            kwargs = {**cfg.gym_kwargs, "max_episode_steps": cfg.episode_length, **kwargs}
        if self.isolation is not None:
            return isolated_vector_env(self.gym_id, self.isolation, n_envs, kwargs)
        fns = [lambda: self.make(**kwargs) for _ in range(n_envs)]
        if use_async:
            return gym.vector.AsyncVectorEnv(fns, context="fork")
        return gym.vector.SyncVectorEnv(fns)

    def open_dataset(self, **kwargs):
        """The bundled random-action dataset as a ``LeRobotDataset``, read from the snapshot; its data
        files are fetched and verified first if load_env left them out (see :meth:`fetch_dataset`). Video
        features decode with the backend that works here (torchcodec if it loads, else pyav:
        :func:`hub_envs._compat.video_backend`) unless ``video_backend=`` is given. The MP4s of video features
        are checked to decode (a truncated or damaged file raises :class:`IntegrityError`, not a decode crash
        inside a DataLoader).

        Args:
            **kwargs: more ``LeRobotDataset`` keywords (``episodes``, ``delta_timestamps``, ``video_backend``...).

        Returns:
            A ``lerobot.datasets.lerobot_dataset.LeRobotDataset`` rooted at the verified snapshot.

        Raises:
            InvalidRepoFormatError: the repo has no ``dataset/``.
            DatasetNotCachedError: offline, and data files are missing (see :meth:`fetch_dataset`).
            IntegrityError: a data file differs from the manifest, or a video does not decode.
        """
        from lerobot.datasets.lerobot_dataset import LeRobotDataset  # heavy: lerobot's datasets, torch

        root = self.fetch_dataset()
        if root is None:
            raise InvalidRepoFormatError(
                f"{self.repo_id}@{self.revision} has no dataset/ (a local folder gets one from push_env)."
            )
        if check_videos(root):
            kwargs.setdefault("video_backend", video_backend())
        return LeRobotDataset(self.repo_id, root=root, **kwargs)

    def processors(self, cfg=None):
        """Fresh ``(env_preprocessor, env_postprocessor)`` LeRobot pipelines of the steps the repo declares (empty ones when it
        declares none; :mod:`hub_envs.loading.processors`).

        Args:
            cfg: a config instance (default: the published one).

        Returns:
            Two ``PolicyProcessorPipeline`` s.
        """
        from hub_envs.loading.processors import pipelines_for  # heavy: torch, lerobot's processors

        return pipelines_for(self, cfg)

    def unregister(self) -> None:
        """Release this load's gym id and draccus choice (the imported modules stay cached). Another load of the
        same repo@sha shares them: they go when the last of those is unregistered. A second call does nothing."""
        if self._unregistered:
            return
        self._unregistered = True
        unregister(self._registration)
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
        task = f", task={self._task!r}" if self._task is not None else ""
        return f"LoadedEnv({self.repo_id}@{self.revision[:12]}, gym_id={self.gym_id!r}, env_type={self.env_type!r}{task})"


#: The envs load_env returned in this process, by draccus choice name (for integrations such as the LeRobot bridge).
_LOADED: dict[str, LoadedEnv] = {}


def remember(loaded: LoadedEnv) -> None:
    """Make ``loaded`` what :func:`loaded_env_for_type` finds for its draccus choice (the load it replaces comes back
    when ``loaded`` is unregistered).

    Args:
        loaded: a load that just succeeded.
    """
    loaded._earlier = _LOADED.get(loaded.env_type)
    _LOADED[loaded.env_type] = loaded


def loaded_env_for_type(env_type: str) -> LoadedEnv | None:
    """The load behind a draccus choice, for integrations such as the LeRobot bridge.

    Args:
        env_type: a draccus choice name (``--env.type``).

    Returns:
        The :class:`LoadedEnv` whose choice it is, if load_env registered it in this process; else None.
    """
    return _LOADED.get(env_type)
