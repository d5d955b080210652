"""The env repo round trip: push_env a folder, load_env it back by repo id, as a user would.

Real parts only: the loopback Hub server over HTTP, the unmodified huggingface_hub client,
gymnasium's registry, draccus parsing, LeRobotDataset.
"""

from __future__ import annotations

import json
import os
import sys
from dataclasses import dataclass
from pathlib import Path

import draccus
import gymnasium as gym
import numpy as np
import pytest
from helpers import TINY, copy_env, republish
from lerobot.envs.configs import EnvConfig

from hub_envs import errors, load_env, push_env, reproduce, trust
from hub_envs.envcode.importing import module_key
from hub_envs.envcode.registration import consenting_choice, snapshot_registries
from hub_envs.testing import hub_environment


@dataclass
class LeRobotStyleConfig:
    """The shape of lerobot's own pipeline configs: an ``env: EnvConfig`` choice field."""

    env: EnvConfig
    seed: int = 1000


def _push(path, repo_id, **kw):
    kw.setdefault("episodes", 3)
    kw.setdefault("progress", False)
    return push_env(path, repo_id, **kw)


def test_push_then_load_by_repo_id_from_a_clean_cache(hub, tmp_path):
    result = _push(TINY, "alice/tiny", episodes=4, seed=7)
    assert result.created_commit and len(result.sha) == 40
    assert result.load_line == f'load_env("alice/tiny@{result.sha}", trust_remote_code=True)'

    with hub_environment(hub.endpoint, tmp_path / "fresh_home", token=hub.token):
        loaded = load_env(f"alice/tiny@{result.sha}", trust_remote_code=True)
        assert loaded.revision == result.sha
        assert str(tmp_path / "fresh_home") in str(loaded.path)

        env = gym.make(loaded.gym_id)
        obs, info = env.reset(seed=3)
        assert obs["agent_pos"].shape == (2,) and isinstance(info["is_success"], bool)
        for _ in range(5):
            obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        assert env.spec.max_episode_steps == loaded.config.episode_length == 30

        cfg = draccus.parse(LeRobotStyleConfig, args=[f"--env.type={loaded.env_type}", "--env.episode_length=12", "--seed=3"])
        # the repo's config class, with the consent flag of LeRobot's CLIs (--env.trust_remote_code) as a field
        assert type(cfg.env) is consenting_choice(loaded.config_class) and cfg.env.episode_length == 12
        assert isinstance(cfg.env, loaded.config_class) and EnvConfig.get_choice_class(loaded.env_type) is type(cfg.env)
        assert cfg.env.type == loaded.env_type
        short = loaded.make(cfg.env)
        assert short.spec.max_episode_steps == 12

        dataset = loaded.open_dataset()
        assert dataset.num_episodes == 4 and dataset.num_frames == 4 * 30
        assert set(dataset.features) >= {"observation.state", "action", "next.reward"}
        first = dataset[0]
        assert tuple(first["observation.state"].shape) == (2,)
        assert json.loads((loaded.dataset_root / "meta" / "hub_envs.json").read_text())["seeds"] == [7, 8, 9, 10]
        assert loaded.manifest.dataset["seeds"] == [7, 8, 9, 10]
        assert loaded.report.features.ok and "matches" in loaded.report.fingerprint
        # the dataset's first observation is what reset(seed=7) gives
        env0 = loaded.make()
        obs0, _ = env0.reset(seed=7)
        np.testing.assert_array_equal(first["observation.state"].numpy(), obs0["agent_pos"])


def test_pushing_unchanged_content_twice_makes_one_commit(hub, tmp_path):
    first = _push(TINY, "alice/tiny-twice")
    second = _push(TINY, "alice/tiny-twice")
    assert not second.created_commit and second.sha == first.sha
    assert "build" not in second.timings  # nothing was regenerated to find out
    assert second.manifest == first.manifest
    forced = _push(TINY, "alice/tiny-twice", force=True)  # rebuilt: the same bytes, so still no commit
    assert not forced.created_commit and forced.sha == first.sha and "build" in forced.timings
    commits = hub.api.list_repo_commits("alice/tiny-twice")
    assert [c.commit_id for c in commits if c.commit_id == first.sha] == [first.sha]
    assert commits[0].commit_id == first.sha
    third = _push(TINY, "alice/tiny-twice", episodes=4)  # different content: a new commit
    assert third.created_commit and third.sha != first.sha
    edited = copy_env(tmp_path, edits={"dynamics.py": lambda s: s + "\n# a comment is a change of code\n"})
    assert _push(edited, "alice/tiny-twice", episodes=4).created_commit


def test_the_card_states_the_license_the_folder_declares_and_none_otherwise(hub, tmp_path):
    from huggingface_hub import ModelCard

    _push(TINY, "alice/tiny-nolicense")  # the fixture's pyproject declares none
    assert "license" not in ModelCard.load("alice/tiny-nolicense").data.to_dict()
    mit = copy_env(
        tmp_path, edits={"pyproject.toml": lambda s: s.replace('version = "0.1.0"', 'version = "0.1.0"\nlicense = "MIT"')}
    )
    _push(mit, "alice/tiny-mit")
    assert ModelCard.load("alice/tiny-mit").data.to_dict()["license"] == "mit"


def test_one_commit_holds_everything_and_is_tagged(hub):
    result = _push(TINY, "alice/tiny-files", tag="v1")
    files = set(hub.api.list_repo_files("alice/tiny-files", revision=result.sha))
    assert {
        "env.py",
        "hub_env.json",
        "README.md",
        "tiny.py",
        "dynamics.py",
        "pyproject.toml",
        "media/rollout.gif",
        "dataset/meta/info.json",
    } <= files
    refs = hub.api.list_repo_refs("alice/tiny-files")
    assert {t.name: t.target_commit for t in refs.tags} == {result.content_tag: result.sha, "v1": result.sha}
    card = hub.api.model_info("alice/tiny-files", revision=result.sha).card_data
    assert "hub-envs" in card.tags and card.library_name == "hub-envs"


def test_two_revisions_of_one_repo_coexist(hub, tmp_path):
    v1 = _push(TINY, "alice/tiny-revs")
    faster = copy_env(tmp_path, edits={"dynamics.py": lambda s: s.replace("GAIN = 1.0", "GAIN = 3.0")})
    v2 = _push(faster, "alice/tiny-revs")
    assert v1.sha != v2.sha
    a = load_env("alice/tiny-revs", revision=v1.sha, trust_remote_code=True)
    b = load_env(f"alice/tiny-revs@{v2.sha}", trust_remote_code=True)
    assert a.gym_id != b.gym_id and a.env_type != b.env_type
    assert a.env_class is not b.env_class
    trajectories = []
    for loaded in (a, b):
        env = gym.make(loaded.gym_id)
        env.reset(seed=0)
        obs, *_ = env.step(np.ones(1, dtype=np.float32))
        trajectories.append(obs["agent_pos"][1])
    assert trajectories[1] == pytest.approx(3 * trajectories[0])


def test_a_branch_loads_with_a_warning_that_shows_the_pin(hub):
    result = _push(TINY, "alice/tiny-branch")
    with pytest.warns(UserWarning, match=f"alice/tiny-branch@{result.sha}"):
        loaded = load_env("alice/tiny-branch", trust_remote_code=True)
    assert loaded.revision == result.sha


def test_offline_load_from_cache(hub, monkeypatch):
    result = _push(TINY, "alice/tiny-offline")
    load_env(f"alice/tiny-offline@{result.sha}", trust_remote_code=True).unregister()
    hub.server.stop()  # no server at all: only the cache can answer
    with hub_environment(hub.endpoint, hub.hf_home, token=hub.token, offline=True):
        loaded = load_env(f"alice/tiny-offline@{result.sha}", trust_remote_code=True)
        assert loaded.revision == result.sha
        gym.make(loaded.gym_id).reset(seed=0)
        with pytest.raises(errors.OfflineNotCachedError, match="alice/tiny-offline@main"):
            load_env("alice/tiny-offline@main", trust_remote_code=True)


MARKER_CODE = "import os, pathlib\npathlib.Path(os.environ['HUB_ENVS_TEST_MARKER']).write_text('imported')\n"


def test_untrusted_load_imports_and_registers_nothing_and_tofu_is_keyed_by_sha(hub, tmp_path, monkeypatch):
    marker = tmp_path / "marker"
    monkeypatch.setenv("HUB_ENVS_TEST_MARKER", str(marker))
    folder = copy_env(tmp_path, edits={"tiny.py": lambda s: MARKER_CODE + s})
    first = _push(folder, "mallory/tiny")
    marker.unlink()
    before = snapshot_registries()

    with pytest.raises(errors.UntrustedCodeError) as e:
        load_env(f"mallory/tiny@{first.sha}")
    assert f"hub-envs trust mallory/tiny@{first.sha}" in str(e.value)
    assert "trust_remote_code=True" in str(e.value)
    assert not marker.exists()
    assert snapshot_registries() == before
    key = module_key("mallory/tiny", first.sha)
    assert not any(name.startswith(f"hub_envs_code.{key}") for name in list(__import__("sys").modules))

    trust("mallory/tiny", first.sha)  # the function (hub_envs.trust), bound to the manifest it reads
    loaded = load_env(f"mallory/tiny@{first.sha}")
    assert marker.exists() and loaded.report.trust.startswith("trust list")
    loaded.unregister()

    second = _push(
        copy_env(tmp_path, src=folder, name="v2", edits={"dynamics.py": lambda s: s.replace("DT = 0.05", "DT = 0.1")}),
        "mallory/tiny",
    )
    with pytest.raises(errors.UntrustedCodeError, match="dynamics.py"):
        load_env(f"mallory/tiny@{second.sha}")


def test_a_tampered_file_is_refused(hub):
    result = _push(TINY, "alice/tiny-tamper")
    evil = "import os\nos.environ['PWNED'] = '1'\n" + (TINY / "dynamics.py").read_text()
    tampered = hub.api.upload_file(path_or_fileobj=evil.encode(), path_in_repo="dynamics.py", repo_id="alice/tiny-tamper").oid
    assert tampered != result.sha
    with pytest.raises(errors.IntegrityError, match="tampered  dynamics.py"):
        load_env(f"alice/tiny-tamper@{tampered}", trust_remote_code=True)
    assert "PWNED" not in os.environ
    extra = hub.api.upload_file(path_or_fileobj=b"print('hi')\n", path_in_repo="extra.py", repo_id="alice/tiny-tamper").oid
    with pytest.raises(errors.IntegrityError, match="unlisted  extra.py"):
        load_env(f"alice/tiny-tamper@{extra}", trust_remote_code=True)


def test_a_missing_requirement_is_reported_with_the_pip_line(hub):
    _push(TINY, "alice/tiny-reqs")

    def require_more(folder):
        manifest = json.loads((folder / "hub_env.json").read_text())
        manifest["requirements"] += ["hub-envs-no-such-package>=1.0", "numpy<1"]
        (folder / "hub_env.json").write_text(json.dumps(manifest))

    sha = republish(hub.api, "alice/tiny-reqs", require_more)
    before = snapshot_registries()
    with pytest.raises(errors.MissingRequirementsError) as e:
        load_env(f"alice/tiny-reqs@{sha}", trust_remote_code=True)
    assert "pip install 'hub-envs-no-such-package>=1.0' 'numpy<1'" in str(e.value)
    assert snapshot_registries() == before
    # LeRobot's own loader (the repo's env.py, no hub-envs): the same pip line, before any env code runs
    from lerobot.envs.factory import make_env as lerobot_make_env

    with pytest.raises(
        ImportError, match=r"alice/tiny-reqs@[0-9a-f]{40} needs .*pip install 'hub-envs-no-such-package>=1.0' 'numpy<1'"
    ):
        lerobot_make_env(f"alice/tiny-reqs@{sha}", n_envs=1, trust_remote_code=True)


def test_push_refuses_declared_shapes_that_disagree_with_rollouts(hub, tmp_path):
    folder = copy_env(tmp_path, edits={"tiny.py": lambda s: s.replace("shape=(2,))", "shape=(3,))")})
    before = snapshot_registries()
    with pytest.raises(errors.FeatureMismatchError) as e:
        _push(folder, "alice/tiny-badshape")
    assert "live shape (2,) != declared (3,)" in e.value.table
    assert snapshot_registries() == before
    with pytest.raises(errors.EnvRepoNotFoundError):
        load_env("alice/tiny-badshape", trust_remote_code=True)


@pytest.mark.parametrize(
    ("get_state", "reason"),
    [
        ("return {'pos': self.pos.copy()}", "returned a dict, not a numeric array"),
        ("return np.zeros(2 + (abs(self.pos[0]) > 0.05))", "returned a value unlike step 0's"),
    ],
    ids=["dict", "shape-changes"],
)
def test_push_warns_when_get_state_cannot_be_recorded(hub, tmp_path, get_state, reason):
    """The simulator-state contract (hub_envs.dataset.states): a get_state() that breaks it is named at push."""
    old = "return np.concatenate([self.pos, self.vel]).astype(np.float64)"
    folder = copy_env(tmp_path, edits={"tiny.py": lambda s: s.replace(old, get_state)})
    with pytest.warns(errors.StatesNotRecordedWarning, match=reason):
        result = _push(folder, f"alice/tiny-state-{len(reason)}")
    assert result.manifest.dataset["env_states"] is None  # published without states, and said so


def test_noise_late_in_an_episode_is_refused_at_push_with_its_step(hub, tmp_path):
    """Determinism covers whole episodes: noise injected from step 40 (past the first 32 steps) is found at push."""
    folder = copy_env(
        tmp_path,
        edits={
            "tiny.py": lambda s: (
                s.replace("episode_length: int = 30", "episode_length: int = 60")
                .replace("self.vel = np.zeros(1)\n        return", "self.vel = np.zeros(1)\n        self.t = 0\n        return")
                .replace(
                    "        reward = -float(abs(self.pos[0]))\n",
                    "        reward = -float(abs(self.pos[0]))\n        self.t += 1\n"
                    "        if self.t > 40:\n            self.vel = self.vel + np.random.normal(0.0, 1e-3, 1)\n",
                )
            )
        },
    )
    with pytest.raises(errors.DeterminismError, match=r"observation 'agent_pos' at step 41 \(max abs difference"):
        _push(folder, "alice/tiny-late-noise")
    with pytest.raises(errors.EnvRepoNotFoundError):  # nothing was published
        load_env("alice/tiny-late-noise", trust_remote_code=True)


def test_load_refuses_a_repo_whose_shapes_or_dataset_disagree_with_its_config(hub):
    _push(TINY, "alice/tiny-lies")

    def lie_in_code_and_dataset(folder):
        code = (folder / "tiny.py").read_text().replace("shape=(2,))", "shape=(3,))").replace("shape=(1,))", "shape=(2,))")
        (folder / "tiny.py").write_text(code)
        manifest = json.loads((folder / "hub_env.json").read_text())
        manifest["config"]["features"]["agent_pos"]["shape"] = [3]
        manifest["config"]["features"]["action"]["shape"] = [2]
        (folder / "hub_env.json").write_text(json.dumps(manifest))

    sha = republish(hub.api, "alice/tiny-lies", lie_in_code_and_dataset)
    before = snapshot_registries()
    with pytest.raises(errors.FeatureMismatchError) as e:
        load_env(f"alice/tiny-lies@{sha}", trust_remote_code=True)
    table = e.value.table
    assert "live shape (2,) != declared (3,)" in table and "dataset shape (2,) != declared (3,)" in table
    assert "action_space shape (1,) != declared (2,)" in table  # every disagreement, not just the first
    assert len(e.value.mismatches) == 2
    assert snapshot_registries() == before
    # LeRobot's own loader (the repo's env.py, no hub-envs) refuses it too, with the same rows
    from lerobot.envs.factory import make_env as lerobot_make_env

    with pytest.raises(ValueError, match=r"declared features disagree") as e:
        lerobot_make_env(f"alice/tiny-lies@{sha}", n_envs=1, trust_remote_code=True)
    assert "live shape (2,) != declared (3,)" in str(e.value) and "action_space shape (1,) != declared (2,)" in str(e.value)

    def lie_in_dataset(folder):
        info = json.loads((folder / "dataset/meta/info.json").read_text())
        info["features"]["observation.state"]["shape"] = [5]
        (folder / "dataset/meta/info.json").write_text(json.dumps(info))

    _push(TINY, "alice/tiny-lies2")
    sha = republish(hub.api, "alice/tiny-lies2", lie_in_dataset)
    with pytest.raises(errors.FeatureMismatchError, match=r"dataset shape \(5,\) != declared \(2,\)"):
        load_env(f"alice/tiny-lies2@{sha}", trust_remote_code=True)
    assert snapshot_registries() == before


def test_a_manifest_of_the_first_format_still_loads(hub):
    """Older formats keep loading: a format_version 1 manifest (no config_overrides, no resolved) is read with
    those fields' defaults."""
    _push(TINY, "alice/tiny-v1")

    def as_format_1(folder):
        manifest = json.loads((folder / "hub_env.json").read_text())
        manifest["format_version"] = 1
        del manifest["config_overrides"], manifest["resolved"]
        (folder / "hub_env.json").write_text(json.dumps(manifest))

    sha = republish(hub.api, "alice/tiny-v1", as_format_1)
    loaded = load_env(f"alice/tiny-v1@{sha}", trust_remote_code=True)
    assert loaded.manifest.format_version == 1 and loaded.manifest.config_overrides == {} and loaded.manifest.resolved == {}
    assert (
        '"config_overrides"' not in loaded.manifest.to_json() and '"resolved"' not in loaded.manifest.to_json()
    )  # written back as format 1 wrote it
    loaded.unregister()


def test_missing_repo_and_revision_are_typed_errors(hub):
    with pytest.raises(errors.EnvRepoNotFoundError, match="nobody/nothing"):
        load_env("nobody/nothing", trust_remote_code=True)
    _push(TINY, "alice/tiny-rev")
    with pytest.raises(errors.RevisionNotFoundError, match="no revision 'v9'"):
        load_env("alice/tiny-rev@v9", trust_remote_code=True)


def test_checks_that_passed_are_reused_for_the_same_sha_and_packages(hub):
    result = _push(TINY, "alice/tiny-cache")
    first = load_env(f"alice/tiny-cache@{result.sha}", trust_remote_code=True)
    assert first.report.fingerprint.startswith("matches") and "cached" not in first.report.fingerprint
    second = load_env(f"alice/tiny-cache@{result.sha}", trust_remote_code=True)
    assert "cached" in second.report.fingerprint
    assert second.report.features.table() == first.report.features.table()
    forced = load_env(f"alice/tiny-cache@{result.sha}", trust_remote_code=True, recheck=True)
    assert "cached" not in forced.report.fingerprint
    other_settings = load_env(f"alice/tiny-cache@{result.sha}", trust_remote_code=True, check_steps=5)
    assert "cached" not in other_settings.report.fingerprint and other_settings.report.features.steps == 5


def test_hub_envs_load_says_how_to_recheck_and_its_recheck_flag_runs_the_checks(hub, capsys):
    from hub_envs.cli import main as cli_main

    sha = _push(TINY, "alice/tiny-recheck").sha
    args = ["load", f"--repo_id=alice/tiny-recheck@{sha}", "--trust_remote_code=true"]
    assert cli_main(args) == 0
    assert "cached" not in capsys.readouterr().out
    assert cli_main(args) == 0
    line = next(x for x in capsys.readouterr().out.splitlines() if x.strip().startswith("fingerprint:"))
    assert "cached: passed on" in line and "hub-envs load --recheck=true" in line  # the flag the message names exists
    assert cli_main([*args, "--recheck=true"]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines() if x.strip().startswith("fingerprint:"))
    assert line.split()[1] == "matches" and "cached" not in line


def test_a_failed_reload_leaves_the_earlier_load_working(hub):
    import sys

    result = _push(TINY, "alice/tiny-reload")
    first = load_env(f"alice/tiny-reload@{result.sha}", trust_remote_code=True)
    with pytest.raises(errors.ConfigError, match="fingerprint='erorr'"):
        load_env(f"alice/tiny-reload@{result.sha}", trust_remote_code=True, fingerprint="erorr")
    # someone else takes the gym id: the reload fails after importing, and must not drop the modules
    # the first load's classes live in
    spec = gym.registry.pop(first.gym_id)
    gym.register(first.gym_id, entry_point="gymnasium.envs.classic_control:CartPoleEnv")
    try:
        with pytest.raises(errors.RegistrationConflictError):
            load_env(f"alice/tiny-reload@{result.sha}", trust_remote_code=True)
        assert first.env_class.__module__ in sys.modules
    finally:
        gym.registry[first.gym_id] = spec
    again = load_env(f"alice/tiny-reload@{result.sha}", trust_remote_code=True)
    assert again.env_class is first.env_class
    assert EnvConfig.get_choice_class(first.env_type) is consenting_choice(first.config_class)
    assert type(gym.make(first.gym_id).unwrapped) is first.env_class


def test_push_repairs_a_repo_a_hand_commit_changed_and_guards_a_taken_tag(hub):
    first = _push(TINY, "alice/tiny-repair", tag="v1")
    stray = hub.api.upload_file(path_or_fileobj=b"notes\n", path_in_repo="NOTES.txt", repo_id="alice/tiny-repair").oid
    again = _push(TINY, "alice/tiny-repair")  # same content, but the repo holds an extra file now
    assert again.created_commit and again.sha != stray
    assert "NOTES.txt" not in hub.api.list_repo_files("alice/tiny-repair", revision=again.sha)
    assert again.manifest.content_digest == first.manifest.content_digest
    head_before = hub.api.model_info("alice/tiny-repair").sha
    with pytest.raises(errors.ConfigError, match="Tag 'v1' of alice/tiny-repair already names commit"):
        _push(TINY, "alice/tiny-repair", episodes=4, tag="v1")
    assert hub.api.model_info("alice/tiny-repair").sha == head_before  # nothing was published


def test_a_repo_id_never_picks_a_same_named_local_folder(hub, tmp_path, monkeypatch):
    result = _push(TINY, "alice/tiny-shadow")
    copy_env(tmp_path / "alice", name="tiny-shadow", edits={"tiny.py": lambda s: "raise RuntimeError('local code ran')\n" + s})
    monkeypatch.chdir(tmp_path)
    with pytest.warns(UserWarning, match="'./alice/tiny-shadow' to use the folder"):
        loaded = load_env("alice/tiny-shadow", revision=result.sha, trust_remote_code=True)
    assert loaded.revision == result.sha and not loaded.is_local
    with pytest.raises(errors.EnvCodeError, match="local code ran"):
        load_env("./alice/tiny-shadow")


# --- integer actions ---------------------------------------------------------------------------------

CARTPOLE = TINY.parent / "cartpole_env"


@pytest.mark.parametrize("declared", ["()", "(1,)"])
def test_discrete_actions_push_load_replay_and_run_in_lerobot(hub, tmp_path, declared):
    """A Discrete(2) CartPole declared with shape () or (1,): stored as int64 (1,), replayed exactly, and
    driven by LeRobot's own loader with the float actions a policy gives."""
    from lerobot.envs.factory import make_env as lerobot_make_env

    from hub_envs.dataset.reader import read_episode_frames

    folder = copy_env(tmp_path, CARTPOLE, edits={"cartpole.py": lambda s: s.replace("shape=()", f"shape={declared}")})
    repo = f"alice/cartpole-{len(declared)}"
    result = _push(folder, repo)
    action = result.manifest.dataset["features"]["action"]
    assert (action["dtype"], action["shape"]) == ("int64", [1])
    loaded = load_env(f"{repo}@{result.sha}", trust_remote_code=True)  # the three-way check passes
    try:
        frames = read_episode_frames(loaded.dataset_root, 0)
        assert frames["action"].dtype == np.int64 and frames["action"].shape[1:] == (1,)
        assert set(np.unique(frames["action"])) <= {0, 1}
    finally:
        loaded.unregister()
    report = reproduce(f"{repo}@{result.sha}", trust_remote_code=True, out=tmp_path / "rep", workers=1, progress=False)
    assert report.reproduced, report.summary()
    with hub_environment(hub.endpoint, tmp_path / "fresh"):
        ((_, tasks),) = lerobot_make_env(f"{repo}@{result.sha}", n_envs=2, trust_remote_code=True).items()
        vec = tasks[0]
        vec.reset(seed=[0, 1])
        _, reward, *_ = vec.step(np.array([[1.0], [0.0]], dtype=np.float32))  # what LeRobot's eval loop passes
        assert reward.tolist() == [1.0, 1.0]


def test_integer_actions_stored_as_floats_are_a_mismatch(hub, tmp_path):
    """The three-way check compares the action's dtype too: a MultiDiscrete env whose dataset says float32."""
    result = _push(CARTPOLE, "alice/cartpole-multi", config={"action_kind": "multi"})
    assert result.manifest.dataset["features"]["action"]["dtype"] == "int64"

    def as_floats(folder):
        info = json.loads((folder / "dataset/meta/info.json").read_text())
        info["features"]["action"]["dtype"] = "float32"
        (folder / "dataset/meta/info.json").write_text(json.dumps(info))

    sha = republish(hub.api, "alice/cartpole-multi", as_floats)
    with pytest.raises(
        errors.FeatureMismatchError, match=r"dataset dtype float32 != int64, which the live actions are stored as"
    ):
        load_env(f"alice/cartpole-multi@{sha}", trust_remote_code=True)


def test_an_action_space_hub_envs_cannot_record_is_refused_at_push_by_name(hub, tmp_path):
    folder = copy_env(
        tmp_path,
        edits={"tiny.py": lambda s: s.replace("spaces.Box(-1.0, 1.0, (1,), np.float32)", "spaces.Text(4)")},
    )
    with pytest.raises(errors.EnvCheckError, match=r"Text\(1, 4, charset=\.\.\.\) actions are not supported: use a Box"):
        _push(folder, "alice/tiny-text-actions")


def test_env_code_reading_assets_through_resolve_loads_from_the_hub_and_in_lerobot(hub, tmp_path):
    """``Path(__file__).resolve().parent / "assets"`` works in a loaded env as in the author's folder: env code is
    imported from real files (hub_envs.envcode.code_copy), not from the cache's symlinks into blobs/."""
    from lerobot.envs.factory import make_env as lerobot_make_env

    reads_asset = (
        "import json\nfrom pathlib import Path\n\n"
        'GAIN = json.loads((Path(__file__).resolve().parent / "assets" / "params.json").read_text())["gain"]\n'
    )
    folder = copy_env(tmp_path, edits={"dynamics.py": lambda s: s.replace("GAIN = 1.0\n", reads_asset)})
    (folder / "assets").mkdir()
    (folder / "assets" / "params.json").write_text('{"gain": 1.5}\n')
    result = _push(folder, "alice/tiny-assets")
    with hub_environment(hub.endpoint, tmp_path / "fresh"):  # from the Hub, into an empty cache
        loaded = load_env(f"alice/tiny-assets@{result.sha}", trust_remote_code=True)
        try:
            module = sys.modules[type(loaded.make().unwrapped).__module__.rsplit(".", 1)[0] + ".dynamics"]
            assert module.GAIN == 1.5 and not Path(module.__file__).is_symlink()
        finally:
            loaded.unregister()
        ((_, tasks),) = lerobot_make_env(f"alice/tiny-assets@{result.sha}", n_envs=1, trust_remote_code=True).items()
        tasks[0].reset(seed=[0])
