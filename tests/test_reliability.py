"""Reliability: a corpus of bad inputs, each refused with its own error and no side effects.

Every case hands ``load_env`` (or ``push_env``) something broken — a bad repo id or revision, a
malformed or tampered manifest, broken env code or config, an inconsistent dataset, a name that
collides — and asserts that

* the error is exactly the documented class (not a parent, not a raw library exception),
* its message names what is wrong (file, field, repo) and says what to do next,
* gymnasium's registry and draccus' EnvConfig choices are exactly as before (nothing half-registered),
* no ``hub_envs_code.*`` module of the failed load is left in ``sys.modules``,
* the Hugging Face cache is unchanged apart from the case's own downloaded snapshot, with no
  partial downloads, and the trust list is unchanged.

One loopback server for the module; each case publishes its own repo, built from one pushed
tiny env by editing files (and fixing the manifest's hashes when the case is not about integrity).
"""

from __future__ import annotations

import json
import shutil
import sys
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import pytest
from helpers import TINY, copy_env, republish
from huggingface_hub import snapshot_download

from hub_envs import errors, load_env, push_env
from hub_envs.envcode.registration import snapshot_registries
from hub_envs.paths import hub_envs_home
from hub_envs.repo.format import FORMAT_VERSION, MANIFEST_FILE, SINGLE_TASK_FORMAT_VERSION, content_digest, hash_files, list_files
from hub_envs.repo.requirements import installed_version
from hub_envs.testing import hub_environment

NS = "rel"


@dataclass
class Base:
    hub: Any
    sha: str
    snapshot: Path  # the pushed tiny env, outside the HF cache the cases use
    work: Path


@pytest.fixture(scope="module")
def base(hub_module, tmp_path_factory) -> Base:
    result = push_env(TINY, f"{NS}/base", episodes=2, progress=False)
    snap = snapshot_download(f"{NS}/base", revision=result.sha, cache_dir=tmp_path_factory.mktemp("base-cache"))
    return Base(hub=hub_module, sha=result.sha, snapshot=Path(snap), work=tmp_path_factory.mktemp("variants"))


def publish_variant(
    base: Base,
    name: str,
    edit: Callable[[Path], None] | None = None,
    *,
    fix: bool = True,
    manifest: Callable[[dict], None] | None = None,
) -> str:
    """Publish ``rel/<name>``: the base repo with ``edit(folder)`` applied, the manifest's hashes
    recomputed when ``fix``, then ``manifest(dict)`` applied to the manifest. Returns the commit sha."""
    work = base.work / name
    shutil.copytree(base.snapshot, work)  # follows the cache's symlinks
    if edit:
        edit(work)
    if (fix or manifest) and (work / MANIFEST_FILE).is_file():
        data = json.loads((work / MANIFEST_FILE).read_text())
        data.update(repo_id=f"{NS}/{name}", gym_id=f"{NS}/{name}", env_type=f"{NS}/{name}")  # as push_env names them
        if fix:
            data["files"] = hash_files(work, list_files(work, skip=(MANIFEST_FILE,)))
            data["content_digest"] = content_digest(data["files"])
        if manifest:
            manifest(data)
        (work / MANIFEST_FILE).write_text(json.dumps(data, indent=2, sort_keys=True))
    api = base.hub.api
    api.create_repo(f"{NS}/{name}")
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*commit a data file.*")
        return api.upload_folder(repo_id=f"{NS}/{name}", folder_path=str(work), commit_message=name).oid


# --- edits --------------------------------------------------------------------------------------


def replace(rel: str, old: str, new: str, count: int = 1) -> Callable[[Path], None]:
    def edit(folder: Path) -> None:
        path = folder / rel
        text = path.read_text()
        assert text.count(old) >= 1, f"{old!r} not in {rel}"
        path.write_text(text.replace(old, new, count))

    return edit


def prepend(rel: str, code: str) -> Callable[[Path], None]:
    def edit(folder: Path) -> None:
        path = folder / rel
        path.write_text(code + path.read_text())

    return edit


def write(rel: str, text: str) -> Callable[[Path], None]:
    def edit(folder: Path) -> None:
        (folder / rel).parent.mkdir(parents=True, exist_ok=True)
        (folder / rel).write_text(text)

    return edit


def delete(rel: str) -> Callable[[Path], None]:
    return lambda folder: (folder / rel).unlink()


def info_json(fn: Callable[[dict], None]) -> Callable[[Path], None]:
    def edit(folder: Path) -> None:
        path = folder / "dataset/meta/info.json"
        info = json.loads(path.read_text())
        fn(info)
        path.write_text(json.dumps(info, indent=4))

    return edit


def setitem(key: str, value: Any) -> Callable[[dict], None]:
    def edit(d: dict) -> None:
        d[key] = value

    return edit


def delitem(*path: str) -> Callable[[dict], None]:
    def edit(d: dict) -> None:
        for k in path[:-1]:
            d = d[k]
        del d[path[-1]]

    return edit


OBS = "np.array([self.pos[0], self.vel[0]], dtype=np.float32)"
CONFIG_CLASS = "@dataclass\nclass TinyEnvConfig(EnvConfig):\n"
GYM_KWARGS = '        return {"render_mode": "rgb_array"}'
POST_INIT = "    @property\n    def gym_kwargs"


# --- the corpus ---------------------------------------------------------------------------------


@dataclass
class Case:
    id: str
    error: type
    says: tuple[str, ...]  # substrings of the message: what is wrong, and what to do next
    prepare: Callable[[Base], Callable[[], Any]]  # publish/setup; returns the failing call
    cleanup: Callable[[], None] | None = None
    repo: str | None = None  # the case's own repo (its snapshot may land in the cache)
    marks: tuple = field(default_factory=tuple)


def repo_case(
    id: str,
    error: type,
    says: tuple[str, ...],
    edit=None,
    *,
    fix: bool = True,
    manifest=None,
    trust_remote_code: bool = True,
    **kwargs,
) -> Case:
    def prepare(b: Base):
        sha = publish_variant(b, id, edit, fix=fix, manifest=manifest)
        return lambda: load_env(f"{NS}/{id}@{sha}", trust_remote_code=trust_remote_code, **kwargs)

    return Case(id, error, says, prepare, repo=f"{NS}/{id}")


def ref_case(id: str, error: type, says: tuple[str, ...], ref: Any) -> Case:
    return Case(id, error, says, lambda b: lambda: load_env(ref, trust_remote_code=True))


def folder_case(id: str, error: type, says: tuple[str, ...], edit) -> Case:
    def prepare(b: Base):
        folder = copy_env(b.work, name=f"folder-{id}")
        edit(folder)
        return lambda: load_env(str(folder))

    return Case(id, error, says, prepare)


def _offline_case() -> Case:
    def prepare(b: Base):
        def call():
            with hub_environment(b.hub.endpoint, b.hub.hf_home, offline=True):
                load_env(f"{NS}/base@{b.sha}", trust_remote_code=True)

        return call

    return Case(
        "offline-not-cached",
        errors.OfflineNotCachedError,
        (f"{NS}/base@", "not in the local cache", "unset HF_HUB_OFFLINE"),
        prepare,
    )


def _corrupt_trust_list_case() -> Case:
    saved: dict[str, bytes | None] = {}

    def prepare(b: Base):
        sha = publish_variant(b, "trust-list-corrupt")
        path = hub_envs_home() / "trusted.json"
        saved["path"], saved["data"] = path, path.read_bytes() if path.exists() else None
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("{not json")
        return lambda: load_env(f"{NS}/trust-list-corrupt@{sha}")

    def cleanup():
        if saved.get("data") is None:
            saved["path"].unlink(missing_ok=True)
        else:
            saved["path"].write_bytes(saved["data"])

    return Case(
        "trust-list-corrupt",
        errors.ConfigError,
        ("trusted.json", "is not valid JSON", "Fix or delete it"),
        prepare,
        cleanup,
        repo=f"{NS}/trust-list-corrupt",
    )


def _gym_id_taken_case() -> Case:
    taken: list[str] = []

    def prepare(b: Base):
        sha = publish_variant(b, "gym-id-taken")
        gym_id = f"{NS}/gym-id-taken-{sha[:12]}"
        gym.register(gym_id, entry_point="gymnasium.envs.classic_control.cartpole:CartPoleEnv")
        taken.append(gym_id)
        return lambda: load_env(f"{NS}/gym-id-taken@{sha}", trust_remote_code=True)

    def cleanup():
        for gym_id in taken:
            gym.registry.pop(gym_id, None)

    return Case(
        "gym-id-taken",
        errors.RegistrationConflictError,
        ("gym id 'rel/gym-id-taken-", "already registered", "fresh process"),
        prepare,
        cleanup,
        repo=f"{NS}/gym-id-taken",
    )


def _push_case(
    id: str, error: type, says: tuple[str, ...], edits: dict | None = None, repo_id: str | None = None, **kwargs
) -> Case:
    def prepare(b: Base):
        folder = copy_env(b.work, name=f"push-{id}", edits=edits)
        return lambda: push_env(folder, repo_id or f"{NS}/{id}", progress=False, **{"episodes": 2, **kwargs})

    return Case(id, error, says, prepare)


E = errors
CASES: list[Case] = [
    # -- repo ids and revisions --
    ref_case("id-empty", E.ConfigError, ("''", "user/name"), ""),
    ref_case("id-none", E.ConfigError, ("None", "user/name"), None),
    ref_case("id-no-namespace", E.ConfigError, ("'tiny'", "needs a namespace", "user/tiny"), "tiny"),
    ref_case("id-space", E.ConfigError, ("'rel/ti ny'", "is not valid", "user/name"), "rel/ti ny"),
    ref_case("id-three-parts", E.ConfigError, ("'rel/a/b'", "is not valid"), "rel/a/b"),
    ref_case("id-dots", E.ConfigError, ("'rel/..base'", "is not valid"), "rel/..base"),
    ref_case("id-trailing-at", E.ConfigError, ("'rel/base@'", "names no revision", "user/name@<sha"), "rel/base@"),
    ref_case("folder-missing", E.EnvFolderError, ("./no/such/env-folder", "does not exist"), "./no/such/env-folder"),
    ref_case("repo-missing", E.EnvRepoNotFoundError, ("'rel/does-not-exist'", "not found", "Check the id"), "rel/does-not-exist"),
    ref_case("revision-missing", E.RevisionNotFoundError, ("rel/base", "no revision 'v9'", "list_repo_refs"), "rel/base@v9"),
    ref_case("sha-missing", E.RevisionNotFoundError, ("rel/base", "0" * 40, "list_repo_refs"), "rel/base@" + "0" * 40),
    ref_case("revision-traversal", E.RevisionNotFoundError, ("rel/base", "'../../etc'", "list_repo_refs"), "rel/base@../../etc"),
    _offline_case(),
    # -- the manifest --
    repo_case("manifest-missing", E.ManifestError, ("hub_env.json is missing", "push_env"), delete(MANIFEST_FILE)),
    repo_case(
        "manifest-not-json",
        E.ManifestError,
        ("hub_env.json", "not valid JSON", "Re-publish"),
        write(MANIFEST_FILE, "{oops"),
        fix=False,
    ),
    repo_case(
        "manifest-not-object",
        E.ManifestError,
        ("hub_env.json", "must be a JSON object", "Re-publish"),
        write(MANIFEST_FILE, "[1, 2]"),
        fix=False,
    ),
    repo_case(
        "manifest-future-version",
        E.ManifestError,
        ("hub_env.json", f"format_version {FORMAT_VERSION + 1}", "upgrade hub-envs"),
        manifest=setitem("format_version", FORMAT_VERSION + 1),
    ),
    repo_case(
        "manifest-newer-writer",
        E.ManifestError,
        (
            "hub_env.json",
            f"format_version {FORMAT_VERSION + 1} was written by hub-envs 9.1.0",
            "pip install -U 'hub-envs>=9.1.0'",
        ),
        manifest=lambda m: (m.__setitem__("format_version", FORMAT_VERSION + 1), m["versions"].__setitem__("hub-envs", "9.1.0")),
    ),
    repo_case(
        "manifest-no-version",
        E.ManifestError,
        ("hub_env.json", "format_version None", "re-publish"),
        manifest=delitem("format_version"),
    ),
    repo_case(
        "manifest-bool-version",
        E.ManifestError,
        ("hub_env.json", "format_version True", "re-publish"),
        manifest=setitem("format_version", True),
    ),
    repo_case(
        "manifest-field-from-a-later-format",
        E.ManifestError,
        ("hub_env.json", "unknown field(s) ['config_overrides', 'resolved'] for format_version 1", "push_env"),
        manifest=setitem("format_version", 1),  # config_overrides came with format 2, resolved with 3
    ),
    repo_case(
        "manifest-unknown-field",
        E.ManifestError,
        (
            "hub_env.json",
            f"unknown field(s) ['surprise'] for format_version {SINGLE_TASK_FORMAT_VERSION}",
            "edited by hand",
            "push_env",
        ),
        manifest=setitem("surprise", 1),
    ),
    repo_case(
        "manifest-bad-benchmark",
        E.ManifestError,
        ("hub_env.json", "benchmarks[0]: 'metrics' must map metric names to numbers", "push_env"),
        manifest=lambda m: m["benchmarks"][0]["metrics"].__setitem__("mean_return", "high"),
    ),
    repo_case(
        "manifest-benchmark-seeds",
        E.ManifestError,
        ("hub_env.json", "benchmarks[0]: 'seeds' must list one non-negative int per episode", "push_env"),
        manifest=lambda m: m["benchmarks"][0].__setitem__("seeds", [0]),
    ),
    repo_case(
        "manifest-missing-field",
        E.ManifestError,
        ("hub_env.json", "missing field(s) ['gym_id']", "Re-publish"),
        manifest=delitem("gym_id"),
    ),
    repo_case(
        "manifest-wrong-type",
        E.ManifestError,
        ("hub_env.json", "'gym_id' must be a string", "push_env"),
        manifest=setitem("gym_id", 5),
    ),
    repo_case(
        "manifest-bad-gym-id",
        E.ManifestError,
        ("hub_env.json", "gym_id 'bad id!'", "Re-publish"),
        manifest=setitem("gym_id", "bad id!"),
    ),
    repo_case(
        "manifest-nan",
        E.ManifestError,
        ("hub_env.json", "NaN", "Re-publish"),
        manifest=lambda m: m["config"].__setitem__("fps", float("nan")),
    ),
    repo_case(
        "manifest-path-traversal",
        E.ManifestError,
        ("hub_env.json", "'../evil.py'", "escapes the repo", "plain relative paths"),
        manifest=lambda m: m["files"].__setitem__("../evil.py", "0" * 64),
    ),
    repo_case(
        "manifest-absolute-path",
        E.ManifestError,
        ("hub_env.json", "'/etc/passwd'", "escapes the repo"),
        manifest=lambda m: m["files"].__setitem__("/etc/passwd", "0" * 64),
    ),
    repo_case(
        "manifest-bad-digest",
        E.ManifestError,
        ("hub_env.json", "files['tiny.py']", "not a sha256"),
        manifest=lambda m: m["files"].__setitem__("tiny.py", "abc"),
    ),
    repo_case(
        "manifest-requirements-not-list",
        E.ManifestError,
        ("hub_env.json", "'requirements'", "pybullet>=3.2"),
        manifest=setitem("requirements", "numpy"),
    ),
    repo_case(
        "manifest-invalid-requirement",
        E.ManifestError,
        ("'numpy>>1'", "is not valid", "dependencies"),
        manifest=setitem("requirements", ["numpy>>1"]),
    ),
    repo_case(
        "entry-point-syntax",
        E.ManifestError,
        ("hub_env.json", "env_entry_point 'tiny.TinyEnv'", "module:Attribute"),
        manifest=setitem("env_entry_point", "tiny.TinyEnv"),
    ),
    repo_case(
        "entry-point-no-module",
        E.InvalidRepoFormatError,
        ("'nomodule:TinyEnv'", "no module nomodule.py", "Fix the entry point"),
        manifest=setitem("env_entry_point", "nomodule:TinyEnv"),
    ),
    repo_case(
        "entry-point-no-attr",
        E.InvalidRepoFormatError,
        ("'tiny:NoSuchEnv'", "has no attribute", "Fix the entry point"),
        manifest=setitem("env_entry_point", "tiny:NoSuchEnv"),
    ),
    repo_case(
        "config-entry-not-envconfig",
        E.InvalidRepoFormatError,
        ("config entry point", "not a subclass", "EnvConfig"),
        manifest=setitem("config_entry_point", "tiny:TinyEnv"),
    ),
    repo_case(
        "manifest-config-differs",
        E.InvalidRepoFormatError,
        ("fps: manifest 99 vs code 20", "Re-publish"),
        manifest=lambda m: m["config"].__setitem__("fps", 99),
    ),
    # -- integrity --
    repo_case(
        "file-tampered",
        E.IntegrityError,
        ("tampered  dynamics.py", "Do not run this code"),
        replace("dynamics.py", "GAIN = 1.0", "GAIN = 9.0"),
        fix=False,
    ),
    repo_case("file-missing", E.IntegrityError, ("missing   dynamics.py", "re-publish"), delete("dynamics.py"), fix=False),
    repo_case(
        "code-unlisted",
        E.IntegrityError,
        ("unlisted  extra.py", "Do not run this code"),
        write("extra.py", "print('hi')\n"),
        fix=False,
    ),
    repo_case(
        "code-unlisted-deep",
        E.IntegrityError,
        ("unlisted  sub/evil.py", "Do not run this code"),
        write("sub/evil.py", "x = 1\n"),
        fix=False,
    ),
    repo_case(
        "extension-unlisted",
        E.IntegrityError,
        ("unlisted  dynamics.abi3.so", "Do not run this code"),
        write("dynamics.abi3.so", "not really ELF"),
        fix=False,
    ),
    repo_case(
        "content-digest-stale", E.IntegrityError, ("content_digest", "Re-publish"), manifest=setitem("content_digest", "0" * 64)
    ),
    # -- trust and requirements --
    repo_case(
        "untrusted",
        E.UntrustedCodeError,
        ("rel/untrusted@", "tiny.py", "trust_remote_code=True", "hub-envs trust rel/untrusted@"),
        trust_remote_code=False,
    ),
    _corrupt_trust_list_case(),
    repo_case(
        "requirement-missing",
        E.MissingRequirementsError,
        ("hub-envs-no-such-package", "not installed", "pip install hub-envs-no-such-package"),
        manifest=lambda m: m["requirements"].append("hub-envs-no-such-package"),
    ),
    repo_case(
        "requirement-newer-lerobot",
        E.MissingRequirementsError,
        ("lerobot>", "installed", "pip install 'lerobot>"),
        manifest=lambda m: m["requirements"].append(f"lerobot>{installed_version('lerobot')}"),
    ),
    repo_case(
        "requirement-incompatible",
        E.MissingRequirementsError,
        ("numpy<1", "installed", "pip install 'numpy<1'"),
        manifest=lambda m: m["requirements"].append("numpy<1"),
    ),
    # -- env code --
    repo_case(
        "import-raises",
        E.EnvCodeError,
        ("tiny", "RuntimeError: broken at import"),
        prepend("tiny.py", "raise RuntimeError('broken at import')\n"),
    ),
    repo_case(
        "import-missing-package",
        E.EnvCodeError,
        ("hub_envs_no_such_package", "declare it in the requirements"),
        prepend("tiny.py", "import hub_envs_no_such_package\n"),
    ),
    repo_case(
        "init-raises",
        E.EnvCodeError,
        ("rel/init-raises@", "RuntimeError: boom in __init__", "Fix the env"),
        replace("tiny.py", "        self.render_mode = render_mode\n", "        raise RuntimeError('boom in __init__')\n"),
    ),
    repo_case(
        "reset-raises",
        E.EnvCodeError,
        ("env.reset(seed=0)", "RuntimeError: boom in reset", "@", "Fix the env's reset"),
        replace(
            "tiny.py",
            "        super().reset(seed=seed)\n",
            "        super().reset(seed=seed)\n        raise RuntimeError('boom in reset')\n",
        ),
    ),
    repo_case(
        "step-raises",
        E.EnvCodeError,
        ("step 0: env.step(action) raised", "RuntimeError: boom in step", "@", "Fix the env's step"),
        replace(
            "tiny.py",
            "        self.pos, self.vel = dynamics_step(",
            "        raise RuntimeError('boom in step')\n        self.pos, self.vel = dynamics_step(",
        ),
    ),
    repo_case(
        "observation-nan",
        E.FeatureMismatchError,
        ("agent_pos", "non-finite values (NaN/inf) at step 0", "Fix the EnvConfig"),
        replace("tiny.py", OBS, "np.array([self.pos[0], np.nan], dtype=np.float32)"),
    ),
    repo_case(
        "observation-outside-space",
        E.FeatureMismatchError,
        ("agent_pos", "outside observation_space at step 0", "Fix the EnvConfig"),
        replace("tiny.py", OBS, "np.array([self.pos[0] + 5.0, self.vel[0]], dtype=np.float32)"),
    ),
    repo_case(
        "observation-wrong-dtype",
        E.FeatureMismatchError,
        ("agent_pos", "float64", "observation_space", "Fix the EnvConfig"),
        replace("tiny.py", OBS, "np.array([self.pos[0], self.vel[0]], dtype=np.float64)"),
    ),
    repo_case(
        "observation-wrong-shape",
        E.FeatureMismatchError,
        ("agent_pos", "live shape (3,) != declared (2,)", "Fix the EnvConfig"),
        replace("tiny.py", OBS, "np.array([self.pos[0], self.vel[0], 0.0], dtype=np.float32)"),
    ),
    repo_case(
        "observation-not-dict",
        E.FeatureMismatchError,
        ("observations must be dicts", "Fix the EnvConfig"),
        replace("tiny.py", 'return {"agent_pos": ' + OBS + "}", "return " + OBS),
    ),
    repo_case(
        "success-missing",
        E.FeatureMismatchError,
        ("info['is_success'] must be a bool", "Fix the EnvConfig"),
        replace("tiny.py", 'return {"is_success": bool(abs(self.pos[0]) < 0.05)}', "return {}"),
    ),
    repo_case(
        "fingerprint-drift",
        E.FingerprintMismatchError,
        ("fingerprint drifted", "seeds [0", "hub-envs reproduce", "fingerprint='warn'"),
        replace("dynamics.py", "GAIN = 1.0", "GAIN = 1.5"),
    ),
    # -- config --
    repo_case(
        "config-post-init-valueerror",
        E.ConfigError,
        ("TinyEnvConfig", "is invalid", "fps must be positive"),
        replace(
            "tiny.py", POST_INIT, "    def __post_init__(self):\n        raise ValueError('fps must be positive')\n\n" + POST_INIT
        ),
    ),
    repo_case(
        "config-post-init-raises",
        E.EnvCodeError,
        ("TinyEnvConfig()", "RuntimeError: config broken"),
        replace(
            "tiny.py", POST_INIT, "    def __post_init__(self):\n        raise RuntimeError('config broken')\n\n" + POST_INIT
        ),
    ),
    repo_case(
        "gym-kwargs-max-episode-steps",
        E.InvalidRepoFormatError,
        ("gym_kwargs contains 'max_episode_steps'", "Remove it from gym_kwargs"),
        replace("tiny.py", GYM_KWARGS, '        return {"render_mode": "rgb_array", "max_episode_steps": 30}'),
    ),
    repo_case(
        "gym-kwargs-not-dict",
        E.InvalidRepoFormatError,
        ("gym_kwargs must return a dict", "list"),
        replace("tiny.py", GYM_KWARGS, '        return ["rgb_array"]'),
    ),
    repo_case(
        "config-no-episode-length",
        E.InvalidRepoFormatError,
        ("no 'episode_length' field", "episode_length: int = 200"),
        replace("tiny.py", "    episode_length: int = 30\n", ""),
    ),
    # -- names that collide --
    repo_case(
        "config-registers-itself",
        E.RegistrationConflictError,
        ("registered itself as the choice 'tiny_self'", "Remove its @EnvConfig.register_subclass"),
        replace("tiny.py", CONFIG_CLASS, '@EnvConfig.register_subclass("tiny_self")\n' + CONFIG_CLASS),
    ),
    repo_case(
        "config-takes-lerobot-choice",
        E.RegistrationConflictError,
        ("pusht", "already", "Remove its @EnvConfig.register_subclass"),
        replace("tiny.py", CONFIG_CLASS, '@EnvConfig.register_subclass("pusht")\n' + CONFIG_CLASS),
    ),
    repo_case(
        "code-overrides-gym-id",
        E.RegistrationConflictError,
        ("CartPole-v1", "already registered", "gym.register"),
        lambda f: (f / "tiny.py").write_text(
            (f / "tiny.py").read_text() + "\ngym.register('CartPole-v1', entry_point=TinyEnv)\n"
        ),
    ),
    _gym_id_taken_case(),
    # -- the dataset --
    repo_case(
        "dataset-info-missing",
        E.DatasetError,
        ("dataset/meta/info.json", "does not exist", "Re-publish"),
        delete("dataset/meta/info.json"),
    ),
    repo_case(
        "dataset-path-traversal",
        E.ManifestError,
        ("dataset.path", "'../../etc'", "plain relative paths"),
        manifest=lambda m: m["dataset"].__setitem__("path", "../../etc"),
    ),
    repo_case("dataset-info-not-json", E.DatasetError, ("info.json", "not JSON", "Re"), write("dataset/meta/info.json", "{")),
    repo_case(
        "dataset-feature-shape",
        E.FeatureMismatchError,
        ("dataset shape (5,) != declared (2,)", "re-publish"),
        info_json(lambda i: i["features"]["observation.state"].__setitem__("shape", [5])),
    ),
    repo_case(
        "dataset-feature-dtype",
        E.FeatureMismatchError,
        ("dataset dtype 'int64'", "re-publish"),
        info_json(lambda i: i["features"]["observation.state"].__setitem__("dtype", "int64")),
    ),
    repo_case(
        "dataset-feature-missing",
        E.FeatureMismatchError,
        ("dataset has no feature 'observation.state'", "re-publish"),
        info_json(lambda i: i["features"].pop("observation.state")),
    ),
    repo_case(
        "dataset-feature-undeclared",
        E.FeatureMismatchError,
        ("dataset feature 'observation.extra' is not declared", "re-publish"),
        info_json(lambda i: i["features"].__setitem__("observation.extra", {"dtype": "float32", "shape": [1], "names": None})),
    ),
    # -- local env folders --
    folder_case(
        "folder-no-pyproject", E.EnvFolderError, ("pyproject.toml is missing", "[tool.hub-envs]"), delete("pyproject.toml")
    ),
    folder_case(
        "folder-bad-toml",
        E.EnvFolderError,
        ("pyproject.toml is not valid TOML", "Fix the syntax"),
        write("pyproject.toml", "[project\n"),
    ),
    folder_case(
        "folder-no-tool-table",
        E.EnvFolderError,
        ("no [tool.hub-envs] table", 'env = "module:EnvClass"'),
        write("pyproject.toml", "[project]\nname = 'x'\n"),
    ),
    folder_case(
        "folder-tool-not-table",
        E.EnvFolderError,
        ("[tool]", "must be a table"),
        write("pyproject.toml", "tool = 'x'\n[project]\nname = 'x'\n"),
    ),
    folder_case(
        "folder-project-not-table",
        E.EnvFolderError,
        ("[project]", "must be a table"),
        write("pyproject.toml", "project = 1\n[tool.hub-envs]\nenv = 'tiny:TinyEnv'\nconfig = 'tiny:TinyEnvConfig'\n"),
    ),
    folder_case(
        "folder-bad-dependency",
        E.EnvFolderError,
        ("dependency 'numpy>>1'", "not a valid requirement"),
        replace("pyproject.toml", '"numpy>=1.26"', '"numpy>>1"'),
    ),
    folder_case(
        "folder-generated-file",
        E.EnvFolderError,
        ("['env.py']", "generated by push_env", "Remove or rename"),
        write("env.py", "x = 1\n"),
    ),
    folder_case(
        "folder-bad-entry-point",
        E.EnvFolderError,
        ("env = 'tiny.TinyEnv'", "module:Attribute"),
        replace("pyproject.toml", 'env = "tiny:TinyEnv"', 'env = "tiny.TinyEnv"'),
    ),
    # -- push_env --
    _push_case("push-bad-repo-id", E.ConfigError, ("'not a repo'", "is not valid"), repo_id="not a repo"),
    _push_case("push-zero-episodes", E.ConfigError, ("--episodes must be at least 1",), episodes=0),
    _push_case(
        "push-render-needs-a-package",
        E.EnvCodeError,
        ("raised ModuleNotFoundError", "pygame_not_installed", "[project] dependencies", "renders the card's GIF"),
        edits={
            "tiny.py": lambda s: s.replace(
                "    def render(self):\n", "    def render(self):\n        import pygame_not_installed  # noqa\n"
            )
        },
    ),
    _push_case(
        "push-nan-observation",
        E.EnvCodeError,  # the determinism check, the first to run, finds it
        ("observation 'agent_pos' contains NaN or inf at step 0", "returned by env.reset", "Fix the env"),
        edits={"tiny.py": lambda s: s.replace(OBS, "np.array([self.pos[0], np.nan], dtype=np.float32)")},
    ),
    _push_case(
        "push-step-raises",
        E.EnvCodeError,
        ("boom in step",),
        edits={
            "tiny.py": lambda s: s.replace(
                "        self.pos, self.vel = dynamics_step(",
                "        raise RuntimeError('boom in step')\n        self.pos, self.vel = dynamics_step(",
            )
        },
    ),
]


def _env_modules() -> set[str]:
    return {m for m in sys.modules if m.startswith("hub_envs_code.")}


def _cache_state(hf_home: Path) -> dict[str, int]:
    cache = hf_home / "hub"
    if not cache.is_dir():
        return {}
    # huggingface_hub 1.x marks its cache folder with a CACHEDIR.TAG the first time it writes there
    return {
        p.relative_to(cache).as_posix(): p.lstat().st_size
        for p in cache.rglob("*")
        if not p.is_dir() and ".locks" not in p.parts and p.name != "CACHEDIR.TAG"
    }


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_bad_input_is_refused_with_its_own_error_and_no_side_effects(case: Case, base: Base):
    call = case.prepare(base)
    try:
        registries, modules = snapshot_registries(), _env_modules()
        cache = _cache_state(base.hub.hf_home)
        trust_file = hub_envs_home() / "trusted.json"
        trust_before = trust_file.read_bytes() if trust_file.exists() else None
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with pytest.raises(errors.HubEnvsError) as info:
                call()
        err = info.value
        assert type(err) is case.error, f"{type(err).__name__} instead of {case.error.__name__}: {err}"
        for text in case.says:
            assert text in str(err), f"{text!r} not in the message:\n{err}"
        assert snapshot_registries() == registries
        assert _env_modules() == modules
        assert (trust_file.read_bytes() if trust_file.exists() else None) == trust_before
        after = _cache_state(base.hub.hf_home)
        own = f"models--{case.repo.replace('/', '--')}/" if case.repo else None
        changed = {p for p in set(cache) | set(after) if cache.get(p) != after.get(p)}
        assert {p for p in changed if not (own and p.startswith(own))} == set()
        assert not [p for p in after if p.endswith(".incomplete")]
    finally:
        if case.cleanup:
            case.cleanup()


def test_the_corpus_is_large_and_every_case_is_distinct():
    assert len(CASES) >= 40
    assert len({c.id for c in CASES}) == len(CASES)
    assert len({c.error for c in CASES}) >= 14


# --- code the manifest does not cover never runs -----------------------------------------------


def test_planted_bytecode_never_runs_instead_of_the_verified_source(hub_storing_bytecode, tmp_path, monkeypatch):
    """Python runs an unchecked-hash ``__pycache__/*.pyc`` without looking at the source beside it;
    the manifest hashes sources only, so hub-envs must never read bytecode from a repo."""
    import importlib.util
    import os
    import py_compile

    monkeypatch.delenv("HUB_ENVS_PWNED", raising=False)
    evil = tmp_path / "dynamics.py"
    evil.write_text("import os\nos.environ['HUB_ENVS_PWNED'] = '1'\n" + (TINY / "dynamics.py").read_text())

    def plant(folder: Path) -> None:
        cfile = Path(importlib.util.cache_from_source(str(folder / "dynamics.py")))
        py_compile.compile(str(evil), cfile=str(cfile), invalidation_mode=py_compile.PycInvalidationMode.UNCHECKED_HASH)

    hub = hub_storing_bytecode  # a Hub that stores .pyc files, as huggingface.co does
    push_env(TINY, f"{NS}/planted-pyc", episodes=1, progress=False)
    sha = republish(hub.api, f"{NS}/planted-pyc", plant)  # the .pyc is uploaded, unlisted in the manifest
    assert any("__pycache__" in f for f in hub.api.list_repo_files(f"{NS}/planted-pyc", revision=sha))
    from lerobot.envs.factory import make_env

    from hub_envs.testing import hub_environment

    # LeRobot's own loader (it downloads env.py alone): env.py never fetches bytecode and imports the
    # verified .py sources only, so the env works and the planted code does not run.
    with hub_environment(hub.endpoint, tmp_path / "lerobot_home"):
        envs = make_env(f"{NS}/planted-pyc@{sha}", n_envs=1, trust_remote_code=True)
        vec = next(iter(next(iter(envs.values())).values()))
        assert vec.reset(seed=0)[0]["agent_pos"].shape == (1, 2)
        vec.close()
    assert "HUB_ENVS_PWNED" not in os.environ

    # load_env fetches the whole snapshot and refuses the unlisted bytecode before anything runs
    with pytest.raises(E.IntegrityError, match=r"unlisted  __pycache__/dynamics\.cpython-\d+\.pyc"):
        load_env(f"{NS}/planted-pyc@{sha}", trust_remote_code=True)
    assert "HUB_ENVS_PWNED" not in os.environ
    # ... and leaves no part of that snapshot in the cache, so nothing later runs the bytecode: LeRobot's
    # loader fetches env.py afresh and works from the verified sources again
    assert not (hub.hf_home / "hub" / f"models--{NS}--planted-pyc" / "snapshots" / sha).exists()
    envs = make_env(f"{NS}/planted-pyc@{sha}", n_envs=1, trust_remote_code=True)
    next(iter(next(iter(envs.values())).values())).close()
    assert "HUB_ENVS_PWNED" not in os.environ


# --- property-based: the parsers only ever raise their own error ------------------------------

from hypothesis import HealthCheck, example, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from hub_envs.repo.format import EnvFolder, Manifest  # noqa: E402
from hub_envs.repo.refs import parse_repo_ref  # noqa: E402

PROPERTY = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])

json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=True, allow_infinity=True) | st.text(max_size=20),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=12), children, max_size=4),
    max_leaves=12,
)
hexes = lambda n: st.text("0123456789abcdef", min_size=n, max_size=n)  # noqa: E731
identifiers = st.from_regex(r"[A-Za-z_][A-Za-z0-9_]{0,10}", fullmatch=True)
names = st.from_regex(r"[A-Za-z0-9_]([A-Za-z0-9_.-]{0,14}[A-Za-z0-9_])?", fullmatch=True).filter(
    lambda s: ".." not in s and "--" not in s
)
rel_paths = st.lists(
    st.from_regex(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,10}", fullmatch=True).filter(lambda s: s not in (".", "..")),
    min_size=1,
    max_size=3,
).map("/".join)
finite_json = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False, allow_infinity=False) | st.text(max_size=20),
    lambda children: st.lists(children, max_size=3) | st.dictionaries(st.text(max_size=10), children, max_size=3),
    max_leaves=8,
)


@st.composite
def benchmark_entries(draw):
    """Benchmark entries as push_env writes them (repo_format._check_benchmark's shape), with any values."""
    episodes = draw(st.integers(1, 4))
    metrics = draw(
        st.dictionaries(st.text(min_size=1, max_size=8), st.floats(allow_nan=False, allow_infinity=False), min_size=1, max_size=3)
    )
    return {
        "name": draw(st.text(min_size=1, max_size=8)),
        "policy": {"type": draw(st.sampled_from(["random", "lerobot"]))},
        "episodes": episodes,
        "seeds": draw(st.lists(st.integers(0, 2**31), min_size=episodes, max_size=episodes)),
        "metrics": metrics,
        "tolerance": {k: draw(st.floats(0, 1)) for k in metrics},
        "per_episode": {"return": draw(st.lists(st.floats(-1, 1), min_size=episodes, max_size=episodes))},
    }


@st.composite
def valid_manifests(draw) -> dict:
    entry = st.builds(lambda m, a: f"{m}:{a}", identifiers, identifiers)
    return {
        "format_version": 1,
        "name": draw(st.text(max_size=20)),
        "env_entry_point": draw(entry),
        "config_entry_point": draw(entry),
        "gym_id": f"{draw(names)}/{draw(names)}",
        "env_type": draw(names),
        "files": draw(st.dictionaries(rel_paths, hexes(64), min_size=1, max_size=5)),
        "content_digest": draw(hexes(64)),
        "requirements": draw(
            st.lists(st.sampled_from(["numpy>=1", "gymnasium", "pybullet>=3.2; python_version>'3'"]), max_size=3)
        ),
        "config": draw(st.dictionaries(st.text(max_size=10), finite_json, max_size=4)),
        "dataset": {"path": draw(rel_paths), "episodes": draw(st.integers(0, 100))},
        "benchmarks": draw(st.lists(benchmark_entries(), max_size=2)),
        "versions": draw(st.dictionaries(st.text(max_size=8), st.text(max_size=8), max_size=3)),
    }


@PROPERTY
@given(st.text(max_size=300) | json_values.map(json.dumps))
@example("[" * 100_000)  # nested deeper than the JSON parser's recursion limit
@example('{"format_version": 1, "files": {"a": NaN}}')
def test_manifest_from_json_raises_only_manifest_error(text):
    try:
        Manifest.from_json(text)
    except errors.ManifestError:
        pass


@PROPERTY
@given(valid_manifests(), st.sampled_from(["set", "delete", "add"]), st.data())
def test_a_mutated_manifest_parses_or_raises_manifest_error(manifest, how, data):
    keys = sorted(manifest)
    if how == "set":
        manifest[data.draw(st.sampled_from(keys))] = data.draw(json_values)
    elif how == "delete":
        del manifest[data.draw(st.sampled_from(keys))]
    else:
        manifest[data.draw(st.text(max_size=10))] = data.draw(json_values)
    try:
        parsed = Manifest.from_dict(manifest)
    except errors.ManifestError:
        return
    assert Manifest.from_json(parsed.to_json()) == parsed  # whatever parses also round-trips


@PROPERTY
@given(valid_manifests())
def test_valid_manifests_round_trip_through_canonical_json(data):
    manifest = Manifest.from_dict(data)
    text = manifest.to_json()
    again = Manifest.from_json(text)
    assert again == manifest and again.to_json() == text
    assert json.loads(text)["files"] == data["files"]


toml_values = (
    st.text(max_size=15).map(json.dumps)
    | st.integers().map(str)
    | st.booleans().map(lambda b: str(b).lower())
    | st.lists(st.text(max_size=10).map(json.dumps), max_size=3).map(lambda xs: "[" + ", ".join(xs) + "]")
    | st.sampled_from(['"tiny:TinyEnv"', '"tiny:TinyEnvConfig"', '"numpy>=1"', "{}", "[1, 2]", '"tiny.TinyEnv"'])
)
toml_lines = st.lists(
    st.sampled_from(["[project]", "[tool]", "[tool.hub-envs]", "[tool.other]", "[[project]]"])
    | st.builds(
        lambda k, v: f"{k} = {v}",
        st.sampled_from(
            ["name", "version", "dependencies", "env", "config", "description", "project", "tool", '"hub-envs"', "x"]
        ),
        toml_values,
    ),
    max_size=10,
).map("\n".join)


@PROPERTY
@given(st.text(max_size=200) | toml_lines)
def test_env_folder_read_raises_only_env_folder_error(text):
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "tiny.py").write_text("x = 1\n")
        (Path(tmp) / "pyproject.toml").write_text(text, encoding="utf-8", errors="surrogatepass")
        try:
            folder = EnvFolder.read(tmp)
        except errors.EnvFolderError:
            return
        assert ":" in folder.env_entry_point and ":" in folder.config_entry_point and folder.name


@PROPERTY
@given(st.text(max_size=60) | st.builds(lambda a, b, r: f"{a}/{b}@{r}", names, names, st.text(max_size=10)))
def test_parse_repo_ref_raises_only_config_error(ref):
    try:
        repo_id, revision = parse_repo_ref(ref)
    except errors.ConfigError:
        return
    assert "/" in repo_id and f"{repo_id}@{revision}" == ref if revision else repo_id == ref


@PROPERTY
@given(names, names, st.one_of(st.none(), hexes(40), names))
def test_parse_repo_ref_round_trips_valid_ids(namespace, name, revision):
    ref = f"{namespace}/{name}" + (f"@{revision}" if revision else "")
    assert parse_repo_ref(ref) == (f"{namespace}/{name}", revision)
