"""``push_env``: validate a local env folder, build its repo (dataset, media, manifest, card) and publish it in one
commit, as the pipeline prepare, already published?, build, publish.

Example:
    >>> from hub_envs import push_env
    >>> result = push_env("envs/pendulum", "user/pendulum-lerobot", episodes=10)   # doctest: +SKIP
    >>> result.load_line                                                            # doctest: +SKIP
    'load_env("user/pendulum-lerobot@3f2a…", trust_remote_code=True)'
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hub_envs.backends import Backend, make_backend
from hub_envs.dataset.video import DEFAULT_VIDEO_GOP, check_video_gop
from hub_envs.envcode.importing import forget_env_folder, module_key
from hub_envs.errors import ConfigError, EnvFolderError, HubEnvsError
from hub_envs.loading.load import load_env
from hub_envs.loading.loaded import LoadedEnv
from hub_envs.publishing.build import FINGERPRINT_SEEDS, build, default_video, stage_printer
from hub_envs.publishing.dataset_repo import (
    LEROBOT_DATASET_TAG,
    DatasetRepo,
    left_behind,
    plan_dataset_repo,
    publish_dataset_repo,
    stage_dataset_repo,
    tag_dataset_repo,
    with_dataset_repo,
)
from hub_envs.publishing.unchanged import published_unchanged, refresh_card, remote_manifest
from hub_envs.repo import hub_io
from hub_envs.repo.attestations import merged_attestations
from hub_envs.repo.format import MANIFEST_FILE, EnvFolder, Manifest, beyond_manifest, check_publishable, content_tag
from hub_envs.repo.refs import parse_repo_ref


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

    The stages: the Hub is asked first whether the caller may write ``repo_id``; the folder is loaded as load_env loads
    it; when main already holds what this push would build (same code, config, seeds, episodes and recorded versions:
    :func:`~hub_envs.publishing.unchanged.published_unchanged`) nothing is rebuilt; else the repo is built in a
    temporary folder (:func:`~hub_envs.publishing.build.build`: every check passes or nothing is published) and
    published: the dataset repo's commit first (the env's manifest names it), then the env commit, then the tags (the
    content tag on both repos; LeRobot's ``v3.0`` on the dataset repo, moved last). Content identical to main makes
    no new commit. Nothing is committed until every episode is written: an interrupted push leaves no commit and no
    partial dataset.

    Args:
        env_dir: the env folder (``pyproject.toml`` with ``[tool.hub-envs]``, the env's code).
        repo_id: the Hub repo to publish to (``user/name``; main: no ``@revision``).
        episodes: random-action episodes of the dataset; episode ``i`` resets with seed ``seed + i``.
        seed: the first episode's seed, and the checks'.
        private: create the repo private (an existing repo keeps its visibility; the dataset repo follows it).
        tag: a tag of your own for the commit (refused if it names another commit).
        token: the Hub token (None: huggingface_hub's own: ``HF_TOKEN``, ``hf auth login``).
        workers: processes (local; default as many as useful here) or Ray actors (default: the cluster's CPUs).
        commit_message: the commit's message (default: ``push_env: <name> <version> (<n> episodes, seed <s>)``).
        progress: say each stage on stderr, with progress bars.
        determinism_steps: cap of the determinism check (default: a whole episode, for two seeds).
        force: rebuild and compare everything even when main already holds this code, config, seeds and versions.
        config: fields of the env's config set before its ``__post_init__`` (``{"obs_type": "pixels_agent_pos"}``; the
            CLI's ``--config.<field>=<value>``): a variant, published from the same folder; load_env rebuilds it from
            the manifest.
        video: store camera (VISUAL) features as MP4 videos encoded by LeRobot's own encoder (dtype ``"video"``) rather
            than PNG images in the parquet; None: True when the env has cameras of at least
            :data:`~hub_envs.dataset.video.MIN_VIDEO_SIDE` px a side (smaller frames crash the encoder). Replay
            compares video frames within :data:`~hub_envs.dataset.video.VIDEO_TOLERANCE` (the codec is lossy).
        backend: where the episodes run: ``"local"`` or ``"ray"`` (the folder's files travel with the job; the dataset
            and the content tag are identical to the local backend's), or a :class:`~hub_envs.backends.Backend`.
        ray_address: the Ray cluster (default ``$RAY_ADDRESS``, else a local Ray started for the push).
        out: a folder where a Ray run keeps its finished shards (the same push started again skips them).
        video_gop: the videos' keyframe interval (default :data:`~hub_envs.dataset.video.DEFAULT_VIDEO_GOP`, 10: a
            dataset about a fifth of its PNG size; LeRobot's own 2 gives faster random access for training).
        dataset_repo: also publish the dataset as the dataset-type repo of the same name, so LeRobot's own tools open
            it by repo id (``LeRobotDataset(repo_id)``, ``lerobot-train --dataset.repo_id``, ``lerobot-dataset-viz``):
            its files are the env repo's ``dataset/`` byte for byte, named by the manifest (``dataset.dataset_repo``).
            A push that fails before its env commit leaves ``v3.0`` on the published dataset; pushing again completes
            it.

    Returns:
        The :class:`PushResult`: the commit, whether it is new, the tags, the manifest.

    Raises:
        ConfigError: an argument that is not an option, a revision in ``repo_id``, a ``tag`` naming another commit, or
            a dataset repo push_env may not replace.
        EnvFolderError: ``env_dir`` is not an env folder (or holds a symlink out of it, or compiled files).
        HubAccessError: no token where one is needed, a refused or read-only token, or an account that cannot write
            ``repo_id``'s namespace (asked before anything is built).
        DeterminismError, EnvCheckError, FeatureMismatchError, EnvCodeError: a check failed; nothing was published.
        HubError, IntegrityError: publishing failed (the message says what was left behind and how to finish).
    """
    repo_id, gop = _checked_arguments(repo_id, episodes=episodes, video_gop=video_gop)
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
        video = default_video(loaded.config) if video is None else bool(video)
        unchanged = None
        if not force:
            unchanged = published_unchanged(
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
        if unchanged is not None:
            sha, manifest, tags, created = _already_published(
                loaded, repo_id, unchanged, attestations, tag=tag, dataset_repo=dataset_repo, token=token, progress=progress
            )
        else:
            with tempfile.TemporaryDirectory(prefix="hub-envs-push-") as tmp, runner:
                staging = Path(tmp) / "repo"
                staging.mkdir()
                manifest = build(
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
                sha, manifest, tags, created = _publish(
                    loaded,
                    staging,
                    manifest,
                    repo_id,
                    dataset_folder=Path(tmp) / "dataset-repo" if dataset_repo else None,
                    tag=tag,
                    private=private,
                    message=commit_message or f"push_env: {manifest.name} {manifest.version} ({episodes} episodes, seed {seed})",
                    token=token,
                    progress=progress,
                )
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


def _checked_arguments(repo_id: str, *, episodes: int, video_gop: int | None) -> tuple[str, int]:
    """``(repo_id, video_gop)`` checked before anything runs (a :class:`ConfigError` naming what is wrong)."""
    if episodes < 1:
        raise ConfigError(f"--episodes must be at least 1, got {episodes}.")
    repo_id, rev = parse_repo_ref(repo_id)
    if rev is not None:
        raise ConfigError(f"push_env publishes to main; drop '@{rev}' from {repo_id}@{rev} (use --tag to name the commit).")
    return repo_id, DEFAULT_VIDEO_GOP if video_gop is None else check_video_gop(video_gop, name="--video_gop")


def _already_published(
    loaded: LoadedEnv,
    repo_id: str,
    unchanged: tuple[str, Manifest, bool],
    attestations: list,
    *,
    tag: str | None,
    dataset_repo: bool,
    token: str | None,
    progress: bool,
) -> tuple[str, Manifest, list[str], bool]:
    """Main holds this push's content: only its card is committed again (when reproductions were merged since), and
    the tags put back. ``(sha, manifest, tags, created_commit)``."""
    sha, manifest, card_current = unchanged
    say = stage_printer(progress)
    say(f"{repo_id}@{sha} already holds this code, config, seeds and versions: nothing to build")
    if not card_current:
        say("Reproductions were merged since its card was rendered: committing the card again, nothing else")
        sha, manifest = refresh_card(loaded, repo_id, sha, manifest, attestations, token=token)
    tags = _tag(repo_id, sha, manifest, tag, token=token, card_refresh=not card_current)
    if dataset_repo:
        tag_dataset_repo(manifest, token=token)  # puts back a v3.0 moved by hand, or left behind by a failed push
    return sha, manifest, tags, not card_current


def _publish(
    loaded: LoadedEnv,
    staging: Path,
    manifest: Manifest,
    repo_id: str,
    *,
    dataset_folder: Path | None,
    tag: str | None,
    private: bool,
    message: str,
    token: str | None,
    progress: bool,
) -> tuple[str, Manifest, list[str], bool]:
    """Publish a built repo: the dataset repo's commit (which the env's manifest then names), the env commit (none
    when main holds exactly this), the tags. What would break is refused before anything is written.
    ``(sha, manifest, tags, created_commit)``."""
    stage_printer(progress)(f"Publishing to {repo_id} at {hub_io.endpoint()}")
    head = hub_io.remote_head(repo_id, token=token)
    remote = remote_manifest(repo_id, head, token) if head is not None else None
    # what the Hub workflow added (merged attestations: beyond_manifest) stays: the push neither lists nor deletes it
    remote_files = [p for p in hub_io.list_remote_files(repo_id, head, token=token) if not beyond_manifest(p)]
    plan: DatasetRepo | None = None
    if dataset_folder is not None:  # read and checked before anything is written
        license = EnvFolder.read(loaded.local_folder).license
        plan = plan_dataset_repo(
            repo_id, stage_dataset_repo(staging, manifest, dataset_folder, license), private=private, token=token
        )
        manifest = with_dataset_repo(manifest, repo_id, plan.head if plan.unchanged else None)

    def env_unchanged() -> bool:
        return remote is not None and remote.to_json() == manifest.to_json() and set(remote_files) == set(manifest.files)

    if not env_unchanged() and tag and hub_io.tag_target(repo_id, tag, token=token) is not None:
        raise ConfigError(
            f"Tag {tag!r} of {repo_id} already names commit {hub_io.tag_target(repo_id, tag, token=token)}; this "
            f"push would make a new commit. Choose another --tag (nothing was published)."
        )
    if plan is not None:  # 1. the dataset repo's commit, which the env's manifest then names
        ds_sha = publish_dataset_repo(plan, manifest, token=token)
        manifest = with_dataset_repo(manifest, repo_id, ds_sha).validated(where=f"{loaded.local_folder} (for {repo_id})")
        (staging / MANIFEST_FILE).write_text(manifest.to_json(), encoding="utf-8")
    if env_unchanged():
        sha, created = head, False
    else:  # 2. the env commit
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
            raise type(e)(f"{e}\n{left_behind(manifest)}") from e.__cause__  # the same error, said in full
        created = True
    tags = _tag(repo_id, sha, manifest, tag, token=token)  # 3. the tags: the env's, then the dataset repo's
    if plan is not None:
        tag_dataset_repo(manifest, token=token)
    return sha, manifest, tags, created


@dataclass
class PushResult:
    """What push_env did.

    Attributes:
        repo_id: the env repo.
        sha: the commit of main that holds the env (new, or the one that already held it).
        created_commit: whether this push made a commit.
        content_tag: ``sha256-<digest16>``, the tag naming this content (the card's load line pins it).
        manifest: the published manifest.
        timings: seconds per stage (``build``, ``publish``, ``total``).
        tags: the tags put on ``sha``.
        dataset_sha: the dataset repo's commit holding the dataset (None: ``dataset_repo=False``).
    """

    repo_id: str
    sha: str
    created_commit: bool
    content_tag: str
    manifest: Manifest
    timings: dict[str, float] = field(default_factory=dict)
    tags: list[str] = field(default_factory=list)
    dataset_sha: str | None = None

    @property
    def load_line(self) -> str:
        """``load_env("user/name@<sha>", trust_remote_code=True)``: the pinned load of what was published."""
        return f'load_env("{self.repo_id}@{self.sha}", trust_remote_code=True)'

    def summary(self) -> str:
        """What was published, and how to load it (what ``push_env`` prints)."""
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


def _merged_attestations(repo_id: str, token: str | None) -> list:
    """The valid attestations on main (:func:`hub_envs.repo.attestations.merged_attestations`: entries naming the author
    of the pull request each came from); invalid ones are skipped."""
    return [e for e in merged_attestations(repo_id, token=token) if e.attestation is not None]


def _tag(
    repo_id: str, sha: str, manifest: Manifest, tag: str | None, *, token: str | None, card_refresh: bool = False
) -> list[str]:
    """Put the content tag (unless an earlier commit with the same content holds it) and ``tag`` on ``sha``.

    ``card_refresh``: ``sha`` is a card-only commit on top of the one holding the content tag (:func:`~hub_envs.publishing.unchanged.refresh_card`):
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
