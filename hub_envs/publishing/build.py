"""``build``: an env folder, loaded, made into the complete content of its repo in a staging folder, as a pipeline of
stages that each return a record: the checks, the code, the dataset, the media, the manifest, the card."""

from __future__ import annotations

import hashlib
import shutil
import sys
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from hub_envs._stack import requirement_closure
from hub_envs.backends import Backend, LocalBackend
from hub_envs.dataset.layout import STATES_PATH
from hub_envs.dataset.reader import dataset_fingerprint, read_info
from hub_envs.dataset.states import EnvStatesWriter
from hub_envs.dataset.video import DEFAULT_VIDEO_GOP, MIN_VIDEO_SIDE
from hub_envs.dataset.writer import (
    DatasetSummary,
    EpisodeFrames,
    dataset_features_from_config,
    rollout_to_frames,
    write_lerobot_dataset,
)
from hub_envs.envcode.envconfig import encode_config
from hub_envs.errors import EnvCheckError, EnvFolderError, HubEnvsError, StatesNotRecordedWarning
from hub_envs.harness.actions import stored_action, unsupported_reason
from hub_envs.harness.checks import FINGERPRINT_STEPS, check_determinism, episode_prefix, fingerprint_of, run_env_checker
from hub_envs.harness.features import check_features
from hub_envs.harness.media import MEDIA_EPISODES, MEDIA_STEPS, card_media_kwargs, write_rollout_media
from hub_envs.harness.provenance import package_versions
from hub_envs.loading.loaded import LoadedEnv
from hub_envs.paths import PACKAGE_DIR
from hub_envs.publishing.card import render_card
from hub_envs.repo.format import (
    CARD_FILE,
    DATASET_DIR,
    ENV_ENTRY_FILE,
    GIF_FILE,
    MANIFEST_FILE,
    MP4_FILE,
    SINGLE_TASK_FORMAT_VERSION,
    SUITE_FORMAT_VERSION,
    EnvFolder,
    Manifest,
    check_publishable,
    content_digest,
    content_tag,
    hash_files,
    list_files,
)
from hub_envs.repo.format import code_digest as code_digest_of_files

ENTRY_TEMPLATE = PACKAGE_DIR / "templates" / "env_entry.py"
#: Seeds of the golden-rollout fingerprint: the first dataset episodes.
FINGERPRINT_SEEDS = 3


def build(
    loaded: LoadedEnv,
    staging: Path,
    *,
    repo_id: str,
    episodes: int,
    seed: int,
    workers: int = 1,
    determinism_steps: int | None = None,
    fingerprint_seeds: int = FINGERPRINT_SEEDS,
    progress: bool = True,
    attestations: list | tuple = (),
    video: bool = False,
    backend: Backend | None = None,
    video_gop: int = DEFAULT_VIDEO_GOP,
    dataset_repo: bool = False,
) -> Manifest:
    """Run the checks and write the complete repo content of ``loaded`` (a local folder) into ``staging``.

    The stages, each one call returning its record: the checks (:func:`check_env`: the env, open, for the stages that
    show it; and the env the card's media need: the author's ``[tool.hub-envs.media] gym_kwargs``,
    :func:`media_env_maker`), the code (:func:`write_code`: its digest), the one rollout pass (:func:`generate_dataset`: the dataset,
    its states, the returns, the fingerprint; then the dataset half of the feature check), the media
    (:func:`render_media`), the manifest (:func:`draft_manifest`, then its content digest) and the card
    (:func:`write_card`). The repo content does not depend on where the episodes ran.

    Args:
        loaded: the env folder, loaded (``load_env(folder, check=False)``).
        staging: an empty folder: the repo's content is written there.
        repo_id: the repo it is built for (``user/name``; the manifest and the dataset name it).
        episodes: dataset episodes; episode ``i`` resets with seed ``seed + i``.
        seed: the first episode's seed, and the checks' seed.
        workers: local processes when no ``backend`` is given.
        determinism_steps: cap of the determinism check (None: a whole episode, for two seeds).
        fingerprint_seeds: the dataset's first episodes that make the golden-rollout fingerprint.
        progress: say each stage on stderr, with progress bars.
        attestations: the merged attestations the card shows ("Reproduced on").
        video: store camera features as MP4 (LeRobot's encoder) rather than PNG images.
        backend: where the episodes run (default: ``workers`` local processes).
        video_gop: the videos' keyframe interval.
        dataset_repo: the card says the dataset is also in the dataset repo of the same name.

    Returns:
        The manifest written to ``staging``, validated as load_env validates it.

    Raises:
        DeterminismError, EnvCheckError, FeatureMismatchError, EnvCodeError: a check failed (nothing is published).
    """
    backend = backend if backend is not None else LocalBackend(workers=workers)
    where = f"{loaded.local_folder} (for {repo_id})"
    say = stage_printer(progress)
    say(f"Checking {loaded.local_folder.name}: determinism, gymnasium check_env, three-way features")
    env = check_env(loaded, seed=seed, determinism_steps=determinism_steps, where=where)
    try:
        folder = EnvFolder.read(loaded.local_folder)
        suite = check_suite(loaded, folder, seed=seed, determinism_steps=determinism_steps, where=where, say=say)
        media_kwargs = card_media_kwargs(loaded.config.gym_kwargs, folder.media_gym_kwargs)  # the author's camera, >= 256 px
        make_media_env = media_env_maker(loaded, media_kwargs, folder)
        if folder.media_gym_kwargs:  # the author's media kwargs refused now, not after the dataset is built
            make_media_env().close()
        code_digest = write_code(loaded, staging, repo_id)
        where_run = ", ".join(f"{k}={v}" for k, v in backend.settings().items() if v is not None)
        per_task = f" for each of {len(suite)} tasks" if suite else ""
        say(
            f"Generating the random-action dataset: {episodes} episodes{per_task} x up to {loaded.config.episode_length} "
            f"steps ({where_run})"
        )
        run = generate_dataset(
            loaded,
            staging,
            repo_id=repo_id,
            seeds=dataset_seeds(seed, episodes, len(suite)),
            backend=backend,
            code_digest=code_digest,
            fingerprint_seeds=fingerprint_seeds,
            features=dataset_features_from_config(loaded.config, action=stored_action(env.action_space), video=video),
            where=where,
            progress=progress,
            video_gop=video_gop,
            suite=suite,
        )
        check_features(loaded.config, env, run.features_written, seed=seed, where=where).raise_if_mismatch(where)
        say("Rendering the GIF and the card")
        render_media(loaded, staging, make_media_env, seeds=list(run.summary.seeds), video=video)
        manifest = draft_manifest(loaded, repo_id=repo_id, code_digest=code_digest, run=run, seed=seed, staging=staging)
        write_card(
            loaded, staging, manifest, env, media_kwargs=media_kwargs, attestations=attestations, dataset_repo=dataset_repo
        )
    finally:
        env.close()
    manifest = replace(manifest, files=hash_files(staging, list_files(staging, skip=(MANIFEST_FILE,)))).validated(where=where)
    (staging / MANIFEST_FILE).write_text(manifest.to_json(), encoding="utf-8")
    return manifest


def stage_printer(enabled: bool) -> Callable[[str], None]:
    """One line on stderr per stage of a push.

    Args:
        enabled: False: say nothing.

    Returns:
        ``say(message)``.
    """

    def say(message: str) -> None:
        if enabled:
            print(message, file=sys.stderr, flush=True)

    return say


# --- 1. the checks ----------------------------------------------------------------------------------------------------


def check_env(loaded: LoadedEnv, *, seed: int, determinism_steps: int | None, where: str) -> Any:
    """Determinism (two seeds, a whole episode or ``determinism_steps``), gymnasium's checker, the live half of the
    three-way feature check. Determinism first: its message names the key, step and difference, which gymnasium's own
    determinism assertion does not.

    Args:
        loaded: the env folder, loaded.
        seed: the first of the determinism check's two seeds, and the feature check's.
        determinism_steps: cap of the determinism check (None: a whole episode).
        where: names the folder in messages.

    Returns:
        The env it checked, open: the dataset half of the feature check and the card reuse it.

    Raises:
        EnvCheckError: actions hub-envs cannot record, or gymnasium's checker refused the env.
        DeterminismError: the same seed gave two different episodes.
        FeatureMismatchError: the config's features and the live env's disagree.
    """
    cfg = loaded.config
    raw = loaded.env_class(**cfg.gym_kwargs)  # no spec: gymnasium's checker would re-make a spec'd env per render mode
    try:
        unsupported = unsupported_reason(raw.action_space)
        if unsupported:  # before anything samples or steps such actions
            raise EnvCheckError(f"{where}: {unsupported}. Nothing was published.")
        budget = int(cfg.episode_length) if determinism_steps is None else min(int(determinism_steps), int(cfg.episode_length))
        check_determinism(loaded.make, seeds=[seed, seed + 1], steps=budget, where=where)
        run_env_checker(raw, where=where)
    finally:
        raw.close()
    env = loaded.make()
    try:
        check_features(cfg, env, None, seed=seed, where=where).raise_if_mismatch(where)
    except BaseException:
        env.close()
        raise
    return env


@dataclass(frozen=True)
class SuiteTask:
    """One task of a suite, checked: its name (the config's ``task``), task id, handle and language instruction."""

    task: str
    index: int
    loaded: LoadedEnv  # LoadedEnv.for_task(task)
    instruction: str


def dataset_seeds(seed: int, episodes: int, tasks: int = 0) -> list[int]:
    """The dataset's reset seeds: episode ``i`` resets with ``seed + i``; a suite's tasks take ``episodes`` each, in task
    order (task ``t``'s episodes are ``t * episodes`` to ``(t + 1) * episodes - 1``).

    Args:
        seed: the first episode's seed.
        episodes: episodes per task.
        tasks: the suite's task count (0: a one-task env).

    Returns:
        One seed per dataset episode.
    """
    return [seed + i for i in range(episodes * max(1, tasks))]


def task_instruction(make: Callable[[], Any], task: str, *, seed: int) -> str:
    """A task's language instruction as the env states it (LeRobot's convention: ``task_description`` on the env, as its
    LIBERO and Meta-World envs set it), else the task's name.

    Args:
        make: makes the task's env.
        task: the task's name.
        seed: the reset seed (an env may set its description in ``reset``).

    Returns:
        The instruction.
    """
    env = make()
    try:
        env.reset(seed=seed)
        try:
            text = env.get_wrapper_attr("task_description")
        except AttributeError:
            text = None
    finally:
        env.close()
    return text.strip() if isinstance(text, str) and text.strip() else task


def check_suite(
    loaded: LoadedEnv,
    folder: EnvFolder,
    *,
    seed: int,
    determinism_steps: int | None,
    where: str,
    say: Callable[[str], None] = lambda _: None,
) -> list[SuiteTask]:
    """A suite's tasks (``[tool.hub-envs] tasks``), each checked as a one-task env is (:func:`check_env`; the default
    task's env was, by :func:`build`), and their instructions. Every task must be a value the config and the env accept, with the features of the config's default
    task (one dataset holds them all), and the default task must be one of them.

    Args:
        loaded: the env folder, loaded.
        folder: the env folder (its ``tasks``).
        seed, determinism_steps: as :func:`check_env`.
        where: names the folder in messages.
        say: says the stage.

    Returns:
        The tasks in task-id order; ``[]`` for a one-task env.

    Raises:
        EnvFolderError: the default task is not listed, a task the config refuses, features that differ by task, two
            tasks with one instruction.
        DeterminismError, EnvCheckError, FeatureMismatchError, EnvCodeError: a task failed a check.
    """
    if not folder.tasks:
        return []
    field_ = f"{folder.root / 'pyproject.toml'}: [tool.hub-envs] tasks"
    default = loaded.config.task
    if default not in folder.tasks:
        raise EnvFolderError(
            f"{field_} = {list(folder.tasks)} does not list the config's default task {default!r} (what load_env and "
            f"LeRobot make when no task is named). Add it to tasks, or set the config's task default to one of them."
        )
    declared = encode_config(loaded.config)["features"]
    out: list[SuiteTask] = []
    for index, task in enumerate(folder.tasks):
        try:
            view = loaded.for_task(task)
        except HubEnvsError as e:
            raise EnvFolderError(f"{field_}: the config refuses task {task!r}: {e}") from e
        if encode_config(view.config)["features"] != declared:
            raise EnvFolderError(
                f"{field_}: task {task!r} declares other features than the default task {default!r}; one dataset holds "
                f"every task of a suite, so the config's features must not depend on the task."
            )
        try:
            view.env_class(**view.config.gym_kwargs).close()
        except (TypeError, ValueError) as e:  # the env itself refused the task's keyword arguments
            raise EnvFolderError(f"{field_}: the env refuses task {task!r} ({type(e).__name__}: {e}).") from e
        if task != default:  # the default task's env is the one build() checked already
            say(f"  task {index} {task!r}: determinism, gymnasium check_env, features")
            check_env(view, seed=seed, determinism_steps=determinism_steps, where=f"{where} task {task!r}").close()
        out.append(SuiteTask(task, index, view, task_instruction(view.make, task, seed=seed)))
    said = [t.instruction for t in out]
    twice = sorted({x for x in said if said.count(x) > 1})
    if twice:
        raise EnvFolderError(
            f"{field_}: several tasks state the instruction {twice} (their task_description); LeRobot's tasks.parquet "
            f"indexes tasks by their text, so each task needs its own."
        )
    return out


# --- 2. the code ------------------------------------------------------------------------------------------------------


def entry_text(repo_id: str) -> str:
    """The ``env.py`` every env repo gets (LeRobot's EnvHub imports it).

    Args:
        repo_id: the repo it names.

    Returns:
        The file's text.
    """
    return ENTRY_TEMPLATE.read_text(encoding="utf-8").replace("{repo_id}", repo_id)


def code_files_of(loaded: LoadedEnv, repo_id: str) -> dict[str, str]:
    """The code files a push of ``loaded`` publishes: the folder's files and ``env.py``.

    Args:
        loaded: the env folder, loaded.
        repo_id: the repo it is pushed to (``env.py`` names it).

    Returns:
        ``{path: sha256}``, sorted.
    """
    files = hash_files(loaded.local_folder, list_files(loaded.local_folder))
    files[ENV_ENTRY_FILE] = hashlib.sha256(entry_text(repo_id).encode("utf-8")).hexdigest()
    return dict(sorted(files.items()))


def write_code(loaded: LoadedEnv, staging: Path, repo_id: str) -> str:
    """Copy the env's own files and the generated ``env.py`` into ``staging``.

    Args:
        loaded: the env folder, loaded.
        staging: the repo's staging folder.
        repo_id: the repo it is pushed to.

    Returns:
        The code digest (what the dataset's ``env_meta`` names).

    Raises:
        EnvFolderError: a symlink out of the folder, or compiled files.
    """
    check_publishable(loaded.local_folder)  # no symlink out of the folder, no compiled files
    for rel in list_files(loaded.local_folder):
        dest = staging / rel
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(loaded.local_folder / rel, dest)
    (staging / ENV_ENTRY_FILE).write_text(entry_text(repo_id), encoding="utf-8")
    return code_digest_of_files(hash_files(staging, list_files(staging)))


# --- 3. the dataset ---------------------------------------------------------------------------------------------------


@dataclass
class DatasetRun:
    """What the one rollout pass of a push produced besides the dataset files."""

    summary: DatasetSummary
    features: dict[str, dict]  # info.json-style, as declared (LeRobot's defaults not added)
    features_written: dict[str, dict]  # as the written info.json has them (the dataset half of the feature check)
    digest: str  # dataset fingerprint, recorded simulator states included
    has_states: bool
    returns: list[float]
    successes: list[bool]
    golden: dict[str, Any]  # the golden-rollout fingerprint, from the first episodes (a suite: the default task's)
    video_gop: int | None = None  # the keyframe interval of the dataset's videos (None: no video feature)
    tasks: list[dict[str, Any]] = field(default_factory=list)  # a suite's task records (the manifest's ``tasks``)
    task_benchmarks: list[dict[str, Any]] = field(default_factory=list)  # a suite's random-policy benchmark, per task


def env_meta(loaded: LoadedEnv, repo_id: str, code_digest: str) -> dict[str, Any]:
    """robomimic-style ``env_meta`` stored in the dataset: enough to rebuild exactly the env the data came from.

    The dataset is part of the commit it describes, so it cannot name that commit's sha; it names the repo and the
    digest of the env's code instead, and ``env_from_dataset`` finds the commit.

    Args:
        loaded: the env folder, loaded.
        repo_id: the env repo.
        code_digest: the code's digest (:func:`write_code`).

    Returns:
        ``env_repo_id``, ``code_digest``, the entry points, ``env_kwargs`` and the config values.
    """
    return {
        "env_repo_id": repo_id,
        "code_digest": code_digest,
        "env_entry_point": loaded.manifest.env_entry_point,
        "config_entry_point": loaded.manifest.config_entry_point,
        "env_kwargs": encode_config(loaded.config)["gym_kwargs"],
        "config": encode_config(loaded.config),
    }


def generate_dataset(
    loaded: LoadedEnv,
    staging: Path,
    *,
    repo_id: str,
    seeds: list[int],
    backend: Backend,
    code_digest: str,
    fingerprint_seeds: int,
    features: dict[str, dict],
    where: str,
    progress: bool,
    video_gop: int = DEFAULT_VIDEO_GOP,
    suite: list[SuiteTask] = (),  # type: ignore[assignment]
) -> DatasetRun:
    """The one rollout pass: the dataset, its simulator states, the random-policy returns and the golden-rollout
    fingerprint (its seeds are the first dataset episodes: no second rollout of them). A suite's tasks run one after
    the other into the same dataset (``seeds`` split evenly among them, in task order), each episode with its task's
    ``task_index``, and each task gets its own returns, benchmark and fingerprint.

    Args:
        loaded: the env folder, loaded.
        staging: the repo's staging folder (the dataset goes to its ``dataset/``).
        repo_id: the env repo.
        seeds: one reset seed per episode.
        backend: where the episodes run.
        code_digest: the code's digest (the dataset's ``env_meta`` names it).
        fingerprint_seeds: the first episodes that make the golden-rollout fingerprint.
        features: the dataset's features (info.json-style).
        where: names the folder in messages.
        progress: show a progress bar.
        video_gop: the videos' keyframe interval.
        suite: a suite's tasks (:func:`check_suite`); empty: a one-task env.

    Returns:
        The :class:`DatasetRun`.

    Raises:
        EnvCodeError: an episode raised.
        DatasetError: the episodes cannot be written as a LeRobot dataset.
    """
    cfg = loaded.config
    per_task = max(1, len(seeds) // max(1, len(suite)))
    # (handle, task_index, its seeds, offset of its first episode): one part for a one-task env
    parts = (
        [(t.loaded, t.index, list(seeds[i * per_task : (i + 1) * per_task]), i * per_task) for i, t in enumerate(suite)]
        if suite
        else [(loaded, 0, list(seeds), 0)]
    )
    returns: list[float] = []
    successes: list[bool] = []
    task_first: dict[int, list[Any]] = {index: [] for _, index, _, _ in parts}
    # env.get_state() before each action, for exact replay (hub_envs.dataset.states): to disk as episodes arrive,
    # beside the dataset folder (which the writer creates whole at its end), moved into it after
    states = EnvStatesWriter(staging / ".env_states.parquet")
    states_problem: list[str] = []

    def frames():
        for handle, task_index, part_seeds, offset in parts:
            task = f" of task {suite[task_index].task!r}" if suite else ""
            for rollout in backend.episodes(
                handle,
                part_seeds,
                max_steps=int(cfg.episode_length),
                progress=progress,
                desc=f"Generating {len(part_seeds)} episodes{task}",
                record_states=True,
            ):
                index = offset + rollout.index  # the episode's index in the whole dataset
                states.add(index, rollout.states)
                if rollout.states_problem and not states_problem:
                    states_problem.append(f"episode {index}: {rollout.states_problem}")
                returns.append(float(np.sum(rollout.rewards)))
                successes.append(bool(np.any(rollout.is_success)))
                if rollout.index < fingerprint_seeds:
                    task_first[task_index].append(episode_prefix(rollout, FINGERPRINT_STEPS))
                yield EpisodeFrames(
                    index=index,
                    seed=rollout.seed,
                    frames=rollout_to_frames(rollout, cfg.features_map),
                    task_index=task_index,
                )

    try:
        summary = write_lerobot_dataset(
            staging / DATASET_DIR,
            repo_id=repo_id,
            fps=int(cfg.fps),
            features=features,
            episodes=frames(),
            task=[t.instruction for t in suite] if suite else str(cfg.task),
            extra_info={"env_meta": env_meta(loaded, repo_id, code_digest)},
            progress=False,  # the rollout bar above already counts episodes
            video_gop=video_gop,
        )
    except BaseException:
        states.abort()
        raise
    has_states = states.close()
    if has_states:
        states.path.replace(staging / DATASET_DIR / STATES_PATH)
    if callable(getattr(loaded.env_class, "get_state", None)) and not has_states:  # the simulator-state contract
        reason = states_problem[0] if states_problem else states.reason
        warnings.warn(
            f"{where}: no simulator states recorded: {reason}. Replays of this dataset cannot restore a step with "
            "reset_to(); return one numeric array of a fixed shape from get_state() (hub_envs.dataset.states).",
            StatesNotRecordedWarning,
            stacklevel=4,
        )
    steps = min(FINGERPRINT_STEPS, int(cfg.episode_length))
    golden = {index: fingerprint_of(first, steps=steps) for index, first in task_first.items()}
    records, task_benchmarks = [], []
    for _, index, part_seeds, offset in parts if suite else []:
        span = slice(offset, offset + len(part_seeds))
        task_benchmarks.append({**random_benchmark(returns[span], successes[span], part_seeds), "task": suite[index].task})
        records.append(
            {
                "task": suite[index].task,
                "task_index": index,
                "instruction": suite[index].instruction,
                "episodes": list(range(span.start, span.stop)),
                "seeds": part_seeds,
                "fingerprint": golden[index],
                "return_mean": float(np.mean(returns[span])),
                "success_rate": float(np.mean(successes[span])),
            }
        )
    default = next((t.index for t in suite if t.task == cfg.task), 0)
    return DatasetRun(
        summary=summary,
        features=features,
        features_written=read_info(staging / DATASET_DIR)["features"],
        digest=dataset_fingerprint(staging / DATASET_DIR) if has_states else summary.fingerprint,
        has_states=has_states,
        returns=returns,
        successes=successes,
        golden=golden[default],
        video_gop=video_gop if dataset_uses_video({"features": features}) else None,
        tasks=records,
        task_benchmarks=task_benchmarks,
    )


def dataset_uses_video(dataset: dict[str, Any]) -> bool:
    """Whether a manifest's ``dataset`` record stores a feature as video.

    Args:
        dataset: the manifest's ``dataset`` (its ``features``).

    Returns:
        True when a feature's dtype is ``video``.
    """
    return any(isinstance(ft, dict) and ft.get("dtype") == "video" for ft in (dataset.get("features") or {}).values())


# --- 4. the media -----------------------------------------------------------------------------------------------------


def cameras(cfg: Any) -> list[tuple[int, ...]]:
    """The env config's cameras.

    Args:
        cfg: the env's config.

    Returns:
        The shapes of its VISUAL features.
    """
    return [tuple(ft.shape) for ft in cfg.features.values() if str(getattr(ft.type, "value", ft.type)).upper().endswith("VISUAL")]


def default_video(cfg: Any) -> bool:
    """Whether a push stores camera features as video when not told.

    Args:
        cfg: the env's config.

    Returns:
        True when the env has cameras the encoder takes (frames of at least ``MIN_VIDEO_SIDE`` px a side).
    """
    shapes = cameras(cfg)
    return bool(shapes) and all(len(s) >= 2 and min(s[:2]) >= MIN_VIDEO_SIDE for s in shapes)


def media_env_maker(loaded: LoadedEnv, media_kwargs: dict[str, Any], folder: EnvFolder) -> Callable[[], Any]:
    """``make()`` for the card's media.

    Args:
        loaded: the env folder, loaded.
        media_kwargs: what the media's env is made with (:func:`hub_envs.harness.media.card_media_kwargs`).
        folder: the env folder (its ``[tool.hub-envs.media] gym_kwargs``).

    Returns:
        A function making the env with ``media_kwargs``.

    Raises:
        EnvFolderError: (from the function) the env refused the author's media kwargs, named with where they come from.
    """

    def make():
        try:
            return loaded.make(**media_kwargs)
        except (TypeError, ValueError) as exc:
            if not folder.media_gym_kwargs:
                raise
            raise EnvFolderError(
                f"{folder.root / 'pyproject.toml'}: [tool.hub-envs.media] gym_kwargs = {folder.media_gym_kwargs}: the env "
                f"refused them when push_env made it to render the card's media ({type(exc).__name__}: {exc}). Give "
                f"keyword arguments that {getattr(loaded.env_class, '__name__', 'the env')} takes, or remove the table."
            ) from exc

    return make


def render_media(loaded: LoadedEnv, staging: Path, make_env: Callable[[], Any], *, seeds: list[int], video: bool) -> list[Path]:
    """The card's GIF (and, for a video dataset of an env with cameras, its MP4) of the first episodes.

    Args:
        loaded: the env folder, loaded.
        staging: the repo's staging folder (the media go to its ``media/``).
        make_env: makes the media's env (:func:`media_env_maker`).
        seeds: the dataset's seeds (the first :data:`~hub_envs.harness.media.MEDIA_EPISODES` are shown).
        video: the dataset stores video.

    Returns:
        The files written.
    """
    cfg = loaded.config
    mp4 = staging / MP4_FILE if video and cameras(cfg) else None
    write_rollout_media(
        make_env,
        staging / GIF_FILE,
        seeds=seeds[:MEDIA_EPISODES],
        fps=int(cfg.fps),
        max_steps=min(MEDIA_STEPS, int(cfg.episode_length)),
        mp4_path=mp4,
    )
    return [staging / GIF_FILE] + ([mp4] if mp4 is not None else [])


# --- 5. the manifest --------------------------------------------------------------------------------------------------


def published_overrides(loaded: LoadedEnv) -> dict[str, Any]:
    """The config fields the publisher set, as the config holds them (decoded: ``"50"`` is recorded as 50).

    Args:
        loaded: the env folder, loaded with ``config=``.

    Returns:
        ``{field: value}``, sorted.
    """
    values = encode_config(loaded.config)
    return {name: values[name] for name in sorted(loaded.manifest.config_overrides)}


def random_benchmark(returns: list[float], successes: list[bool], seeds: list[int]) -> dict[str, Any]:
    """The repo's first benchmark: the seeded random policy over the dataset's episodes.

    Args:
        returns, successes: per episode.
        seeds: the episodes' reset seeds.

    Returns:
        A manifest ``benchmarks`` entry (metrics, per-episode values, tolerances).
    """
    return {
        "name": "random-policy",
        "policy": {"type": "random", "seed_source": "episode reset seed (action_space.seed(seed))"},
        "episodes": len(returns),
        "seeds": list(seeds),
        "metrics": {"mean_return": float(np.mean(returns)), "success_rate": float(np.mean(successes))},
        "per_episode": {"return": [float(r) for r in returns], "success": [bool(s) for s in successes]},
        "tolerance": {"mean_return": 1e-6, "success_rate": 0.0},
    }


def draft_manifest(loaded: LoadedEnv, *, repo_id: str, code_digest: str, run: DatasetRun, seed: int, staging: Path) -> Manifest:
    """The manifest of what was built, with its content digest; its ``files`` once the card is written.

    Args:
        loaded: the env folder, loaded.
        repo_id: the env repo.
        code_digest: the code's digest.
        run: the rollout pass's record.
        seed: the check seed.
        staging: the repo's staging folder (the content digest covers its files but the manifest and the card).

    Returns:
        The manifest, ``files`` empty.
    """
    summary = run.summary
    seeds = list(summary.seeds)
    manifest = Manifest(
        repo_id=repo_id,
        name=loaded.manifest.name,
        version=loaded.manifest.version,
        description=loaded.manifest.description,
        env_entry_point=loaded.manifest.env_entry_point,
        config_entry_point=loaded.manifest.config_entry_point,
        gym_id=repo_id,
        env_type=repo_id,
        requirements=tuple(loaded.manifest.requirements),
        config=encode_config(loaded.config),
        config_overrides=published_overrides(loaded),
        dataset={
            "path": DATASET_DIR,
            "fingerprint": run.digest,
            "env_states": STATES_PATH if run.has_states else None,
            "episodes": summary.episodes,
            "frames": summary.frames,
            "fps": summary.fps,
            "seeds": seeds,
            "return_mean": summary.return_mean,
            "return_std": summary.return_std,
            "return_min": summary.return_min,
            "return_max": summary.return_max,
            "success_rate": summary.success_rate,
            "features": run.features,
            **({"video_gop": run.video_gop} if run.video_gop is not None else {}),
        },
        fingerprint=run.golden,
        code_digest=code_digest,
        seeds={"dataset": seeds, "check": seed, "fingerprint": run.golden["seeds"]},
        versions=package_versions(loaded.manifest.requirements),
        resolved=requirement_closure(loaded.manifest.requirements),
        # a suite: one random-policy benchmark per task (its ``task`` named), its tasks' records
        benchmarks=tuple(run.task_benchmarks) if run.tasks else (random_benchmark(run.returns, run.successes, seeds),),
        processors=tuple(loaded.manifest.processors),
        files={},
        content_digest="",
        tasks=tuple(run.tasks),
        format_version=SUITE_FORMAT_VERSION if run.tasks else SINGLE_TASK_FORMAT_VERSION,
    )
    return replace(
        manifest, content_digest=content_digest(hash_files(staging, list_files(staging, skip=(MANIFEST_FILE, CARD_FILE))))
    )


# --- 6. the card ------------------------------------------------------------------------------------------------------


def write_card(
    loaded: LoadedEnv,
    staging: Path,
    manifest: Manifest,
    env: Any,
    *,
    media_kwargs: dict[str, Any],
    attestations: list | tuple,
    dataset_repo: bool,
) -> str:
    """The card (``README.md``), rendered from the manifest before its ``files`` are final (the card is one of them).

    Args:
        loaded: the env folder, loaded (its license, the env class's documentation).
        staging: the repo's staging folder.
        manifest: the manifest, with its content digest (the card's load line names its content tag).
        env: the checked env (the spaces shown).
        media_kwargs: what the media's env was made with (stated under the GIF).
        attestations: the merged attestations of this content ("Reproduced on").
        dataset_repo: the dataset is also in the dataset repo of the same name.

    Returns:
        The card's text.
    """
    card = render_card(
        manifest,
        env_class=loaded.env_class,
        media_kwargs=media_kwargs,
        env=env,
        content_tag=content_tag(manifest.content_digest),
        license=EnvFolder.read(loaded.local_folder).license,
        reproductions=attestations,
        dataset_repo=dataset_repo,
    )
    (staging / CARD_FILE).write_text(card, encoding="utf-8")
    return card
