"""LeRobot EnvHub entry point, written by hub-envs' push_env. Do not edit: it is regenerated.

    from lerobot.envs.factory import make_env
    envs = make_env("{repo_id}@<sha>", n_envs=2, trust_remote_code=True)

LeRobot downloads this file alone. It finds the repo id and commit it came from in its own cache
path (.../models--user--name/snapshots/<sha>/env.py), fetches the rest of that same commit (the
env's code and assets; not the dataset), checks every file against the manifest's sha256, imports
the env's code as a package unique to repo+sha, and builds vector envs the way LeRobot's own
``make_env`` does (``AutoresetMode.SAME_STEP``, so ``info["final_info"]["is_success"]`` reaches
LeRobot's eval loop, and a ``TimeLimit`` of the config's ``episode_length``). Each env exposes the
config's ``task`` as ``task`` / ``task_description``, which LeRobot's ``add_envs_task`` reads. A benchmark
suite (the manifest's ``tasks``) comes back as ``{name: {task id: VectorEnv}}``, one per task (each with its
language instruction as ``task_description``), so ``lerobot-eval`` reports every task and the suite.
Needs only huggingface_hub and gymnasium (both come with lerobot); hub-envs is not required.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import json
import os
import re
import sys
from pathlib import Path

import gymnasium as gym

# Not Path.resolve(): in a huggingface_hub cache the snapshot's files are symlinks into blobs/.
_HERE = Path(os.path.abspath(__file__)).parent
_MANIFEST = "hub_env.json"
_ROOT_PACKAGE = "hub_envs_code"
#: What making an env does not need: fetched only by load_env / open_dataset.
_NOT_NEEDED = ("dataset/", "media/", "README.md")


def _snapshot_origin(folder: Path):
    """(repo_id, sha, cache_dir) when this file sits in a huggingface_hub cache snapshot, else None."""
    sha, snapshots, repo_dir = folder.name, folder.parent, folder.parent.parent
    if snapshots.name != "snapshots" or not re.fullmatch(r"[0-9a-f]{40}", sha):
        return None
    kind, _, name = repo_dir.name.partition("--")
    if kind != "models" or not name:
        return None
    return name.replace("--", "/"), sha, repo_dir.parent


def _safe(text: str) -> str:
    """Repo-controlled text made safe to print: control and bidi characters as escapes."""
    return ascii(str(text))[1:-1]


def _is_bytecode(path: str) -> bool:
    return path.endswith((".pyc", ".pyo")) or "__pycache__" in path.split("/")


def _needed(files: dict) -> dict:
    """The files making an env needs: all but the dataset, the media and the card (as hub_envs.code_copy)."""
    return {p: h for p, h in files.items() if p not in _NOT_NEEDED and not p.startswith(_NOT_NEEDED[:2])}


def _complete(folder: Path) -> bool:
    manifest = folder / _MANIFEST
    if not manifest.is_file():
        return False
    files = json.loads(manifest.read_text(encoding="utf-8")).get("files", {})
    return all((folder / p).is_file() for p in _needed(files))


def _ensure_snapshot() -> dict:
    if not _complete(_HERE):
        origin = _snapshot_origin(_HERE)
        if origin is None:
            raise FileNotFoundError(f"{_HERE} holds only env.py and is not a Hub cache snapshot; download the whole repo.")
        from huggingface_hub import snapshot_download

        try:  # hub-envs, where installed, checks every answer of the endpoint before the client writes anything
            import hub_envs.hub_io  # noqa: F401
        except ImportError:
            pass
        repo_id, sha, cache_dir = origin
        # the same commit into the same cache folder; HF_ENDPOINT / HF_TOKEN apply as usual
        snapshot_download(repo_id, revision=sha, cache_dir=cache_dir,
                          ignore_patterns=[p + "*" if p.endswith("/") else p for p in _NOT_NEEDED]
                          + ["*.pyc", "*.pyo", "*.so", "*.pyd", "__pycache__/*", "*/__pycache__/*"])
    manifest = json.loads((_HERE / _MANIFEST).read_text(encoding="utf-8"))
    compiled = sorted(p for p in manifest.get("files", {}) if _is_bytecode(p))
    if compiled:  # Python would run these instead of the sources anyone reads
        raise RuntimeError(f"{_HERE}: {_MANIFEST} lists compiled bytecode ({', '.join(_safe(p) for p in compiled)}); an env repo "
                           f"holds .py sources only, so this one is not imported. Ask the repo's author to re-publish it with push_env.")
    bad = []
    for rel, expected in sorted(_needed(manifest.get("files", {})).items()):
        digest = hashlib.sha256((_HERE / rel).read_bytes()).hexdigest()
        if digest != expected:
            bad.append(rel)
    listed = set(manifest.get("files", {}))
    for dirpath, _, names in os.walk(_HERE):  # code Python could run instead of the verified sources
        for name in names:
            rel = Path(dirpath, name).relative_to(_HERE).as_posix()
            if name.endswith((".py", ".pyc", ".pyo", ".so", ".pyd")) and rel not in listed:
                bad.append(f"{rel} (unlisted)")
    if bad:
        served = [b for b in bad if _as_served(_HERE / b)]
        if served:  # byte for byte what the Hub serves: the publication itself disagrees with its manifest
            advice = (f"{', '.join(_safe(b) for b in served)} are exactly what the Hub serves for this commit, so the "
                      f"published files disagree with their own manifest and downloading again will not help: ask the "
                      f"repo's author to re-publish it with push_env.")
        else:
            advice = "Delete this snapshot from the cache and download it again, or ask the repo's author."
        raise RuntimeError(f"{_HERE}: {', '.join(_safe(b) for b in bad)} differ from the sha256 in {_MANIFEST} or are code it "
                           f"does not list; not importing. {advice}")
    return manifest


def _as_served(path: Path) -> bool:
    """Whether a cached file is byte for byte what the Hub served: huggingface_hub names a blob by the ETag it
    checked, the git blob sha1 of a regular file or the sha256 of an LFS one."""
    try:
        blob = os.path.basename(os.readlink(path))
        data = path.read_bytes()
    except OSError:
        return False
    git_sha1 = hashlib.sha1(b"blob %d\0" % len(data) + data).hexdigest()
    return blob in (git_sha1, hashlib.sha256(data).hexdigest())


def _source_only(folder: Path) -> None:
    """Import the snapshot's modules from their verified .py sources only: no bytecode cache, no .so.

    Every folder gets a source-only finder: ``folder`` now, and each package folder below it (hidden
    ones, ``dataset/`` and ``media/`` included) when the import system first finds it, before anything
    is imported from it, so Python's default finders (which honour ``__pycache__``) never search one.
    """
    import importlib.machinery

    class _SourceLoader(importlib.machinery.SourceFileLoader):
        def get_code(self, fullname):  # from the source alone: never read or write a __pycache__ entry
            path = self.get_filename(fullname)
            return self.source_to_code(self.get_data(path), path)

        def set_data(self, *args, **kwargs):
            pass

    class _SourceOnlyFinder(importlib.machinery.FileFinder):
        def __init__(self, path):
            super().__init__(path, (_SourceLoader, [".py"]))

        def find_spec(self, fullname, target=None):
            spec = super().find_spec(fullname, target)
            if spec is not None and spec.submodule_search_locations:
                for d in list(spec.submodule_search_locations):
                    if not isinstance(sys.path_importer_cache.get(str(d)), _SourceOnlyFinder):
                        sys.path_importer_cache[str(d)] = _SourceOnlyFinder(str(d))
            return spec

    sys.path_importer_cache[str(folder)] = _SourceOnlyFinder(str(folder))


def _module_key(*parts: str) -> str:
    """The package name hub-envs' load_env uses for the same repo+sha (so both share one import)."""
    key = re.sub(r"\W", "_", "__".join(parts))
    return key if not key[0].isdigit() else f"_{key}"


def _import_package(manifest: dict) -> str:
    origin = _snapshot_origin(_HERE)
    key = _module_key(origin[0], origin[1]) if origin else _module_key(manifest["name"], manifest["content_digest"][:12])
    name = f"{_ROOT_PACKAGE}.{key}"
    if _ROOT_PACKAGE not in sys.modules:
        root = importlib.util.module_from_spec(importlib.util.spec_from_loader(_ROOT_PACKAGE, loader=None, is_package=True))
        root.__path__ = []
        sys.modules[_ROOT_PACKAGE] = root
    if name not in sys.modules:
        folder = _code_copy(manifest, origin) if origin else _HERE
        _source_only(folder)
        pkg = importlib.util.module_from_spec(importlib.util.spec_from_loader(name, loader=None, is_package=True))
        pkg.__path__ = [str(folder)]
        sys.modules[name] = pkg
    return name


def _code_copy(manifest: dict, origin) -> Path:
    """Real files, not the cache's symlinks into blobs/, so ``Path(__file__).resolve().parent`` is the code's folder
    (the folder hub-envs' load_env imports from too: $HUB_ENVS_HOME/code/<models--user--name>/<sha>)."""
    import shutil
    import uuid

    repo_id, sha = origin[0], origin[1]
    home = os.environ.get("HUB_ENVS_HOME") or os.path.join(os.environ.get("XDG_STATE_HOME") or "~/.local/state", "hub-envs")
    root = Path(home).expanduser() / "code" / ("models--" + repo_id.replace("/", "--"))
    target = root / sha
    wanted = _needed(manifest.get("files", {}))

    def matches(folder: Path) -> bool:
        present = {q.relative_to(folder).as_posix() for q in folder.rglob("*") if q.is_file() or q.is_symlink()}
        return present == set(wanted) and all(
            not (folder / rel).is_symlink() and hashlib.sha256((folder / rel).read_bytes()).hexdigest() == digest
            for rel, digest in wanted.items()
        )

    if target.is_dir() and matches(target):
        return target
    root.mkdir(parents=True, exist_ok=True)
    tmp = root / f".{sha}.partial-{uuid.uuid4().hex[:12]}"
    try:
        for rel, digest in sorted(wanted.items()):
            data = (_HERE / rel).read_bytes()
            if hashlib.sha256(data).hexdigest() != digest:
                raise RuntimeError(f"{_HERE}: {_safe(rel)} changed since it was checked; load it again.")
            (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
            (tmp / rel).write_bytes(data)
        if target.exists():
            shutil.rmtree(target, ignore_errors=True)
        try:
            os.rename(tmp, target)
        except OSError:
            if not matches(target):
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return target


def _resolve(package: str, entry_point: str):
    module, _, attr = entry_point.partition(":")
    obj = importlib.import_module(f"{package}.{module}")
    for part in attr.split("."):
        obj = getattr(obj, part)
    return obj


def _preflight(manifest: dict) -> None:
    """Before any of the env's code is imported: every requirement it declares is installed, at a version it
    accepts; otherwise an ImportError naming them and the pip line (not a bare ModuleNotFoundError from deep
    inside the env's code)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        from packaging.requirements import InvalidRequirement, Requirement
    except ImportError:  # pragma: no cover - packaging comes with huggingface_hub
        return
    problems, lines = [], []
    for text in manifest.get("requirements", []):
        try:
            req = Requirement(text)
        except InvalidRequirement:
            problems.append(f"{_safe(text)} (not a valid requirement)")
            continue
        if req.marker is not None and not req.marker.evaluate():
            continue
        try:
            have = version(req.name)
        except PackageNotFoundError:
            problems.append(f"{_safe(text)} (not installed)")
            lines.append(_safe(text))
            continue
        if req.specifier and not req.specifier.contains(have, prereleases=True):
            problems.append(f"{_safe(text)} ({_safe(req.name)} {_safe(have)} is installed)")
            lines.append(_safe(text))
    if problems:
        origin = _snapshot_origin(_HERE)
        repo = f"{origin[0]}@{origin[1]}" if origin else str(_HERE)
        pip = "pip install " + " ".join(f"'{line}'" for line in lines) if lines else "fix the repo's requirements"
        raise ImportError(f"{repo} needs {', '.join(problems)}. Install them: {pip}")


def load_classes():
    """(env class, config class) of this repo."""
    manifest = _ensure_snapshot()
    _preflight(manifest)
    package = _import_package(manifest)
    return _resolve(package, manifest["env_entry_point"]), _resolve(package, manifest["config_entry_point"])


class IntegerActions(gym.ActionWrapper):
    """A policy's float actions in LeRobot's layout (a Discrete's as shape (1,)) as the integers the env expects
    (the same conversion as hub_envs.harness.actions.IntegerActions)."""

    def action(self, action):
        import numpy as np

        arr = np.asarray(action)
        if isinstance(self.env.action_space, gym.spaces.Discrete):
            return np.int64(np.rint(arr.reshape(-1)[0])) if arr.size == 1 else action
        if arr.dtype.kind == "f":
            return np.rint(arr).astype(self.env.action_space.dtype).reshape(self.env.action_space.shape)
        return action


class TaskDescription(gym.Wrapper):
    """Exposes the config's ``task`` string (and a suite task's instruction) to LeRobot's eval loop (``add_envs_task``)."""

    def __init__(self, env: gym.Env, task: str, description: str | None = None):
        super().__init__(env)
        self.task = task
        self.task_description = description or task


#: repo@sha (and config) whose declared features matched a live env in this process
_FEATURES_CHECKED: set = set()


def _check_features_once(cfg, make_one) -> None:
    """The declared-vs-live half of hub-envs' three-way feature check, once per repo@sha and config in a process:
    every feature the config declares has that shape in a live observation (images: HWC or CHW), and the action
    space the declared action shape. A disagreement is refused with the whole table, as load_env refuses it."""
    origin = _snapshot_origin(_HERE)
    key = (origin[:2] if origin else str(_HERE), json.dumps(getattr(cfg, "gym_kwargs", {}), sort_keys=True, default=str))
    if key in _FEATURES_CHECKED:
        return
    env = make_one()
    try:
        obs, _ = env.reset(seed=0)
        rows = []
        for name, feature in cfg.features.items():
            declared = tuple(int(d) for d in feature.shape)
            kind = str(getattr(feature.type, "value", feature.type)).upper()
            if kind.endswith("ACTION"):
                live, what = tuple(env.action_space.shape or ()), "action_space shape"
            else:
                node = obs
                for part in name.split("/"):
                    node = node.get(part) if isinstance(node, dict) else None
                if node is None:
                    rows.append(f"  {_safe(name)}: declared {declared}, not in the live observation")
                    continue
                live, what = tuple(getattr(node, "shape", ())), "live shape"
            channel_first = kind.endswith("VISUAL") and len(declared) == 3 and live in (
                (declared[2], declared[0], declared[1]), (declared[1], declared[2], declared[0]))
            scalar = kind.endswith("ACTION") and live == () and declared == (1,)  # a Discrete, as LeRobot stores it
            if live != declared and not channel_first and not scalar:
                rows.append(f"  {_safe(name)}: {what} {live} != declared {declared}")
    finally:
        env.close()
    if rows:
        repo = f"{origin[0]}@{origin[1]}" if origin else str(_HERE)
        raise ValueError(f"{repo}: the env's declared features disagree with what it produces:\n" + "\n".join(rows)
                         + "\nNot building it. Ask the repo's author to fix the config's features and re-publish with push_env.")
    _FEATURES_CHECKED.add(key)


def _published_config(config_class, manifest: dict, **fields):
    """The published config: the code's defaults with the fields the publisher set (``config_overrides``), and ``fields``."""
    overrides = manifest.get("config_overrides") or {}
    if overrides:
        import typing

        import draccus  # LeRobot's config library, present wherever LeRobot runs this file

        hints = typing.get_type_hints(config_class)  # field by field: EnvConfig is a draccus choice registry
        return config_class(**{**{name: draccus.decode(hints[name], value) for name, value in overrides.items()}, **fields})
    return config_class(**fields)


def _vector_env(env_class, cfg, n_envs: int, use_async_envs: bool, description: str | None = None):
    """``n_envs`` copies of the env ``cfg`` describes, as LeRobot's eval loop expects them."""
    task = cfg.task if isinstance(cfg.task, str) else None

    def _one():
        env = gym.wrappers.TimeLimit(env_class(**cfg.gym_kwargs), max_episode_steps=int(cfg.episode_length))
        if isinstance(env.action_space, (gym.spaces.Discrete, gym.spaces.MultiDiscrete)):
            env = IntegerActions(env)
        return TaskDescription(env, task, description) if task is not None else env

    _check_features_once(cfg, _one)
    fns = [_one for _ in range(n_envs)]
    mode = gym.vector.AutoresetMode.SAME_STEP
    if use_async_envs:
        return gym.vector.AsyncVectorEnv(fns, context="fork", autoreset_mode=mode)
    return gym.vector.SyncVectorEnv(fns, autoreset_mode=mode)


def _suite_tasks(manifest: dict, cfg, strict: bool) -> list:
    """The suite tasks to make: the one a config of this repo names, those LeRobot's config names in its ``task``
    (``a,b``, as LeRobot's own multi-task configs list them), else all. ``strict``: a config of this repo, whose task
    must be one of the suite's (LeRobot's own config may hold a task of its own, which means all)."""
    tasks = manifest.get("tasks") or []
    names = [t["task"] for t in tasks]
    wanted = getattr(cfg, "task", None)
    if isinstance(wanted, str) and wanted:
        chosen = [w.strip() for w in wanted.split(",")]
        unknown = [w for w in chosen if w not in names]
        if not unknown:
            return [tasks[names.index(w)] for w in chosen]
        if strict or any(w in names for w in chosen):
            raise ValueError(f"{_safe(', '.join(unknown))}: not tasks of this suite; its tasks are "
                             f"{', '.join(_safe(n) for n in names)}.")
    return tasks


def make_env(n_envs: int = 1, use_async_envs: bool = False, cfg=None):
    """LeRobot EnvHub's entry point: ``{name: {0: VectorEnv}}`` of ``n_envs`` copies of this env; for a benchmark
    suite, ``{name: {task id: VectorEnv}}`` of its tasks.

    ``cfg``, when it is an instance of this repo's config class, overrides the published config (a suite: the
    task it names); anything else (LeRobot passes its own ``HubEnvConfig``) means the published one: the code's
    defaults with the fields the publisher set (``config_overrides``: a variant published with ``--config.*``),
    and for a suite every task (or those its ``task`` names, comma-separated).
    """
    env_class, config_class = load_classes()
    manifest = json.loads((_HERE / _MANIFEST).read_text(encoding="utf-8"))
    name = manifest.get("name") or "hub_env"
    if manifest.get("tasks"):
        if isinstance(cfg, config_class):
            records = _suite_tasks(manifest, cfg, strict=True)  # a config of this repo: the task it names
            return {name: {r["task_index"]: _vector_env(env_class, cfg, n_envs, use_async_envs, r["instruction"])
                           for r in records}}
        return {
            name: {
                r["task_index"]: _vector_env(env_class, _published_config(config_class, manifest, task=r["task"]),
                                             n_envs, use_async_envs, r["instruction"])
                for r in _suite_tasks(manifest, cfg, strict=False)
            }
        }
    if not isinstance(cfg, config_class):
        cfg = _published_config(config_class, manifest)
    return {name: {0: _vector_env(env_class, cfg, n_envs, use_async_envs)}}
