"""``env_from_dataset``: load exactly the env a dataset came from (robomimic's ``create_env_from_metadata``): the env repo
and the code digest its ``env_meta`` names, the commit found, the code and config checked.

Example:
    >>> from hub_envs import env_from_dataset                                          # doctest: +SKIP
    >>> loaded = env_from_dataset("~/data/pendulum-copy", trust_remote_code=True)      # doctest: +SKIP
    >>> env = loaded.make()                                                            # doctest: +SKIP
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from huggingface_hub import snapshot_download

from hub_envs._text import safe_text
from hub_envs.dataset.env_meta import read_env_meta
from hub_envs.dataset.reader import dataset_fingerprint
from hub_envs.envcode.envconfig import config_differences, encode_config
from hub_envs.errors import EnvRepoNotFoundError, HubEnvsError, ManifestError, ReproductionError
from hub_envs.loading.dataset_files import ensure_dataset_files
from hub_envs.loading.load import load_env
from hub_envs.repo import hub_io
from hub_envs.repo.format import DATASET_DIR, MANIFEST_FILE, Manifest, code_digest, is_commit_sha
from hub_envs.repo.refs import parse_repo_ref

__all__ = ["env_from_dataset", "locate_dataset"]


def _env_repo_id(value: Any, dataset_root: Path) -> str:
    """The env repo a dataset names: data, so it must be a Hub repo id and nothing else.

    A path-shaped value (``./payload``, ``/abs``, ``~/x``) would make load_env import a local folder,
    which needs no consent: a dataset could run code of its choosing. Only ``user/name`` passes.
    """
    try:
        repo_id, revision = parse_repo_ref(value if isinstance(value, str) else "")
    except HubEnvsError:
        repo_id, revision = "", None
    if not repo_id or revision is not None:
        raise ReproductionError(
            f"{dataset_root}: its env_meta names the env repo {safe_text(repr(value))}, which is not a Hub repo id "
            f"('user/name'). A dataset can only name an env on the Hub; load a local env folder yourself with load_env."
        )
    return repo_id


def locate_dataset(
    path_or_repo_id: str | Path, *, revision: str | None = None, token: str | None = None
) -> tuple[Path, tuple[str, str] | None]:
    """The local folder of a dataset, fetched when it names a repo.

    Args:
        path_or_repo_id: a dataset folder (standalone, or ``<env snapshot>/dataset``), an env repo folder, an env repo id
            (its bundled dataset, data files fetched and checked against its manifest) or a dataset repo id.
        revision: the revision of a repo id (overrides ``@rev``).
        token: the Hub token.

    Returns:
        ``(dataset folder, (env repo id, sha) or None)``: the second when the folder is the bundled dataset of an env
        snapshot.

    Raises:
        ReproductionError: the folder is no LeRobot dataset, or the env repo has no dataset.
        IntegrityError: a data file differs from the env's manifest.
    """
    path = Path(str(path_or_repo_id)).expanduser()
    if path.is_dir():
        path = path.absolute()
        if (path / MANIFEST_FILE).is_file() and (path / DATASET_DIR / "meta" / "info.json").is_file():
            path = path / DATASET_DIR
        if not (path / "meta" / "info.json").is_file():
            raise ReproductionError(
                f"{path} is neither a LeRobot dataset folder (meta/info.json) nor an env repo with a dataset/."
            )
        origin = (
            hub_io.snapshot_origin(path.parent) if path.name == DATASET_DIR and (path.parent / MANIFEST_FILE).is_file() else None
        )
        return path, origin
    repo_id, at_rev = parse_repo_ref(str(path_or_repo_id))
    revision = revision or at_rev
    # an env repo (model type) bundles its dataset; otherwise look for a dataset repo of that name
    try:
        with hub_io.translate_hub_errors(repo_id, revision):
            is_env_repo = hub_io.api(token).file_exists(repo_id, MANIFEST_FILE, revision=revision, repo_type=hub_io.REPO_TYPE)
    except EnvRepoNotFoundError:
        is_env_repo = False
    if is_env_repo:
        snap = hub_io.resolve_snapshot(repo_id, revision, token=token, lazy=True)
        if snap.from_cache and not (snap.path / DATASET_DIR / "meta" / "info.json").is_file():
            # only part of that commit is cached (e.g. its manifest, read while searching history)
            snap = hub_io.resolve_snapshot(repo_id, snap.sha, token=token, force_download=True, lazy=True)
        if not (snap.path / DATASET_DIR / "meta" / "info.json").is_file():
            raise ReproductionError(f"{repo_id}@{snap.sha} has no dataset/. Re-publish it with push_env.")
        # the data files too (load_env leaves them out), each checked against the commit's manifest
        manifest = Manifest.read(snap.path, where=f"{repo_id}@{snap.sha}: hub_env.json")
        ensure_dataset_files(repo_id, snap.sha, snap.path, manifest, token=token)
        return snap.path / DATASET_DIR, (repo_id, snap.sha)

    with hub_io.translate_hub_errors(repo_id, revision):
        local = snapshot_download(repo_id, repo_type="dataset", revision=revision, token=token)
    return Path(local), None


def _find_commit(env_repo_id: str, digest: str, dataset_root: Path, token: str | None) -> str:
    """The newest commit of ``env_repo_id`` whose code has the code digest ``digest`` (the exact dataset preferred)."""
    client = hub_io.api(token)
    with hub_io.translate_hub_errors(env_repo_id, None):
        commits = client.list_repo_commits(env_repo_id, repo_type=hub_io.REPO_TYPE)
    fingerprint = None
    first_match = None
    for commit in commits:
        try:
            text = hub_io.read_remote_text(env_repo_id, MANIFEST_FILE, revision=commit.commit_id, token=token)
            manifest = Manifest.from_json(text) if text is not None else None
        except ManifestError:
            manifest = None
        if manifest is None or code_digest(manifest.files) != digest:
            continue
        if first_match is None:
            first_match = commit.commit_id
        if fingerprint is None:
            fingerprint = dataset_fingerprint(dataset_root)
        if manifest.dataset.get("fingerprint") == fingerprint:
            return commit.commit_id
    if first_match is None:
        raise ReproductionError(
            f"No commit of {env_repo_id} holds the code that recorded {dataset_root} (code digest {digest[:16]}…): "
            f"its history was rewritten or the code was never published there. If you know the commit, pass "
            f"env_revision='<sha>'."
        )
    return first_match


def env_from_dataset(
    path_or_repo_id: str | Path,
    *,
    revision: str | None = None,
    env_revision: str | None = None,
    trust_remote_code: bool = False,
    check: bool = True,
    fingerprint: str = "error",
    token: str | None = None,
):
    """Load the env that recorded a dataset, at the commit whose code recorded it.

    Args:
        path_or_repo_id: a dataset folder (standalone, or ``<env snapshot>/dataset``), an env repo
            folder, an env repo id (its bundled dataset) or a dataset repo id; ``@rev`` allowed.
        revision: the revision of ``path_or_repo_id`` when it is a repo id.
        env_revision: the env repo commit to use, skipping the search (it is still verified).
        trust_remote_code: as for :func:`hub_envs.load_env`.
        check: as for :func:`hub_envs.load_env`.
        fingerprint: as for :func:`hub_envs.load_env`.
        token: as for :func:`hub_envs.load_env`.

    Returns:
        A :class:`hub_envs.loading.loaded.LoadedEnv`; ``loaded.make()`` builds the env with the recorded kwargs.

    Raises:
        ReproductionError: the dataset names no env, no commit has its code, or the code or config
            of the commit found differs from what the dataset recorded.
    """
    root, origin = locate_dataset(path_or_repo_id, revision=revision, token=token)
    meta = read_env_meta(root)
    env_repo = _env_repo_id(meta["env_repo_id"], root)
    digest = str(meta["code_digest"])
    if env_revision is not None:
        sha = env_revision
    elif origin is not None and origin[0] == env_repo:
        sha = origin[1]
    elif is_commit_sha(meta.get("env_sha")):
        sha = meta["env_sha"]
    else:
        sha = _find_commit(env_repo, digest, root, token)
    loaded = load_env(f"{env_repo}@{sha}", trust_remote_code=trust_remote_code, check=check, fingerprint=fingerprint, token=token)  # type: ignore[arg-type]
    try:
        actual = code_digest(loaded.manifest.files)
        if actual != digest:
            raise ReproductionError(
                f"{env_repo}@{loaded.revision} is not the code that recorded {root}: its code digest is {actual[:16]}…, "
                f"the dataset's env_meta names {digest[:16]}…. Pass env_revision= the commit that recorded the data, or "
                f"omit it to search the history."
            )
        recorded = meta.get("config")
        if isinstance(recorded, dict):
            diffs = config_differences(recorded, encode_config(loaded.config))
            if diffs:
                raise ReproductionError(
                    f"{env_repo}@{loaded.revision}: the dataset was recorded with other config values:\n  "
                    + "\n  ".join(diffs)
                    + "\nThe env cannot be rebuilt exactly from this commit."
                )
    except HubEnvsError:
        loaded.unregister()
        raise
    return loaded
