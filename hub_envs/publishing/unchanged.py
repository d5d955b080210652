"""Whether main already holds what a push would build (then nothing is rebuilt), and the card-only commit when
reproductions were merged since its card was rendered."""

from __future__ import annotations

import hashlib
from dataclasses import replace
from typing import Any

from hub_envs._compat import LEROBOT_VIDEO_GOP
from hub_envs._stack import requirement_closure
from hub_envs.dataset.video import DEFAULT_VIDEO_GOP
from hub_envs.envcode.envconfig import encode_config
from hub_envs.harness.media import card_media_kwargs
from hub_envs.harness.provenance import package_versions
from hub_envs.loading.loaded import LoadedEnv
from hub_envs.publishing.build import cameras, code_files_of, dataset_seeds, dataset_uses_video, published_overrides
from hub_envs.publishing.card import render_card, reproduced_table
from hub_envs.publishing.dataset_repo import dataset_commit_exists
from hub_envs.repo import hub_io
from hub_envs.repo.format import (
    CARD_FILE,
    DATASET_DIR,
    MANIFEST_FILE,
    MEDIA_DIR,
    SINGLE_TASK_FORMAT_VERSION,
    SUITE_FORMAT_VERSION,
    EnvFolder,
    Manifest,
    beyond_manifest,
    content_tag,
)
from hub_envs.repo.format import code_digest as code_digest_of_files


def _card_shows(repo_id: str, sha: str, table: str, token: str | None) -> bool:
    """Whether the card at ``sha`` already shows ``table`` (the "Reproduced on" table; "" for none)."""
    card = hub_io.read_remote_text(repo_id, CARD_FILE, revision=sha, token=token) or ""
    return table in card if table else "## Reproduced on" not in card


def published_unchanged(
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

    Args:
        loaded: the env folder, loaded.
        repo_id: the env repo.
        episodes, seed, fingerprint_seeds, video, video_gop, dataset_repo: what the push would build.
        token: the Hub token.
        attestations: the merged attestations.

    Returns:
        None when a build is needed; else ``(sha, manifest, card_current)``: main's commit and manifest, and whether
        its card already shows the merged ``attestations`` of this content ("Reproduced on"; when one was merged since
        the last push, only the card is re-rendered: :func:`refresh_card`).
    """
    head = hub_io.remote_head(repo_id, token=token)
    if head is None:
        return None
    remote = remote_manifest(repo_id, head, token)
    if remote is None:
        return None
    local = loaded.manifest
    tasks = local.task_names  # a suite's (the folder's [tool.hub-envs] tasks)
    seeds = dataset_seeds(seed, episodes, len(tasks))
    code = code_files_of(loaded, repo_id)
    same = (
        remote.format_version == (SUITE_FORMAT_VERSION if tasks else SINGLE_TASK_FORMAT_VERSION)
        and remote.task_names == tasks
        and all(t["episodes"] == list(range(i * episodes, (i + 1) * episodes)) for i, t in enumerate(remote.tasks))
        and remote.repo_id == repo_id
        and {p: h for p, h in remote.files.items() if not _generated(p)} == code
        and remote.code_digest == code_digest_of_files(code)
        and remote.config == encode_config(loaded.config)
        and remote.config_overrides == published_overrides(loaded)
        and remote.seeds.get("dataset") == seeds
        and remote.seeds.get("check") == seed
        and remote.dataset.get("episodes") == len(seeds)
        and dataset_uses_video(remote.dataset) == (video and bool(cameras(loaded.config)))
        and (not dataset_uses_video(remote.dataset) or remote.dataset.get("video_gop", LEROBOT_VIDEO_GOP) == video_gop)
        and remote.fingerprint.get("seeds") == _default_task_seeds(local, loaded.config, seeds, episodes)[:fingerprint_seeds]
        and (remote.name, remote.version, remote.description) == (local.name, local.version, local.description)
        and remote.requirements == tuple(local.requirements)
        and remote.processors == tuple(local.processors)
        and remote.versions == package_versions(local.requirements)
        and remote.resolved == requirement_closure(local.requirements)
        and ("dataset_repo" in remote.dataset) == dataset_repo
    )
    if not same:
        return None
    if dataset_repo and not dataset_commit_exists(repo_id, remote.dataset["dataset_repo"].get("revision"), token):
        return None
    remote_files = {p for p in hub_io.list_remote_files(repo_id, head, token=token) if not beyond_manifest(p)}
    if remote_files != set(remote.files):
        return None
    table = reproduced_table([e for e in attestations if e.attestation.content_digest == remote.content_digest])
    return head, remote, _card_shows(repo_id, head, table, token)


def refresh_card(
    loaded: LoadedEnv, repo_id: str, head: str, remote: Manifest, attestations: list, *, token: str | None
) -> tuple[str, Manifest]:
    """Main holds this content, but attestations were merged since its card was rendered: render the card again from
    main's manifest (as :func:`~hub_envs.publishing.build.build` renders it) and commit it with the manifest's new hash
    of it, on top of ``head``: nothing else is rebuilt, and the content digest (which excludes the card) stays.

    Args:
        loaded: the env folder, loaded.
        repo_id: the env repo.
        head: main's commit.
        remote: main's manifest.
        attestations: the merged attestations.
        token: the Hub token.

    Returns:
        ``(sha, manifest)`` of the card's commit.
    """
    env = loaded.make()
    folder = EnvFolder.read(loaded.local_folder)
    try:
        card = render_card(
            replace(remote, files={}),  # as build renders it: before the files are hashed
            env_class=loaded.env_class,
            media_kwargs=card_media_kwargs(loaded.config.gym_kwargs, folder.media_gym_kwargs),
            env=env,
            content_tag=content_tag(remote.content_digest),
            license=folder.license,
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


def _default_task_seeds(local: Manifest, config: Any, seeds: list[int], episodes: int) -> list[int]:
    """The dataset seeds of the task the top-level fingerprint is of: a suite's default task's, else all."""
    if not local.tasks:
        return seeds
    index = local.task_names.index(config.task) if config.task in local.task_names else 0
    return seeds[index * episodes : (index + 1) * episodes]


def _generated(path: str) -> bool:
    """A file push_env makes from the code (the dataset, the media, the card), not one the author wrote."""
    return path == CARD_FILE or path.startswith((f"{DATASET_DIR}/", f"{MEDIA_DIR}/"))


def remote_manifest(repo_id: str, sha: str, token: str | None) -> Manifest | None:
    """The manifest of ``repo_id`` at ``sha``.

    Args:
        repo_id: the env repo.
        sha: a commit.
        token: the Hub token.

    Returns:
        The manifest; None when there is none, or it cannot be read (the push replaces it).
    """
    text = hub_io.read_remote_text(repo_id, MANIFEST_FILE, revision=sha, token=token)
    if text is None:
        return None
    try:
        return Manifest.from_json(text)
    except Exception:  # noqa: BLE001 - an unreadable manifest on main: the push replaces it
        return None
