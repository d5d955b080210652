"""LeRobot EnvHub entry point, written by hub-envs' push_env. Do not edit: it is regenerated.

    from lerobot.envs.factory import make_env
    envs = make_env("{repo_id}@<sha>", n_envs=2, trust_remote_code=True)

LeRobot downloads this file alone. It finds the repo id and commit it came from in its own cache
path (.../models--user--name/snapshots/<sha>/env.py), fetches the rest of that same snapshot,
imports the env's code as a package unique to repo+sha, and builds vector envs from the config.
Needs only huggingface_hub and gymnasium (both come with lerobot); hub-envs is not required.
"""

from __future__ import annotations

import importlib
import importlib.util
import json
import re
import sys
from pathlib import Path

import gymnasium as gym

_HERE = Path(__file__).resolve().parent
_MANIFEST = "hub_env.json"


def _snapshot_origin(folder: Path):
    """(repo_id, sha, cache_dir) when this file sits in a huggingface_hub cache snapshot, else None."""
    sha, snapshots, repo_dir = folder.name, folder.parent, folder.parent.parent
    if snapshots.name != "snapshots" or not re.fullmatch(r"[0-9a-f]{40}", sha):
        return None
    kind, _, name = repo_dir.name.partition("--")
    if kind != "models" or not name:
        return None
    return name.replace("--", "/"), sha, repo_dir.parent


def _complete(folder: Path) -> bool:
    manifest = folder / _MANIFEST
    if not manifest.is_file():
        return False
    files = json.loads(manifest.read_text(encoding="utf-8")).get("files", {})
    return all((folder / p).is_file() for p in files)


def _ensure_snapshot() -> dict:
    if not _complete(_HERE):
        origin = _snapshot_origin(_HERE)
        if origin is None:
            raise FileNotFoundError(f"{_HERE} holds only env.py and is not a Hub cache snapshot; download the whole repo.")
        from huggingface_hub import snapshot_download

        repo_id, sha, cache_dir = origin
        snapshot_download(repo_id, revision=sha, cache_dir=cache_dir)  # same commit, same cache folder
    return json.loads((_HERE / _MANIFEST).read_text(encoding="utf-8"))


def _import_package(manifest: dict):
    origin = _snapshot_origin(_HERE)
    ident = f"{origin[0]}__{origin[1]}" if origin else f"{manifest['name']}__{manifest['content_digest'][:12]}"
    key = re.sub(r"\W", "_", ident)
    name = f"hub_envs_code.{key}"
    if "hub_envs_code" not in sys.modules:
        root = importlib.util.module_from_spec(importlib.util.spec_from_loader("hub_envs_code", loader=None, is_package=True))
        root.__path__ = []
        sys.modules["hub_envs_code"] = root
    if name not in sys.modules:
        pkg = importlib.util.module_from_spec(importlib.util.spec_from_loader(name, loader=None, is_package=True))
        pkg.__path__ = [str(_HERE)]
        sys.modules[name] = pkg
    return name


def _resolve(package: str, entry_point: str):
    module, _, attr = entry_point.partition(":")
    obj = importlib.import_module(f"{package}.{module}")
    for part in attr.split("."):
        obj = getattr(obj, part)
    return obj


def load_classes():
    """(env class, config class) of this repo."""
    manifest = _ensure_snapshot()
    package = _import_package(manifest)
    return _resolve(package, manifest["env_entry_point"]), _resolve(package, manifest["config_entry_point"])


def make_env(n_envs: int = 1, use_async_envs: bool = False, cfg=None):
    """LeRobot EnvHub's entry point: a gymnasium VectorEnv of ``n_envs`` copies of this env."""
    env_class, config_class = load_classes()
    cfg = cfg if isinstance(cfg, config_class) else config_class()

    def _one():
        return gym.wrappers.TimeLimit(env_class(**cfg.gym_kwargs), max_episode_steps=cfg.episode_length)

    fns = [_one for _ in range(n_envs)]
    return gym.vector.AsyncVectorEnv(fns, context="fork") if use_async_envs else gym.vector.SyncVectorEnv(fns)
