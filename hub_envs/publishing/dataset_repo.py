"""The dataset repo a push publishes beside the env repo: the same dataset, byte for byte, as the dataset-type repo of
the same name with LeRobot's own dataset card, for LeRobot's tools (``LeRobotDataset(repo_id)``)."""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from hub_envs.dataset.layout import CODEBASE_VERSION, HUB_ENVS_META_PATH
from hub_envs.dataset.reader import read_info
from hub_envs.errors import ConfigError, IntegrityError, RevisionNotFoundError
from hub_envs.repo import hub_io
from hub_envs.repo.format import CARD_FILE, DATASET_DIR, Manifest, content_tag, list_files

#: The tag ``LeRobotDataset(repo_id)`` opens when no revision is given: LeRobot's ``CODEBASE_VERSION``, resolved by its
#: ``get_safe_version`` among the dataset repo's tags (0.4.4 and 0.6.x alike). Each push moves it, as LeRobot's own
#: ``LeRobotDataset.push_to_hub`` does, after the env commit: it names the dataset the env repo's main publishes.
LEROBOT_DATASET_TAG = CODEBASE_VERSION


@dataclass(frozen=True)
class DatasetRepo:
    """The dataset repo a push publishes to, as it is before the push (nothing written yet)."""

    repo_id: str
    head: str | None  # its main (None: no such repo yet)
    unchanged: bool  # main holds exactly the files of ``folder``, byte for byte
    remote_files: list[str]  # main's files (deleted by the commit unless ``folder`` has them)
    folder: Path  # what it will hold: the env repo's dataset/ (the same bytes) and a LeRobot dataset card
    private: bool  # create it private (the env repo is)


def dataset_card(manifest: Manifest, info: dict[str, Any], license: str | None) -> str:
    """The dataset repo's ``README.md``: LeRobot's own dataset card (``create_lerobot_dataset_card``: the ``LeRobot`` tag, the
    ``data/*/*.parquet`` config the Hub's viewer reads, ``info.json`` shown as LeRobot shows it) with what ties it to its
    env repo. Made of the manifest and ``info`` alone (the content tag, not a commit sha): the same content gives the
    same card.

    Args:
        manifest: the env's manifest.
        info: the dataset's ``meta/info.json``.
        license: the env folder's license (an SPDX id), or None.

    Returns:
        The card's text.
    """
    from lerobot.datasets.utils import create_lerobot_dataset_card  # heavy: lerobot's datasets (torch)

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


def stage_dataset_repo(staging: Path, manifest: Manifest, folder: Path, license: str | None) -> Path:
    """``folder`` holding what the dataset repo is to hold: ``staging``'s ``dataset/`` files (linked, not copied: the same
    bytes the manifest hashes) at its root, and the card (:func:`dataset_card`).

    Args:
        staging: the env repo's staging folder.
        manifest: the env's manifest.
        folder: an empty folder.
        license: the env folder's license, or None.

    Returns:
        ``folder``.
    """
    source = staging / DATASET_DIR
    for rel in list_files(source):
        dest = folder / rel
        dest.parent.mkdir(parents=True, exist_ok=True)
        try:
            dest.hardlink_to(source / rel)
        except OSError:  # a file system without hard links
            shutil.copy2(source / rel, dest)
    (folder / CARD_FILE).write_text(dataset_card(manifest, read_info(source), license), encoding="utf-8")
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


def plan_dataset_repo(repo_id: str, folder: Path, *, private: bool, token: str | None) -> DatasetRepo:
    """Read the dataset repo ``repo_id`` and refuse, before anything is written, what publishing to it would break.

    Args:
        repo_id: the dataset repo (the env repo's name).
        folder: what it is to hold (:func:`stage_dataset_repo`).
        private: the env repo is to be created private.
        token: the Hub token.

    Returns:
        The :class:`DatasetRepo` record: its head, and whether it holds ``folder`` already.

    Raises:
        ConfigError: a dataset there that push_env did not publish (it would be replaced), or a public one beside a
            private env.
    """
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
    return DatasetRepo(repo_id, head, unchanged, sorted(remote), folder, bool(env_private))


def _holds_exactly(remote: dict[str, str], folder: Path) -> bool:
    """Whether a commit's files (:func:`hub_io.remote_file_digests`, ``.gitattributes`` left out) are ``folder``'s, byte for byte."""
    local = {rel: folder / rel for rel in list_files(folder)}
    return set(remote) == set(local) and all(hub_io.local_file_digest(local[p], d) == d for p, d in remote.items())


def with_dataset_repo(manifest: Manifest, repo_id: str, sha: str | None) -> Manifest:
    """The manifest naming the dataset repo commit that holds its dataset.

    Args:
        manifest: the env's manifest.
        repo_id: the dataset repo.
        sha: its commit (None: not committed yet).

    Returns:
        A copy of ``manifest`` with ``dataset.dataset_repo``.
    """
    return replace(manifest, dataset={**manifest.dataset, "dataset_repo": {"repo_id": repo_id, "revision": sha}})


def publish_dataset_repo(plan: DatasetRepo, manifest: Manifest, *, token: str | None) -> str:
    """Commit ``plan.folder`` to the dataset repo's main in one commit (none when main holds it already). No tag moves
    here: ``LeRobotDataset(repo_id)`` keeps opening the published dataset until the env commit is made.

    Args:
        plan: the dataset repo's record (:func:`plan_dataset_repo`).
        manifest: the env's manifest (the commit message names its content).
        token: the Hub token.

    Returns:
        The dataset repo's commit holding the dataset.

    Raises:
        IntegrityError: the new commit does not hold exactly the files sent.
    """
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


def dataset_commit_exists(repo_id: str, sha: str | None, token: str | None) -> bool:
    """Whether the dataset repo ``repo_id`` has commit ``sha``.

    Args:
        repo_id: the dataset repo.
        sha: a commit (None: no).
        token: the Hub token.

    Returns:
        True when it has.
    """
    if sha is None:
        return False
    try:
        return hub_io.remote_head(repo_id, branch=sha, token=token, repo_type=hub_io.DATASET_REPO_TYPE) == sha
    except RevisionNotFoundError:
        return False


def left_behind(manifest: Manifest) -> str:
    """What a push whose env commit failed after its dataset repo commit leaves behind, and how to finish it.

    Args:
        manifest: the env's manifest, naming the dataset repo commit.

    Returns:
        The sentence the push's error ends with.
    """
    record = manifest.dataset["dataset_repo"]
    return (
        f"The dataset repo {record['repo_id']} got commit {record['revision']} on main before the env commit failed; its "
        f"{LEROBOT_DATASET_TAG} tag (what LeRobotDataset({record['repo_id']!r}) opens) still names the dataset the env repo "
        f"publishes. Push again to finish: the dataset is not committed a second time."
    )


def tag_dataset_repo(manifest: Manifest, *, token: str | None) -> None:
    """Put the content tag (unless an earlier commit holds it) and LeRobot's ``v3.0`` on the dataset repo commit the
    manifest names (``dataset.dataset_repo``).

    Args:
        manifest: the env's manifest, naming the dataset repo commit.
        token: the Hub token.
    """
    record = manifest.dataset["dataset_repo"]
    repo_id, sha, kind = record["repo_id"], record["revision"], hub_io.DATASET_REPO_TYPE
    name = content_tag(manifest.content_digest)
    message = f"hub-envs content {manifest.content_digest}"
    if hub_io.tag_target(repo_id, name, token=token, repo_type=kind) in (None, sha):
        hub_io.tag(repo_id, sha, name, message=message, token=token, repo_type=kind)
    hub_io.move_tag(repo_id, sha, LEROBOT_DATASET_TAG, message=message, token=token, repo_type=kind)
