"""``push_env``: validate a local env folder, build its dataset and card, publish it in one commit.

1. load the folder through the same code path ``load_env`` uses;
2. refuse to publish if a check fails: determinism (two seeds, a whole episode each, or
   ``determinism_steps``), gymnasium's ``check_env``, the three-way feature check;
3. generate the random-action dataset (seeded, in parallel across processes, progress bar);
4. record the golden-rollout fingerprint and the random-policy benchmark, write the manifest,
   render the card and a GIF;
5. publish everything as ONE commit (identical content makes no new commit), tag it; the dataset also goes to
   the dataset repo of the same name first, for LeRobot's own tools (``LeRobotDataset(repo_id)``), named by the
   manifest, its ``v3.0`` tag moved once the env commit is made;
6. print the commit sha and the pinned load line.

Example:
    >>> from hub_envs import push_env
    >>> result = push_env("envs/pendulum", "user/pendulum-lerobot", episodes=10)   # doctest: +SKIP
    >>> result.load_line                                                            # doctest: +SKIP
    'load_env("user/pendulum-lerobot@3f2a…", trust_remote_code=True)'
"""

from __future__ import annotations

import hashlib
import json
import shutil
import sys
import tempfile
import time
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from hub_envs import hub_io
from hub_envs._compat import LEROBOT_VIDEO_GOP
from hub_envs.backends import Backend, LocalBackend, make_backend
from hub_envs.card import render_card, reproduced_table
from hub_envs.dataset.layout import CODEBASE_VERSION, HUB_ENVS_META_PATH
from hub_envs.dataset.reader import dataset_fingerprint, read_info
from hub_envs.dataset.states import STATES_PATH, EnvStatesWriter
from hub_envs.dataset.video import DEFAULT_VIDEO_GOP, check_video_gop
from hub_envs.dataset.writer import (
    DatasetSummary,
    EpisodeFrames,
    dataset_features_from_config,
    rollout_to_frames,
    write_lerobot_dataset,
)
from hub_envs.envconfig import encode_config
from hub_envs.errors import (
    ConfigError,
    EnvCheckError,
    EnvFolderError,
    HubEnvsError,
    IntegrityError,
    RevisionNotFoundError,
    StatesNotRecordedWarning,
)
from hub_envs.harness.actions import stored_action, unsupported_reason
from hub_envs.harness.checks import FINGERPRINT_STEPS, check_determinism, episode_prefix, fingerprint_of, run_env_checker
from hub_envs.harness.features import check_features
from hub_envs.harness.media import MEDIA_EPISODES, MEDIA_STEPS, card_media_kwargs, write_rollout_media
from hub_envs.harness.provenance import package_versions, requirement_closure
from hub_envs.importing import forget_env_folder, module_key
from hub_envs.load import LoadedEnv, load_env
from hub_envs.repo_format import (
    CARD_FILE,
    DATASET_DIR,
    ENV_ENTRY_FILE,
    FORMAT_VERSION,
    GIF_FILE,
    MANIFEST_FILE,
    MEDIA_DIR,
    MP4_FILE,
    EnvFolder,
    Manifest,
    beyond_manifest,
    check_publishable,
    content_digest,
    content_tag,
    hash_files,
    list_files,
)
from hub_envs.repo_format import code_digest as code_digest_of_files

ENTRY_TEMPLATE = Path(__file__).resolve().parent / "templates" / "env_entry.py"


@dataclass
class PushResult:
    """What push_env did."""

    repo_id: str
    sha: str
    created_commit: bool
    content_tag: str
    manifest: Manifest
    timings: dict[str, float] = field(default_factory=dict)
    tags: list[str] = field(default_factory=list)
    #: the dataset repo of the same name and its commit holding the dataset (None: ``dataset_repo=False``)
    dataset_sha: str | None = None

    @property
    def load_line(self) -> str:
        return f'load_env("{self.repo_id}@{self.sha}", trust_remote_code=True)'

    def summary(self) -> str:
        verb = "Published" if self.created_commit else "Unchanged; already published"
        text = (
            f"{verb} {self.repo_id} at commit {self.sha} (tags: {', '.join(self.tags)}).\n"
            f"Load it pinned:\n  from hub_envs import load_env\n  {self.load_line}"
        )
        if self.dataset_sha is not None:
            text += (
                f"\nIts dataset, for LeRobot's own tools (dataset repo {self.repo_id} at commit {self.dataset_sha}, tags "
                f'{LEROBOT_DATASET_TAG} and {self.content_tag}):\n  LeRobotDataset("{self.repo_id}")   # lerobot-train '
                f"--dataset.repo_id={self.repo_id}"
            )
        return text


#: Seeds of the golden-rollout fingerprint: the first dataset episodes.
FINGERPRINT_SEEDS = 3


def _stage_printer(enabled: bool):
    def say(message: str) -> None:
        if enabled:
            print(message, file=sys.stderr, flush=True)

    return say


def _random_benchmark(returns: list[float], successes: list[bool], seeds: list[int]) -> dict[str, Any]:
    return {
        "name": "random-policy",
        "policy": {"type": "random", "seed_source": "episode reset seed (action_space.seed(seed))"},
        "episodes": len(returns),
        "seeds": list(seeds),
        "metrics": {"mean_return": float(np.mean(returns)), "success_rate": float(np.mean(successes))},
        "per_episode": {"return": [float(r) for r in returns], "success": [bool(s) for s in successes]},
        "tolerance": {"mean_return": 1e-6, "success_rate": 0.0},
    }


def _has_get_state(loaded: LoadedEnv) -> bool:
    """Whether the env offers the simulator-state contract (:class:`hub_envs.dataset.states.SupportsSimulatorState`)."""
    return callable(getattr(loaded.env_class, "get_state", None))


def env_meta(loaded: LoadedEnv, repo_id: str, code_digest: str) -> dict[str, Any]:
    """robomimic-style env_meta stored in the dataset: enough to rebuild exactly the env the data came from.

    The dataset is part of the commit it describes, so it cannot name that commit's sha; it names the
    repo and the digest of the env's code instead, and ``env_from_dataset`` finds the commit.
    """
    return {
        "env_repo_id": repo_id,
        "code_digest": code_digest,
        "env_entry_point": loaded.manifest.env_entry_point,
        "config_entry_point": loaded.manifest.config_entry_point,
        "env_kwargs": encode_config(loaded.config)["gym_kwargs"],
        "config": encode_config(loaded.config),
    }


@dataclass
class _DatasetRun:
    """What the one rollout pass of a push produced besides the dataset files."""

    summary: DatasetSummary
    features: dict[str, dict]  # info.json-style, as declared (LeRobot's defaults not added)
    digest: str  # dataset fingerprint, recorded simulator states included
    has_states: bool
    returns: list[float]
    successes: list[bool]
    golden: dict[str, Any]  # the golden-rollout fingerprint, from the first episodes
    video_gop: int | None = None  # the keyframe interval of the dataset's videos (None: no video feature)


def _check_env(loaded: LoadedEnv, *, seed: int, determinism_steps: int | None, where: str) -> Any:
    """Stage 1: determinism (two seeds, a whole episode or ``determinism_steps``), gymnasium's checker, the live
    half of the three-way feature check. Determinism first: its message names the key, step and difference,
    which gymnasium's own determinism assertion does not.

    Returns the env it checked (open): the dataset half of the feature check and the card reuse it.
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


def _entry_text(repo_id: str) -> str:
    return ENTRY_TEMPLATE.read_text(encoding="utf-8").replace("{repo_id}", repo_id)


def _code_files(loaded: LoadedEnv, repo_id: str) -> dict[str, str]:
    """``{path: sha256}`` of the code files a push of ``loaded`` publishes (the folder's files and ``env.py``)."""
    files = hash_files(loaded.local_folder, list_files(loaded.local_folder))
    files[ENV_ENTRY_FILE] = hashlib.sha256(_entry_text(repo_id).encode("utf-8")).hexdigest()
    return dict(sorted(files.items()))


def _merged_attestations(repo_id: str, token: str | None) -> list:
    """The valid attestations on main (:func:`hub_envs.attestation.merged_attestations`: entries naming the author
    of the pull request each came from); invalid ones are skipped."""
    from hub_envs.attestation import merged_attestations

    return [e for e in merged_attestations(repo_id, token=token) if e.attestation is not None]


def _card_shows(repo_id: str, sha: str, table: str, token: str | None) -> bool:
    """Whether the card at ``sha`` already shows ``table`` (the "Reproduced on" table; "" for none)."""
    card = hub_io.read_remote_text(repo_id, CARD_FILE, revision=sha, token=token) or ""
    return table in card if table else "## Reproduced on" not in card


def _cameras(cfg: Any) -> list[tuple[int, ...]]:
    """The shapes of the env config's VISUAL features (its cameras)."""
    return [tuple(ft.shape) for ft in cfg.features.values() if str(getattr(ft.type, "value", ft.type)).upper().endswith("VISUAL")]


def _has_cameras(cfg: Any) -> bool:
    """Whether the env's config declares a VISUAL feature (a camera: stored as video by default, as LeRobot does)."""
    return bool(_cameras(cfg))


def _default_video(cfg: Any) -> bool:
    """Video by default when the env has cameras the encoder takes (frames of at least MIN_VIDEO_SIDE px)."""
    from hub_envs.dataset.video import MIN_VIDEO_SIDE

    shapes = _cameras(cfg)
    return bool(shapes) and all(len(s) >= 2 and min(s[:2]) >= MIN_VIDEO_SIDE for s in shapes)


def _dataset_uses_video(dataset: dict[str, Any]) -> bool:
    return any(isinstance(ft, dict) and ft.get("dtype") == "video" for ft in (dataset.get("features") or {}).values())


def _published_unchanged(
    loaded: LoadedEnv,
    repo_id: str,
    *,
    episodes: int,
    seed: int,
    fingerprint_seeds: int,
    token: str | None,
    attestations: list = (),  # type: ignore[assignment]
    video: bool = False,
    video_gop: int = DEFAULT_VIDEO_GOP,
    dataset_repo: bool = True,
) -> tuple[str, Manifest, bool] | None:
    """``(sha, manifest, card_current)`` of main when it already holds what this push would build, else None.

    "The same" is: the same code files (each hash), config values, dataset seeds and episode count, check
    seed, fingerprint seeds, requirements, processors, name/version/description, format, and recorded package
    versions (hub-envs' own included, so a new hub-envs regenerates); and main holds exactly the files its
    manifest lists. Generated files (dataset, GIF, card) are not rebuilt to compare them: they follow from
    the above, and a hand edit of them that also rewrote the manifest is for ``hub-envs reproduce`` to find
    (``force=True`` regenerates anyway). With ``dataset_repo``, the manifest also names a commit of the dataset repo
    that exists (a manifest from before dataset repos, or a deleted one, rebuilds and publishes it).
    ``card_current``: the card already shows the merged ``attestations``
    of this content ("Reproduced on"); when one was merged since the last push, only the card is re-rendered
    (:func:`_refresh_card`).
    """
    head = hub_io.remote_head(repo_id, token=token)
    if head is None:
        return None
    remote = _remote_manifest(repo_id, head, token)
    if remote is None:
        return None
    local = loaded.manifest
    seeds = [seed + i for i in range(episodes)]
    code = _code_files(loaded, repo_id)
    same = (
        remote.format_version == FORMAT_VERSION
        and remote.repo_id == repo_id
        and {p: h for p, h in remote.files.items() if not _generated(p)} == code
        and remote.code_digest == code_digest_of_files(code)
        and remote.config == encode_config(loaded.config)
        and remote.config_overrides == _published_overrides(loaded)
        and remote.seeds.get("dataset") == seeds
        and remote.seeds.get("check") == seed
        and remote.dataset.get("episodes") == episodes
        and _dataset_uses_video(remote.dataset) == (video and _has_cameras(loaded.config))
        and (not _dataset_uses_video(remote.dataset) or remote.dataset.get("video_gop", LEROBOT_VIDEO_GOP) == video_gop)
        and remote.fingerprint.get("seeds") == seeds[:fingerprint_seeds]
        and (remote.name, remote.version, remote.description) == (local.name, local.version, local.description)
        and remote.requirements == tuple(local.requirements)
        and remote.processors == tuple(local.processors)
        and remote.versions == package_versions(local.requirements)
        and remote.resolved == requirement_closure(local.requirements)
        and ("dataset_repo" in remote.dataset) == dataset_repo
    )
    if not same:
        return None
    if dataset_repo and not _dataset_commit_exists(repo_id, remote.dataset["dataset_repo"].get("revision"), token):
        return None
    remote_files = {p for p in hub_io.list_remote_files(repo_id, head, token=token) if not beyond_manifest(p)}
    if remote_files != set(remote.files):
        return None
    table = reproduced_table([e for e in attestations if e.attestation.content_digest == remote.content_digest])
    return head, remote, _card_shows(repo_id, head, table, token)


def _refresh_card(
    loaded: LoadedEnv, repo_id: str, head: str, remote: Manifest, attestations: list, *, token: str | None
) -> tuple[str, Manifest]:
    """Main holds this content, but attestations were merged since its card was rendered: render the card again
    from main's manifest (as :func:`build_repo` renders it) and commit it with the manifest's new hash of it, on
    top of ``head``: nothing else is rebuilt, and the content digest (which excludes the card) stays."""
    env = loaded.make()
    folder = EnvFolder.read(loaded.local_folder)
    try:
        card = render_card(
            replace(remote, files={}),  # as build_repo renders it: before the files are hashed
            env_class=loaded.env_class,
            media_kwargs=card_media_kwargs(loaded.config.gym_kwargs, folder.media_gym_kwargs),
            env=env,
            content_tag=content_tag(remote.content_digest),
            license=EnvFolder.read(loaded.local_folder).license,
            reproductions=attestations,
            dataset_repo="dataset_repo" in remote.dataset,
        ).encode("utf-8")
    finally:
        env.close()
    manifest = replace(remote, files={**remote.files, CARD_FILE: hashlib.sha256(card).hexdigest()})
    manifest = manifest.validated(where=f"{loaded.local_folder} (for {repo_id})")
    sha = hub_io.update_files(
        repo_id,
        {CARD_FILE: card, MANIFEST_FILE: manifest.to_json().encode("utf-8")},
        parent_commit=head,
        message="push_env: the card shows the reproductions merged since",
        description=f"content digest {manifest.content_digest}",
        token=token,
    )
    return sha, manifest


def _generated(path: str) -> bool:
    """A file push_env makes from the code (the dataset, the media, the card), not one the author wrote."""
    return path == CARD_FILE or path.startswith((f"{DATASET_DIR}/", f"{MEDIA_DIR}/"))


def _remote_manifest(repo_id: str, sha: str, token: str | None) -> Manifest | None:
    text = hub_io.read_remote_text(repo_id, MANIFEST_FILE, revision=sha, token=token)
    if text is None:
        return None
    try:
        return Manifest.from_json(text)
    except Exception:  # noqa: BLE001 - an unreadable manifest on main: the push replaces it
        return None


def _write_code(loaded: LoadedEnv, staging: Path, repo_id: str) -> str:
    """Stage 2: the env's own files and the generated ``env.py``; returns the code digest."""
    check_publishable(loaded.local_folder)  # no symlink out of the folder, no compiled files
    for rel in list_files(loaded.local_folder):
        dest = staging / rel
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(loaded.local_folder / rel, dest)
    (staging / ENV_ENTRY_FILE).write_text(_entry_text(repo_id), encoding="utf-8")
    return code_digest_of_files(hash_files(staging, list_files(staging)))


def _generate_dataset(
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
) -> _DatasetRun:
    """Stage 3, the one rollout pass: the dataset, its simulator states, the random-policy returns and the
    golden-rollout fingerprint (its seeds are the first dataset episodes; no second rollout of them)."""
    cfg = loaded.config
    returns: list[float] = []
    successes: list[bool] = []
    # env.get_state() before each action, for exact replay (hub_envs.dataset.states): to disk as episodes arrive,
    # beside the dataset folder (which the writer creates whole at its end), moved into it after
    states = EnvStatesWriter(staging / ".env_states.parquet")
    states_problem: list[str] = []
    first: list[Any] = []  # the fingerprint's episodes

    def frames():
        for rollout in backend.episodes(
            loaded,
            seeds,
            max_steps=int(cfg.episode_length),
            progress=progress,
            desc=f"Generating {len(seeds)} episodes",
            record_states=True,
        ):
            states.add(rollout.index, rollout.states)
            if rollout.states_problem and not states_problem:
                states_problem.append(f"episode {rollout.index}: {rollout.states_problem}")
            returns.append(float(np.sum(rollout.rewards)))
            successes.append(bool(np.any(rollout.is_success)))
            if rollout.index < fingerprint_seeds:
                first.append(episode_prefix(rollout, FINGERPRINT_STEPS))
            yield EpisodeFrames(index=rollout.index, seed=rollout.seed, frames=rollout_to_frames(rollout, cfg.features_map))

    try:
        summary = write_lerobot_dataset(
            staging / DATASET_DIR,
            repo_id=repo_id,
            fps=int(cfg.fps),
            features=features,
            episodes=frames(),
            task=str(cfg.task),
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
    if _has_get_state(loaded) and not has_states:
        reason = states_problem[0] if states_problem else states.reason
        warnings.warn(
            f"{where}: no simulator states recorded: {reason}. Replays of this dataset cannot restore a step with "
            "reset_to(); return one numeric array of a fixed shape from get_state() (hub_envs.dataset.states).",
            StatesNotRecordedWarning,
            stacklevel=4,
        )
    return _DatasetRun(
        summary=summary,
        features=features,
        digest=dataset_fingerprint(staging / DATASET_DIR) if has_states else summary.fingerprint,
        has_states=has_states,
        returns=returns,
        successes=successes,
        golden=fingerprint_of(first, steps=min(FINGERPRINT_STEPS, int(cfg.episode_length))),
        video_gop=video_gop if _dataset_uses_video({"features": features}) else None,
    )


def _published_overrides(loaded: LoadedEnv) -> dict[str, Any]:
    """The config fields the publisher set, as the config holds them (decoded: ``"50"`` is recorded as 50)."""
    values = encode_config(loaded.config)
    return {name: values[name] for name in sorted(loaded.manifest.config_overrides)}


def _draft_manifest(loaded: LoadedEnv, *, repo_id: str, code_digest: str, run: _DatasetRun, seed: int) -> Manifest:
    """Stage 4: the manifest of what was built, but ``files`` and ``content_digest`` (they cover the card too)."""
    summary = run.summary
    seeds = list(summary.seeds)
    return Manifest(
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
        config_overrides=_published_overrides(loaded),
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
        benchmarks=(_random_benchmark(run.returns, run.successes, seeds),),
        processors=tuple(loaded.manifest.processors),
        files={},
        content_digest="",
    )


def _media_env_maker(loaded: LoadedEnv, media_kwargs: dict[str, Any], folder: EnvFolder):
    """``make()`` for the card's media: the env with ``media_kwargs``; the author's ``[tool.hub-envs.media]
    gym_kwargs`` that the env refuses are named with where they come from."""

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


def build_repo(
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
    """Run the checks and write the complete repo content for ``loaded`` (a local folder) into ``staging``.

    The stages, in order: check the env (:func:`_check_env`) and the env the card's media need (the author's
    ``[tool.hub-envs.media] gym_kwargs``, :func:`_media_env_maker`), copy the code (:func:`_write_code`), the one
    rollout pass (:func:`_generate_dataset`: dataset, states, returns, fingerprint), the dataset half of the
    feature check, the GIF, the manifest and the card. Returns the manifest it wrote (validated as load_env
    validates it). The episodes run on ``backend`` (default: ``workers`` local processes); the repo content
    does not depend on where they ran. ``dataset_repo``: the card says the dataset is also in the dataset repo.
    """
    backend = backend if backend is not None else LocalBackend(workers=workers)
    where = f"{loaded.local_folder} (for {repo_id})"
    cfg = loaded.config
    say = _stage_printer(progress)
    say(f"Checking {loaded.local_folder.name}: determinism, gymnasium check_env, three-way features")
    env = _check_env(loaded, seed=seed, determinism_steps=determinism_steps, where=where)
    try:
        folder = EnvFolder.read(loaded.local_folder)
        media_kwargs = card_media_kwargs(cfg.gym_kwargs, folder.media_gym_kwargs)  # the author's camera, >= 256 px
        make_media_env = _media_env_maker(loaded, media_kwargs, folder)
        if folder.media_gym_kwargs:  # the author's media kwargs refused now, not after the dataset is built
            make_media_env().close()
        code_digest = _write_code(loaded, staging, repo_id)
        where_run = ", ".join(f"{k}={v}" for k, v in backend.settings().items() if v is not None)
        say(f"Generating the random-action dataset: {episodes} episodes x up to {cfg.episode_length} steps ({where_run})")
        run = _generate_dataset(
            loaded,
            staging,
            repo_id=repo_id,
            seeds=[seed + i for i in range(episodes)],
            backend=backend,
            code_digest=code_digest,
            fingerprint_seeds=fingerprint_seeds,
            features=dataset_features_from_config(cfg, action=stored_action(env.action_space), video=video),
            where=where,
            progress=progress,
            video_gop=video_gop,
        )
        check_features(cfg, env, read_info(staging / DATASET_DIR)["features"], seed=seed, where=where).raise_if_mismatch(where)
        say("Rendering the GIF and the card")
        seeds = list(run.summary.seeds)
        write_rollout_media(
            make_media_env,
            staging / GIF_FILE,
            seeds=seeds[:MEDIA_EPISODES],
            fps=int(cfg.fps),
            max_steps=min(MEDIA_STEPS, int(cfg.episode_length)),
            mp4_path=staging / MP4_FILE if video and _has_cameras(cfg) else None,
        )
        manifest = _draft_manifest(loaded, repo_id=repo_id, code_digest=code_digest, run=run, seed=seed)
        manifest = replace(
            manifest, content_digest=content_digest(hash_files(staging, list_files(staging, skip=(MANIFEST_FILE, CARD_FILE))))
        )
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
    finally:
        env.close()
    manifest = replace(manifest, files=hash_files(staging, list_files(staging, skip=(MANIFEST_FILE,)))).validated(where=where)
    (staging / MANIFEST_FILE).write_text(manifest.to_json(), encoding="utf-8")
    return manifest


# --- the dataset repo: the same dataset as a dataset-type repo of the same name, for LeRobot's own tools -------------

#: The tag ``LeRobotDataset(repo_id)`` opens when no revision is given: LeRobot's ``CODEBASE_VERSION``, resolved by its
#: ``get_safe_version`` among the dataset repo's tags (0.4.4 and 0.6.x alike). Each push moves it, as LeRobot's own
#: ``LeRobotDataset.push_to_hub`` does, after the env commit: it names the dataset the env repo's main publishes.
LEROBOT_DATASET_TAG = CODEBASE_VERSION


@dataclass(frozen=True)
class _DatasetRepo:
    """The dataset repo a push publishes to, as it is before the push (nothing written yet)."""

    repo_id: str
    head: str | None  # its main (None: no such repo yet)
    unchanged: bool  # main holds exactly the files of ``folder``, byte for byte
    remote_files: list[str]  # main's files (deleted by the commit unless ``folder`` has them)
    folder: Path  # what it will hold: the env repo's dataset/ (the same bytes) and a LeRobot dataset card
    private: bool  # create it private (the env repo is)


def _dataset_card(manifest: Manifest, info: dict[str, Any], license: str | None) -> str:
    """The dataset repo's README.md: LeRobot's own dataset card (``create_lerobot_dataset_card``: the ``LeRobot`` tag,
    the ``data/*/*.parquet`` config the Hub's viewer reads, ``info.json`` shown as LeRobot shows it) with what ties it
    to its env repo. Made of the manifest and ``info`` alone (the content tag, not a commit sha): the same content
    gives the same card."""
    from lerobot.datasets.utils import create_lerobot_dataset_card

    repo_id, tag, ds = manifest.repo_id, content_tag(manifest.content_digest), manifest.dataset
    description = (
        f"The random-action dataset of the env repo [{repo_id}](/{repo_id}) ({manifest.name} {manifest.version}), "
        f"published with it by hub-envs' `push_env`: {ds['episodes']} episodes, {ds['frames']} frames at {ds['fps']} fps, "
        f"each episode's reset seed recorded (`meta/hub_envs.json`). Its files are the env repo's `dataset/` folder, "
        f"byte for byte: the env's manifest `hub_env.json` lists their sha256 and names this repo's commit "
        f"(`dataset.dataset_repo`).\n\n"
        f'- `LeRobotDataset("{repo_id}")`: the latest publication (LeRobot opens the `{LEROBOT_DATASET_TAG}` tag, which '
        f"each push moves once its env commit is made)\n"
        f'- `LeRobotDataset("{repo_id}", revision="{tag}")`: exactly this content (the same tag is on both repos)\n'
        f'- the env that recorded it: `load_env("{repo_id}@{tag}", trust_remote_code=True)` (hub-envs), or '
        f'`make_env("{repo_id}@{tag}", trust_remote_code=True)` (LeRobot\'s EnvHub)'
    )
    card = create_lerobot_dataset_card(
        tags=["hub-envs", manifest.name],
        license=license,
        repo_id=repo_id,
        dataset_description=description,
        # what LeRobot's card shows for dataset_info=, given as text: 0.4.4 takes a dict there, 0.5+ a DatasetInfo
        dataset_structure=f"[meta/info.json](meta/info.json):\n```json\n{json.dumps(info, indent=4)}\n```\n",
    )
    return str(card)


def _stage_dataset_repo(staging: Path, manifest: Manifest, folder: Path, license: str | None) -> Path:
    """``folder`` holding what the dataset repo is to hold: ``staging``'s ``dataset/`` files (linked, not copied:
    the same bytes the manifest hashes) at its root, and the card."""
    source = staging / DATASET_DIR
    for rel in list_files(source):
        dest = folder / rel
        dest.parent.mkdir(parents=True, exist_ok=True)
        try:
            dest.hardlink_to(source / rel)
        except OSError:  # a file system without hard links
            shutil.copy2(source / rel, dest)
    (folder / CARD_FILE).write_text(_dataset_card(manifest, read_info(source), license), encoding="utf-8")
    return folder


def _published_by_push_env(repo_id: str, sha: str, token: str | None) -> bool:
    """Whether the dataset repo ``repo_id`` at ``sha`` is the dataset of the env repo of the same name (its
    ``meta/hub_envs.json`` names it): what push_env may replace, unlike a dataset someone published there by hand."""
    text = hub_io.read_remote_text(repo_id, HUB_ENVS_META_PATH, revision=sha, token=token, repo_type=hub_io.DATASET_REPO_TYPE)
    try:
        meta = json.loads(text) if text is not None else None
    except ValueError:
        return False
    env = meta.get("env_meta") if isinstance(meta, dict) else None
    return isinstance(env, dict) and env.get("env_repo_id") == repo_id


def _plan_dataset_repo(repo_id: str, folder: Path, *, private: bool, token: str | None) -> _DatasetRepo:
    """Read the dataset repo ``repo_id`` and refuse, before anything is written, what publishing to it would break:
    a dataset there that push_env did not publish (it would be replaced), or a public one beside a private env."""
    kind = hub_io.DATASET_REPO_TYPE
    env_private = hub_io.repo_private(repo_id, token=token)
    env_private = private if env_private is None else env_private  # an existing env repo keeps its visibility
    head = hub_io.remote_head(repo_id, token=token, repo_type=kind)
    remote = hub_io.remote_file_digests(repo_id, head, token=token, repo_type=kind) if head is not None else {}
    remote.pop(".gitattributes", None)  # the Hub's own
    if remote and not _published_by_push_env(repo_id, head, token):  # type: ignore[arg-type]
        raise ConfigError(
            f"The dataset repo {repo_id} (type dataset) holds a dataset push_env did not publish for the env repo "
            f"{repo_id}; publishing would replace its files. Nothing was published. Rename or delete that dataset repo, "
            f"or push with --dataset_repo=false (LeRobot users then open the dataset with --dataset.root)."
        )
    if env_private and hub_io.repo_private(repo_id, token=token, repo_type=kind) is False:
        raise ConfigError(
            f"The env repo {repo_id} is private but the dataset repo {repo_id} is public: publishing would make the "
            f"private env's dataset public. Nothing was published. Make it private "
            f"(HfApi().update_repo_settings({repo_id!r}, private=True, repo_type='dataset')) or delete it, then push "
            f"again, or push with --dataset_repo=false."
        )
    unchanged = head is not None and _holds_exactly(remote, folder)
    return _DatasetRepo(repo_id, head, unchanged, sorted(remote), folder, bool(env_private))


def _holds_exactly(remote: dict[str, str], folder: Path) -> bool:
    """Whether a commit's files (:func:`hub_io.remote_file_digests`, ``.gitattributes`` left out) are ``folder``'s, byte for byte."""
    local = {rel: folder / rel for rel in list_files(folder)}
    return set(remote) == set(local) and all(hub_io.local_file_digest(local[p], d) == d for p, d in remote.items())


def _with_dataset_repo(manifest: Manifest, repo_id: str, sha: str | None) -> Manifest:
    """The manifest naming the dataset repo commit that holds its dataset (None: not committed yet)."""
    return replace(manifest, dataset={**manifest.dataset, "dataset_repo": {"repo_id": repo_id, "revision": sha}})


def _publish_dataset_repo(plan: _DatasetRepo, manifest: Manifest, *, token: str | None) -> str:
    """Commit ``plan.folder`` to the dataset repo's main in one commit (none when main holds it already); its sha.
    No tag moves here: ``LeRobotDataset(repo_id)`` keeps opening the published dataset until the env commit is made."""
    if plan.unchanged:
        return plan.head  # type: ignore[return-value]
    sha = hub_io.publish_folder(
        plan.folder,
        plan.repo_id,
        parent_commit=plan.head,
        remote_files=plan.remote_files,
        message=f"push_env: the dataset of {plan.repo_id} ({manifest.dataset['episodes']} episodes)",
        description=f"content digest {manifest.content_digest}",
        private=plan.private,
        token=token,
        repo_type=hub_io.DATASET_REPO_TYPE,
    )
    remote = hub_io.remote_file_digests(plan.repo_id, sha, token=token, repo_type=hub_io.DATASET_REPO_TYPE)
    remote.pop(".gitattributes", None)
    if not _holds_exactly(remote, plan.folder):  # the manifest is about to name this commit: it must hold these bytes
        raise IntegrityError(
            f"The dataset repo {plan.repo_id} at its new commit {sha} does not hold the files push_env sent (the Hub at "
            f"{hub_io.endpoint()} lists other files or digests). The env repo was not changed, and LeRobot's "
            f"{LEROBOT_DATASET_TAG} tag still names the published dataset. Check the Hub, then push again."
        )
    return sha


def _dataset_commit_exists(repo_id: str, sha: str | None, token: str | None) -> bool:
    """Whether the dataset repo ``repo_id`` has commit ``sha``."""
    if sha is None:
        return False
    try:
        return hub_io.remote_head(repo_id, branch=sha, token=token, repo_type=hub_io.DATASET_REPO_TYPE) == sha
    except RevisionNotFoundError:
        return False


def _left_behind(manifest: Manifest) -> str:
    """What a push whose env commit failed after its dataset repo commit leaves behind, and how to finish it."""
    record = manifest.dataset["dataset_repo"]
    return (
        f"The dataset repo {record['repo_id']} got commit {record['revision']} on main before the env commit failed; its "
        f"{LEROBOT_DATASET_TAG} tag (what LeRobotDataset({record['repo_id']!r}) opens) still names the dataset the env repo "
        f"publishes. Push again to finish: the dataset is not committed a second time."
    )


def _tag_dataset_repo(manifest: Manifest, *, token: str | None) -> None:
    """Put the content tag (unless an earlier commit holds it) and LeRobot's ``v3.0`` on the dataset repo commit the
    manifest names."""
    record = manifest.dataset["dataset_repo"]
    repo_id, sha, kind = record["repo_id"], record["revision"], hub_io.DATASET_REPO_TYPE
    name = content_tag(manifest.content_digest)
    message = f"hub-envs content {manifest.content_digest}"
    if hub_io.tag_target(repo_id, name, token=token, repo_type=kind) in (None, sha):
        hub_io.tag(repo_id, sha, name, message=message, token=token, repo_type=kind)
    hub_io.move_tag(repo_id, sha, LEROBOT_DATASET_TAG, message=message, token=token, repo_type=kind)


def _tag(
    repo_id: str, sha: str, manifest: Manifest, tag: str | None, *, token: str | None, card_refresh: bool = False
) -> list[str]:
    """Put the content tag (unless an earlier commit with the same content holds it) and ``tag`` on ``sha``.

    ``card_refresh``: ``sha`` is a card-only commit on top of the one holding the content tag (:func:`_refresh_card`):
    the tag moves to it. Both commits hold the same content (the tag's promise), and the card names the tag for its
    load line (a commit cannot name its own sha), so the tag must follow the card that shows the reproductions.
    """
    tags = [content_tag(manifest.content_digest)] + ([tag] if tag else [])
    message = f"hub-envs content {manifest.content_digest}"
    for name in tags:
        if name == tags[0] and hub_io.tag_target(repo_id, name, token=token) not in (None, sha):
            if card_refresh:
                hub_io.move_tag(repo_id, sha, name, message=message, token=token)
            continue  # otherwise an earlier commit holds the same content and keeps its content tag
        hub_io.tag(repo_id, sha, name, message=message, token=token)
    return tags


def push_env(
    env_dir: str | Path,
    repo_id: str,
    *,
    episodes: int = 10,
    seed: int = 0,
    private: bool = False,
    tag: str | None = None,
    token: str | None = None,
    workers: int | None = None,
    commit_message: str | None = None,
    progress: bool = True,
    determinism_steps: int | None = None,
    force: bool = False,
    config: dict[str, Any] | None = None,
    video: bool | None = None,
    backend: str | Backend = "local",
    ray_address: str | None = None,
    out: str | Path | None = None,
    video_gop: int | None = None,
    dataset_repo: bool = True,
) -> PushResult:
    """Validate ``env_dir``, generate its dataset and card, and publish it to ``repo_id`` in one commit.

    Pushing content identical to the repo's current main makes no new commit (the result says so).
    When main already holds what this push would build (same code, config, seeds, episodes and recorded
    versions: :func:`_published_unchanged`), nothing is regenerated and the push takes about a second;
    ``force=True`` rebuilds and compares everything. ``determinism_steps`` caps the determinism check
    (default: a whole episode, for two seeds). ``config`` sets fields of the env's config before its
    ``__post_init__`` (``{"obs_type": "pixels_agent_pos"}``; the CLI's ``--config.<field>=<value>``): the
    variant is published from the same folder, and load_env rebuilds it from the manifest. ``video``: store
    camera (VISUAL) features as MP4 videos encoded by LeRobot's own encoder (dtype ``"video"``, LeRobot's default
    for cameras) rather than PNG images in the parquet; default (None): True when the env has camera features
    of at least :data:`~hub_envs.dataset.video.MIN_VIDEO_SIDE` px a side (smaller frames crash the encoder).
    Replay compares video frames within :data:`hub_envs.dataset.video.VIDEO_TOLERANCE` (the codec is lossy).
    ``video_gop``: their keyframe interval (default :data:`~hub_envs.dataset.video.DEFAULT_VIDEO_GOP`, 10: a
    dataset about a fifth of its PNG size; 2 is LeRobot's own setting, faster random access for training).

    ``backend="ray"`` generates the dataset on a Ray cluster (``ray_address``, default ``$RAY_ADDRESS`` or a
    local Ray started for the push; :mod:`hub_envs.backends`): the folder's files travel with the job, the
    dataset and the content tag are identical to the local backend's. ``out``: a folder where a Ray run keeps
    its finished shards (the same push started again skips them). Nothing is committed until every
    episode is written: an interrupted push leaves no commit and no partial dataset.

    Before anything is built, the Hub is asked who the caller is (:func:`hub_envs.hub_io.check_write_access`): no
    token where one is needed, a refused or read-only token, or an account that cannot write ``repo_id``'s
    namespace raises :class:`~hub_envs.errors.HubAccessError` at once.

    ``dataset_repo`` (default True): also publish the dataset as the dataset-type repo of the same name, so LeRobot's
    own tools open it by repo id (``LeRobotDataset(repo_id)``, ``lerobot-train --dataset.repo_id``,
    ``lerobot-dataset-viz``). Its files are the env repo's ``dataset/`` byte for byte; its commit is made first and
    the env's manifest names it (``dataset.dataset_repo``), then the env commit, then the tags: the content tag on
    both repos, and on the dataset repo LeRobot's ``v3.0`` (what ``LeRobotDataset(repo_id)`` opens), moved last. A
    push that fails before its env commit leaves ``v3.0`` on the published dataset; pushing again completes it
    (an unchanged dataset is not committed again). The dataset repo is private when the env repo is.
    """
    if episodes < 1:
        raise ConfigError(f"--episodes must be at least 1, got {episodes}.")
    repo_id, rev = hub_io.parse_repo_ref(repo_id)
    if rev is not None:
        raise ConfigError(f"push_env publishes to main; drop '@{rev}' from {repo_id}@{rev} (use --tag to name the commit).")
    gop = DEFAULT_VIDEO_GOP if video_gop is None else check_video_gop(video_gop, name="--video_gop")
    runner = make_backend(backend, workers=workers, ray_address=ray_address, checkpoint_dir=out)
    env_dir = Path(env_dir)
    if not env_dir.is_dir():
        raise EnvFolderError(f"Env folder {env_dir} does not exist. Pass --env_dir=PATH to the folder with pyproject.toml.")
    check_publishable(env_dir)  # before anything runs: a symlink out of the folder would publish its target
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    hub_io.check_write_access(repo_id, token=token)  # before anything is built: no token, or one that cannot write here
    loaded = load_env(env_dir.resolve(), check=False, config=config)
    try:
        attestations = _merged_attestations(repo_id, token)
        video = _default_video(loaded.config) if video is None else bool(video)
        unchanged = (
            None
            if force
            else _published_unchanged(
                loaded,
                repo_id,
                episodes=episodes,
                seed=seed,
                fingerprint_seeds=FINGERPRINT_SEEDS,
                token=token,
                attestations=attestations,
                video=video,
                video_gop=gop,
                dataset_repo=dataset_repo,
            )
        )
        if unchanged is not None:
            sha, manifest, card_current = unchanged
            say = _stage_printer(progress)
            say(f"{repo_id}@{sha} already holds this code, config, seeds and versions: nothing to build")
            if not card_current:
                say("Reproductions were merged since its card was rendered: committing the card again, nothing else")
                sha, manifest = _refresh_card(loaded, repo_id, sha, manifest, attestations, token=token)
            tags = _tag(repo_id, sha, manifest, tag, token=token, card_refresh=not card_current)
            if dataset_repo:
                _tag_dataset_repo(manifest, token=token)  # puts back a v3.0 moved by hand, or left behind by a failed push
            timings["total"] = time.perf_counter() - t0
            return PushResult(
                repo_id=repo_id,
                sha=sha,
                created_commit=not card_current,
                content_tag=tags[0],
                manifest=manifest,
                timings=timings,
                tags=tags,
                dataset_sha=manifest.dataset["dataset_repo"]["revision"] if dataset_repo else None,
            )
        with tempfile.TemporaryDirectory(prefix="hub-envs-push-") as tmp, runner:
            staging = Path(tmp) / "repo"
            staging.mkdir()
            manifest = build_repo(
                loaded,
                staging,
                repo_id=repo_id,
                episodes=episodes,
                seed=seed,
                determinism_steps=determinism_steps,
                progress=progress,
                attestations=attestations,
                video=video,
                backend=runner,
                video_gop=gop,
                dataset_repo=dataset_repo,
            )
            timings["build"] = time.perf_counter() - t0
            t = time.perf_counter()
            _stage_printer(progress)(f"Publishing to {repo_id} at {hub_io.endpoint()}")
            head = hub_io.remote_head(repo_id, token=token)
            remote_manifest = _remote_manifest(repo_id, head, token) if head is not None else None
            # what the Hub workflow added (merged attestations: beyond_manifest) stays: the push neither lists nor deletes it
            remote_files = [p for p in hub_io.list_remote_files(repo_id, head, token=token) if not beyond_manifest(p)]
            same_files = set(remote_files) == set(manifest.files)
            plan = None
            if dataset_repo:  # read and checked before anything is written
                license = EnvFolder.read(loaded.local_folder).license
                folder = _stage_dataset_repo(staging, manifest, Path(tmp) / "dataset-repo", license)
                plan = _plan_dataset_repo(repo_id, folder, private=private, token=token)
                manifest = _with_dataset_repo(manifest, repo_id, plan.head if plan.unchanged else None)

            def env_unchanged() -> bool:
                return remote_manifest is not None and remote_manifest.to_json() == manifest.to_json() and same_files

            if not env_unchanged() and tag and hub_io.tag_target(repo_id, tag, token=token) is not None:
                raise ConfigError(
                    f"Tag {tag!r} of {repo_id} already names commit {hub_io.tag_target(repo_id, tag, token=token)}; this "
                    f"push would make a new commit. Choose another --tag (nothing was published)."
                )
            if plan is not None:  # 1. the dataset repo's commit, which the env's manifest then names
                ds_sha = _publish_dataset_repo(plan, manifest, token=token)
                manifest = _with_dataset_repo(manifest, repo_id, ds_sha).validated(where=f"{loaded.local_folder} (for {repo_id})")
                (staging / MANIFEST_FILE).write_text(manifest.to_json(), encoding="utf-8")
            if env_unchanged():
                sha, created = head, False
            else:  # 2. the env commit
                message = (
                    commit_message
                    or f"push_env: {manifest.name} {manifest.version} ({manifest.dataset['episodes']} episodes, seed {seed})"
                )
                try:
                    sha = hub_io.publish_folder(
                        staging,
                        repo_id,
                        parent_commit=head,
                        remote_files=remote_files,
                        message=message,
                        description=f"content digest {manifest.content_digest}",
                        private=private,
                        token=token,
                    )
                except HubEnvsError as e:
                    if plan is None or plan.unchanged:
                        raise
                    raise type(e)(f"{e}\n{_left_behind(manifest)}") from e.__cause__  # the same error, said in full
                created = True
            tags = _tag(repo_id, sha, manifest, tag, token=token)  # 3. the tags: the env's, then the dataset repo's
            if plan is not None:
                _tag_dataset_repo(manifest, token=token)
            timings["publish"] = time.perf_counter() - t
    finally:
        loaded.unregister()
        forget_env_folder(module_key(loaded.repo_id, loaded.revision))  # push keeps nothing imported
    timings["total"] = time.perf_counter() - t0
    return PushResult(
        repo_id=repo_id,
        sha=sha,
        created_commit=created,
        content_tag=tags[0],
        manifest=manifest,
        timings=timings,
        tags=tags,
        dataset_sha=manifest.dataset["dataset_repo"]["revision"] if dataset_repo else None,
    )
