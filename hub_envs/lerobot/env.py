"""Hub envs as LeRobot env configs: the generic ``--env.type=hub`` choice (:class:`HubEnv`), LeRobot-ready vector envs and
env processors (:func:`make_env`, :func:`make_env_pre_post_processors`), and the hooks that put them in LeRobot's scripts.

Example:
    >>> import draccus
    >>> from lerobot.configs.eval import EvalPipelineConfig
    >>> from hub_envs.lerobot.env import HubEnv, make_env
    >>> cfg = draccus.parse(EvalPipelineConfig, args=["--env.type=hub", "--env.repo_id=user/pendulum-lerobot",
    ...     "--env.revision=<sha>", "--env.trust_remote_code=true"])                     # doctest: +SKIP
    >>> envs = make_env(cfg.env, n_envs=2)                                               # doctest: +SKIP
"""

from __future__ import annotations

import copy
import dataclasses
import typing
from dataclasses import dataclass, field
from typing import Any, Unpack

import draccus
import gymnasium as gym
from lerobot.envs.configs import EnvConfig

from hub_envs._compat import env_configs_create_envs, hf_transform_to_torch, route_lerobot_scripts
from hub_envs.dataset.reader import read_hub_envs_meta
from hub_envs.envcode.registration import owner_of_choice
from hub_envs.errors import ConfigError, DatasetError, UntrustedCodeError
from hub_envs.harness.actions import IntegerActions
from hub_envs.loading.isolated import CodeRun, code_run
from hub_envs.loading.load import load_env
from hub_envs.loading.loaded import LoadedEnv, loaded_env_for_type

HUB_CHOICE = "hub"

#: (repo_id, revision, fingerprint, check) -> LoadedEnv, so re-building a config does not re-run the checks.
#: An entry exists only once load_env passed its trust gate for that exact commit in this process (its code
#: is already imported here), so a config rebuilt later (decoded from train_config.json) reuses it.
_CACHE: dict[tuple, LoadedEnv] = {}

#: Consent given on the command line being parsed (hub-envs train / eval, LeRobot's CLIs through the plugin):
#: while set, it is the only consent a hub env config gets; what a --config_path file says is ignored.
_CLI_CONSENT: list[bool] = []


def set_cli_consent(trust_remote_code: bool | None) -> None:
    """Declare the consent of the command line LeRobot is about to parse.

    Args:
        trust_remote_code: the command line's ``--env.trust_remote_code`` (None: no command line, a Python call).
    """
    _CLI_CONSENT.clear()
    if trust_remote_code is not None:
        _CLI_CONSENT.append(bool(trust_remote_code))


def load_cached(
    repo_id: str,
    revision: str | None = None,
    *,
    trust_remote_code: bool = False,
    fingerprint: str = "error",
    check: bool = True,
    **run: Unpack[CodeRun],
) -> LoadedEnv:
    """:func:`hub_envs.load_env`, once per process for the same arguments.

    Args:
        repo_id, revision, trust_remote_code, fingerprint, check: as :func:`hub_envs.load_env` takes them.
        run: how the env's code runs (:class:`~hub_envs.loading.isolated.CodeRun`).

    Returns:
        The :class:`~hub_envs.loading.loaded.LoadedEnv` (the same one while it stays registered).

    Raises:
        HubEnvsError: as :func:`hub_envs.load_env`.
    """
    iso = tuple(sorted(code_run(run, "load_cached", complete=True).items()))
    key = (repo_id, revision, fingerprint, bool(check), iso)
    loaded = _CACHE.get(key)
    if loaded is not None and loaded_env_for_type(loaded.env_type) is loaded:
        return loaded
    try:
        loaded = load_env(
            repo_id,
            revision=revision,
            trust_remote_code=trust_remote_code,
            fingerprint=fingerprint,
            check=check,
            **run,
        )
    except UntrustedCodeError as e:
        raise UntrustedCodeError(f"{e}\nWith LeRobot's CLIs (hub-envs train / eval): add --env.trust_remote_code=true.") from None
    _CACHE[key] = loaded
    if not loaded.is_local:
        _CACHE[(loaded.repo_id, loaded.revision, fingerprint, bool(check), iso)] = loaded
    return loaded


def _typed_overrides(config_class: type, overrides: dict[str, Any], *, where: str) -> dict[str, Any]:
    names = {f.name: f for f in dataclasses.fields(config_class) if f.init}
    unknown = sorted(set(overrides) - set(names))
    if unknown:
        raise ConfigError(
            f"{where}: --env.overrides has {unknown}, which {config_class.__qualname__} does not have; "
            f"its fields are {sorted(names)}."
        )
    try:
        hints = typing.get_type_hints(config_class)
    except Exception:
        hints = {}
    out = {}
    for name, value in overrides.items():
        if name in hints:
            try:
                value = draccus.decode(hints[name], value)
            except Exception as e:
                raise ConfigError(f"{where}: --env.overrides {name}={value!r} is not a valid {hints[name]}: {e}") from None
        out[name] = value
    return out


@EnvConfig.register_subclass(HUB_CHOICE)
@dataclass
class HubEnv(EnvConfig):
    """``--env.type=hub``: any env repo by id, pinned to a commit, with its own config's values.

    Fields (flags ``--env.<field>``):
        repo_id: ``user/name`` (``user/name@rev`` works too) or a local env folder.
        revision: a commit sha (pin it), tag or branch; replaced by the resolved sha once loaded.
        trust_remote_code: consent to run the repo's code (or ``hub-envs trust user/name@sha`` once). Only
            from the command line (``--env.trust_remote_code=true``) or a Python call: never read from a
            ``--config_path`` file, and always saved as ``false`` (a shared config cannot carry consent).
        overrides: values for the repo config's own fields, e.g. ``--env.overrides='{obs_type: pixels_agent_pos}'``.
        task, fps, episode_length: override the repo config's (default: the repo's). A benchmark suite: ``task`` names
            the tasks to make, comma-separated as LeRobot's multi-task configs do (default: all of them), each its own
            task id in ``{suite: {task id: VectorEnv}}``, so ``lerobot-eval`` reports every task and the suite.
        fingerprint: ``error`` / ``warn`` / ``off``, what a drifted golden rollout does at load.
        check: run load_env's feature and fingerprint checks.
        isolation, sandbox, versions: run the env in worker processes / a sandbox / a venv of the publisher's
            versions (see :func:`hub_envs.load_env`). With isolation, ``overrides`` / ``task`` / ``fps`` /
            ``episode_length`` are applied by the repo's config class in a worker (it is not imported here).
    """

    repo_id: str | None = None
    revision: str | None = None
    trust_remote_code: bool = False
    overrides: dict[str, Any] = field(default_factory=dict)
    fps: int | None = None
    episode_length: int | None = None
    fingerprint: str = "error"
    check: bool = True
    isolation: str = "none"
    sandbox: bool = False
    versions: str = "current"

    def __post_init__(self) -> None:
        if not self.repo_id:
            raise ConfigError("--env.type=hub needs --env.repo_id=user/name (and --env.revision=<sha> to pin it).")
        if self.fingerprint not in ("error", "warn", "off"):
            raise ConfigError(f"--env.fingerprint={self.fingerprint!r}: use error, warn or off.")
        consent = _CLI_CONSENT[0] if _CLI_CONSENT else bool(self.trust_remote_code)
        self.trust_remote_code = False  # consent is not part of what a run's config describes, nor saved with it
        run = CodeRun(isolation=self.isolation, sandbox=self.sandbox, versions=self.versions)
        loaded = load_cached(
            self.repo_id, self.revision, trust_remote_code=consent, fingerprint=self.fingerprint, check=self.check, **run
        )
        where = f"{loaded.repo_id}@{loaded.revision}"
        overrides = dict(self.overrides or {})
        self._suite_tasks = suite_selection(loaded, self.task if loaded.is_suite else None, where=where)
        if self._suite_tasks:  # the suite's tasks, each made with its own config (create_envs)
            overrides["task"] = self._suite_tasks[0]  # the features are the same for every task (push_env checks it)
            self.task = None
        for name in ("task", "fps", "episode_length"):
            if getattr(self, name) is not None and (
                loaded.config_class is not None or getattr(self, name) != getattr(loaded.config, name, None)
            ):
                overrides.setdefault(name, getattr(self, name))
        if overrides and loaded.config_class is not None:
            overrides = _typed_overrides(loaded.config_class, overrides, where=where)
        # in-process, the repo's config class; isolated, what it computed in a worker (see LoadedEnv.config_with)
        env_cfg = loaded.config_with(overrides) if overrides else loaded.config
        self._loaded = loaded
        self._env_config = env_cfg
        self._overrides = overrides
        if not loaded.is_local:
            self.repo_id, self.revision = loaded.repo_id, loaded.revision
        self.task = ",".join(self._suite_tasks) if self._suite_tasks else env_cfg.task
        self.fps = int(env_cfg.fps)
        self.episode_length = int(env_cfg.episode_length)
        self.features = dict(env_cfg.features)
        self.features_map = dict(env_cfg.features_map)

    def __deepcopy__(self, memo):
        # a copy of the config names the same loaded env (imported code and registrations are per process)
        new = type(self).__new__(type(self))
        memo[id(self)] = new
        for key, value in self.__dict__.items():
            setattr(new, key, value if key == "_loaded" else copy.deepcopy(value, memo))
        return new

    @property
    def loaded(self) -> LoadedEnv:
        """The :class:`~hub_envs.loading.loaded.LoadedEnv` this config names."""
        return self._loaded

    @property
    def env_config(self) -> EnvConfig:
        """The repo's own config instance (its class, with the overrides applied)."""
        return self._env_config

    @property
    def gym_id(self) -> str:
        return self._loaded.gym_id

    @property
    def gym_kwargs(self) -> dict:
        # for LeRobot's own make_env: gym.make(gym_id, **gym_kwargs) honours episode_length this way
        return {**self._env_config.gym_kwargs, "max_episode_steps": int(self.episode_length)}

    # LeRobot >= 0.5 asks the config itself for its envs and env processors (0.4 branches in its factory,
    # where install_hooks routes hub env configs here).
    def create_envs(self, n_envs: int, use_async_envs: bool = False) -> dict[str, dict[int, gym.vector.VectorEnv]]:
        """LeRobot >= 0.5's env creation (:func:`make_vec_env`).

        Args:
            n_envs: how many envs.
            use_async_envs: one process each.

        Returns:
            ``{name: {0: VectorEnv}}``; a suite: ``{name: {task id: VectorEnv}}`` of the tasks ``task`` names (default all).
        """
        if self._suite_tasks:
            configs = {t: self._loaded.config_with({**self._overrides, "task": t}) for t in self._suite_tasks}
            return suite_vec_envs(self._loaded, configs, n_envs, use_async_envs)
        return {self._loaded.manifest.name: {0: make_vec_env(self._loaded, self._env_config, n_envs, use_async_envs)}}

    def get_env_processors(self):
        """The repo's declared env processors as ``(env_preprocessor, env_postprocessor)`` LeRobot pipelines."""
        return self._loaded.processors(self._env_config)


# --- vector envs and processors for LeRobot's eval loop ---------------------------------------


class TaskDescription(gym.Wrapper):
    """Exposes the config's ``task`` string (and a suite task's instruction) to LeRobot's eval loop (``add_envs_task``)."""

    def __init__(self, env: gym.Env, task: str, description: str | None = None):
        super().__init__(env)
        self.task = task
        self.task_description = description or task


def suite_selection(loaded: LoadedEnv, task: str | None, *, where: str) -> list[str]:
    """The suite tasks a LeRobot config names: ``task`` comma-separated (LeRobot's multi-task convention), or all.

    Args:
        loaded: the load (a one-task env: ``[]``).
        task: the config's ``task`` (None: all the suite's tasks).
        where: names the repo in messages.

    Returns:
        The task names, in the order given (``[]`` for a one-task env).

    Raises:
        ConfigError: a name that is not one of the suite's tasks (the message lists them).
    """
    if not loaded.is_suite:
        return []
    if not task:
        return list(loaded.tasks)
    chosen = [t.strip() for t in str(task).split(",") if t.strip()]
    unknown = [t for t in chosen if t not in loaded.tasks]
    if unknown or not chosen:
        raise ConfigError(
            f"{where}: --env.task={task!r} names {unknown or 'nothing'}, not tasks of this suite; its tasks are "
            f"{loaded.tasks} (name one or several, comma-separated, or leave --env.task out for all)."
        )
    return chosen


def suite_vec_envs(
    loaded: LoadedEnv, configs: dict[str, EnvConfig], n_envs: int = 1, use_async_envs: bool = False
) -> dict[str, dict[int, gym.vector.VectorEnv]]:
    """A suite's tasks as LeRobot's ``make_env`` returns a multi-task benchmark: ``{suite name: {task id: VectorEnv}}``,
    each task's envs made from its config (:func:`make_vec_env`) and stating its instruction as ``task_description``.

    Args:
        loaded: a suite's load.
        configs: ``{task name: its config}`` of the tasks to make.
        n_envs, use_async_envs: per task, as :func:`make_vec_env`.

    Returns:
        The mapping; the task id is the task's index in ``loaded.tasks`` (a plain EnvHub repo's suite: its own suite
        names and task ids).
    """
    out: dict = {}
    for task, cfg in configs.items():
        record = loaded.manifest.task_record(task)
        vec = make_vec_env(loaded, cfg, n_envs, use_async_envs, description=record["instruction"])
        # a plain EnvHub repo's suite keeps the suite names and task ids its own make_env gives
        out.setdefault(record.get("suite", loaded.manifest.name), {})[record.get("task_id", record["task_index"])] = vec
    return out


def loaded_for(cfg: Any) -> tuple[LoadedEnv, EnvConfig] | None:
    """The load behind a hub env config.

    Args:
        cfg: LeRobot's ``cfg.env``.

    Returns:
        ``(loaded env, repo config instance)`` for a hub env config (``hub`` or a per-repo choice), else None.
    """
    if isinstance(cfg, HubEnv):
        return cfg.loaded, cfg.env_config
    if isinstance(cfg, EnvConfig):
        try:
            env_type = cfg.type
        except Exception:
            return None
        loaded = loaded_env_for_type(env_type) if owner_of_choice(env_type) else None
        if loaded is not None and isinstance(cfg, loaded.config_class):
            return loaded, cfg
    return None


def make_vec_env(
    loaded: LoadedEnv,
    cfg: EnvConfig | None = None,
    n_envs: int = 1,
    use_async_envs: bool = False,
    description: str | None = None,
) -> gym.vector.VectorEnv:
    """``n_envs`` copies of a loaded env, as LeRobot's eval loop expects them: ``AutoresetMode.SAME_STEP`` (so
    ``info["final_info"]["is_success"]`` is there), the config's ``episode_length`` as time limit, its ``task`` exposed as
    ``task``/``task_description``.

    Args:
        loaded: a :class:`~hub_envs.loading.loaded.LoadedEnv`.
        cfg: a config instance (default: the published one).
        n_envs: how many envs.
        use_async_envs: one process each.
        description: the ``task_description`` the envs state (default: the config's ``task``).

    Returns:
        The vector env.

    Raises:
        ConfigError: ``n_envs`` below 1.
    """
    if n_envs < 1:
        raise ConfigError(f"n_envs must be at least 1, got {n_envs}.")
    cfg = cfg if cfg is not None else loaded.config
    gym_id, kwargs, steps = loaded.gym_id, dict(cfg.gym_kwargs), int(cfg.episode_length)
    task = cfg.task if isinstance(cfg.task, str) else None

    def _one():
        env = gym.make(gym_id, max_episode_steps=steps, disable_env_checker=True, **kwargs)
        if isinstance(env.action_space, (gym.spaces.Discrete, gym.spaces.MultiDiscrete)):
            env = IntegerActions(env)  # LeRobot's policies give floats
        return TaskDescription(env, task, description) if task is not None else env

    fns = [_one for _ in range(n_envs)]
    mode = gym.vector.AutoresetMode.SAME_STEP
    if use_async_envs:
        return gym.vector.AsyncVectorEnv(fns, context="fork", autoreset_mode=mode)
    return gym.vector.SyncVectorEnv(fns, autoreset_mode=mode)


def make_env(
    cfg, n_envs: int = 1, use_async_envs: bool = False, hub_cache_dir: str | None = None, trust_remote_code: bool = False
) -> dict[str, dict[int, gym.vector.VectorEnv]]:
    """LeRobot's ``make_env``: hub env configs get :func:`make_vec_env`, others LeRobot's own. A hub env config was loaded
    through load_env's trust gate when it was built, so LeRobot's ``trust_remote_code`` (which ``lerobot_train`` never
    passes) is not needed for it.

    Args:
        cfg: LeRobot's env config.
        n_envs, use_async_envs, hub_cache_dir, trust_remote_code: LeRobot's.

    Returns:
        ``{name: {0: VectorEnv}}``.
    """
    found = loaded_for(cfg)
    if found is None:
        from lerobot.envs import factory  # heavy: lerobot (torch)

        return factory.make_env(
            cfg, n_envs=n_envs, use_async_envs=use_async_envs, hub_cache_dir=hub_cache_dir, trust_remote_code=trust_remote_code
        )
    loaded, env_cfg = found
    if isinstance(cfg, HubEnv):
        return cfg.create_envs(n_envs, use_async_envs)  # a suite's tasks, or the one env
    if loaded.is_suite:  # the repo's own config (--env.type=<its choice>): the task it names, with its task id
        return suite_vec_envs(loaded, {env_cfg.task: env_cfg}, n_envs, use_async_envs)
    return {loaded.manifest.name: {0: make_vec_env(loaded, env_cfg, n_envs, use_async_envs)}}


def make_env_pre_post_processors(env_cfg, policy_cfg):
    """LeRobot's ``make_env_pre_post_processors``, plus the processors a hub env repo declares.

    Args:
        env_cfg: LeRobot's env config.
        policy_cfg: its policy config.

    Returns:
        ``(env_preprocessor, env_postprocessor)``.
    """
    from lerobot.envs import factory  # heavy: lerobot (torch)
    from lerobot.processor import PolicyProcessorPipeline  # heavy: lerobot (torch)

    pre, post = factory.make_env_pre_post_processors(env_cfg=env_cfg, policy_cfg=policy_cfg)
    found = loaded_for(env_cfg)
    if found is None or (isinstance(env_cfg, HubEnv) and env_configs_create_envs()):
        return pre, post  # LeRobot >= 0.5 already asked HubEnv.get_env_processors()
    loaded, cfg = found
    ours_pre, ours_post = loaded.processors(cfg)
    return (
        PolicyProcessorPipeline(steps=[*pre.steps, *ours_pre.steps], name=ours_pre.name),
        PolicyProcessorPipeline(steps=[*post.steps, *ours_post.steps], name=ours_post.name),
    )


def keep_declared_shapes(dataset):
    """Make ``action`` / ``observation.*`` features declared with shape ``(1,)`` come back with that shape.

    LeRobot stores a shape-``(1,)`` feature as a scalar column and returns it as a 0-d tensor (and a chunk of them as
    ``(T,)``), while its policies expect ``(..., 1)``: a 1-D action (pendulum's torque) breaks ACT and diffusion training
    with a broadcasting error. This adds the last dimension back, in the dataset's own torch transform.

    Args:
        dataset: a ``LeRobotDataset``.

    Returns:
        ``dataset``, its transform wrapped.
    """
    import torch  # heavy: torch
    from lerobot.utils.constants import ACTION, OBS_PREFIX  # heavy: lerobot (torch)

    to_torch_base = hf_transform_to_torch()

    keys = [
        k
        for k, ft in dataset.meta.features.items()
        if tuple(ft.get("shape", ())) == (1,)
        and ft.get("dtype") not in ("image", "video", "string")
        and (k == ACTION or k.startswith(OBS_PREFIX))
    ]
    hf = getattr(dataset, "hf_dataset", None)
    if not keys or hf is None:
        return dataset

    def to_torch(items):
        items = to_torch_base(items)
        for key in keys:
            if key in items:
                items[key] = [x.reshape(1) if isinstance(x, torch.Tensor) and x.dim() == 0 else x for x in items[key]]
        return items

    hf.set_transform(to_torch)
    return dataset


def _written_by_hub_envs(meta) -> bool:
    """Whether hub-envs wrote a dataset (it has hub-envs' metadata: :func:`hub_envs.dataset.reader.read_hub_envs_meta`,
    read from the files, which LeRobot does not load)."""
    root = getattr(meta, "root", None)
    try:
        return root is not None and bool(read_hub_envs_meta(root))
    except (OSError, DatasetError):
        return False


def _fix_shapes(cfg, dataset):
    meta = getattr(dataset, "meta", None)
    if dataset is not None and (
        loaded_for(getattr(cfg, "env", None)) is not None or (meta is not None and _written_by_hub_envs(meta))
    ):
        keep_declared_shapes(dataset)
    return dataset


def make_dataset(cfg):
    """LeRobot's ``make_dataset``; for a hub env run or a hub-envs dataset, with :func:`keep_declared_shapes`.

    Args:
        cfg: LeRobot's ``TrainPipelineConfig``.

    Returns:
        The dataset.
    """
    from lerobot.datasets import factory  # heavy: lerobot (torch)

    return _fix_shapes(cfg, factory.make_dataset(cfg))


def make_train_eval_datasets(cfg, *args, **kwargs):
    """LeRobot >= 0.5's ``make_train_eval_datasets``, each dataset with :func:`keep_declared_shapes`.

    Args:
        cfg: LeRobot's ``TrainPipelineConfig``.
        args, kwargs: LeRobot's.

    Returns:
        ``(train, eval or None)``.
    """
    from lerobot.datasets import factory  # heavy: lerobot (torch)

    train, evaluation = factory.make_train_eval_datasets(cfg, *args, **kwargs)
    return _fix_shapes(cfg, train), _fix_shapes(cfg, evaluation)


_DATASET_HOOKS = {"make_dataset": make_dataset, "make_train_eval_datasets": make_train_eval_datasets}


def install_hooks() -> None:
    """Route ``lerobot_train`` / ``lerobot_eval`` env creation through :func:`make_env` and
    :func:`make_env_pre_post_processors`, and ``lerobot_train``'s dataset through :func:`make_dataset`
    (idempotent; other env configs and datasets still get LeRobot's own behaviour)."""
    route_lerobot_scripts(make_env, make_env_pre_post_processors, _DATASET_HOOKS)


__all__ = [
    "HubEnv",
    "HUB_CHOICE",
    "TaskDescription",
    "install_hooks",
    "load_cached",
    "loaded_for",
    "make_env",
    "set_cli_consent",
    "make_env_pre_post_processors",
    "make_vec_env",
    "suite_vec_envs",
    "make_dataset",
    "make_train_eval_datasets",
    "keep_declared_shapes",
]
