"""The ``env_meta`` a dataset push_env wrote records (robomimic's): the env repo, the digest of its code, its entry
points and config, enough to rebuild exactly the env the data came from."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hub_envs.dataset.reader import read_hub_envs_meta, read_info
from hub_envs.errors import ReproductionError


def read_env_meta(dataset_root: str | Path) -> dict[str, Any]:
    """The dataset's ``env_meta``, checked to name an env repo and a code digest.

    Args:
        dataset_root: a LeRobot dataset folder.

    Returns:
        ``env_meta`` from ``meta/hub_envs.json`` (``meta/info.json``'s ``hub_envs.env_meta`` in older datasets).

    Raises:
        DatasetError: ``meta/info.json`` cannot be read.
        ReproductionError: the dataset was not written by push_env (no ``env_meta``).
    """
    meta = read_hub_envs_meta(dataset_root, read_info(dataset_root)).get("env_meta")  # info.json checked, as LeRobot reads it
    if not isinstance(meta, dict) or not meta.get("env_repo_id") or not meta.get("code_digest"):
        raise ReproductionError(
            f"{dataset_root}/meta has no hub-envs env_meta (env_repo_id, code_digest): the dataset was not "
            f"written by push_env, so which env produced it is unknown. Load the env yourself with load_env."
        )
    return meta
