"""A new process's first step of a cached env: no torch, no lerobot, unless something asks for them.

A user's second run of ``load_env("user/name@<sha>").make()`` (files cached, consent in the trust list, the checks'
verdict cached) needs only gymnasium and the env's own code; LeRobot's config (``loaded.config``) and its ``--env.type``
choice are still there the moment something asks for them in the same process. Each scenario is a fresh ``python``
(``sys.modules`` is what is asserted); real parts: the loopback Hub, huggingface_hub, LeRobot's parser, draccus.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from hub_envs import load_env, push_env, trust
from hub_envs.errors import IsolationUnavailableError, ProcessorError
from hub_envs.loading import check_cache
from hub_envs.paths import hub_envs_home

ROOT = Path(__file__).resolve().parent.parent

#: Loads the env, makes it, steps it, and says which of torch and lerobot got imported; then the scenario.
SCRIPT = """
import json, sys
from hub_envs import load_env

loaded = load_env(sys.argv[1], **json.loads(sys.argv[3]))
env = loaded.make()
env.reset(seed=0)
env.step(env.action_space.sample())
out = {"heavy": sorted({m.split(".")[0] for m in sys.modules} & {"torch", "lerobot"}), "checks": loaded.report.fingerprint}
scenario = sys.argv[2]
if scenario == "load only":
    print("RESULT " + json.dumps(out))
    sys.exit(0)

if scenario == "processors on use":  # the env's declared processors, built when asked for (LeRobot's eval loop does)
    import torch

    pre, post = loaded.processors()
    clipped = post(post.to_transition({"action": torch.full((1, env.action_space.shape[0]), 5.0)}))["action"]
    out["processors"] = [[type(s).__name__ for s in pre.steps], [type(s).__name__ for s in post.steps]]
    out["clipped"] = sorted(set(clipped.flatten().tolist()))
    print("RESULT " + json.dumps(out))
    sys.exit(0)

if scenario == "unregistered":  # the choice of a load released before LeRobot came is not registered when it comes
    env_type = loaded.env_type
    loaded.unregister()
    from lerobot.envs.configs import EnvConfig

    out["choice_after_unregister"] = env_type in EnvConfig.get_known_choices()
    loaded = load_env(sys.argv[1])  # loaded again: registered at once

if scenario == "config first":
    cfg = loaded.config
    out["config_first"] = [type(cfg).__qualname__, cfg.g]

import draccus
from lerobot.configs.eval import EvalPipelineConfig
from lerobot.envs.configs import EnvConfig

from hub_envs.envcode.envconfig import encode_config

ev = draccus.parse(EvalPipelineConfig, args=[f"--env.type={loaded.env_type}", "--env.g=5.0", "--env.episode_length=7",
                                             "--policy.type=act"])
out["parsed"] = [isinstance(ev.env, loaded.config_class), ev.env.type == loaded.env_type, ev.env.g]
out["made_from_parsed"] = loaded.make(ev.env).spec.max_episode_steps
cfg = loaded.config
out["config"] = [isinstance(cfg, EnvConfig), type(cfg) is loaded.config_class, encode_config(cfg) == loaded.manifest.config]
print("RESULT " + json.dumps(out))
"""

#: A processor step of the env's own code (an identity on observations).
OWN_STEP = """from dataclasses import dataclass

from lerobot.processor.pipeline import ObservationProcessorStep


@dataclass
class Same(ObservationProcessorStep):
    def observation(self, observation):
        return observation

    def transform_features(self, features):
        return features
"""


def _run(ref: str, scenario: str, **load_kwargs) -> dict:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    argv = [sys.executable, "-c", SCRIPT, ref, scenario, json.dumps(load_kwargs)]
    done = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(next(line for line in done.stdout.splitlines() if line.startswith("RESULT "))[len("RESULT ") :])


@pytest.fixture(scope="module")
def cached(hub_module) -> str:
    """envs/pendulum (state observations) pushed, trusted, and loaded once in a process of its own (which runs and
    caches its checks): the ``user/name@<sha>`` of a user's second run."""
    sha = push_env(ROOT / "envs" / "pendulum", "alice/pendulum-first-step", episodes=1, progress=False).sha
    ref = f"alice/pendulum-first-step@{sha}"
    trust("alice/pendulum-first-step", sha)
    _run(ref, "first load")
    return ref


@pytest.mark.parametrize("scenario", ["parser first", "config first"])
def test_a_cached_env_steps_without_torch_or_lerobot_and_lerobot_still_finds_it(cached, scenario):
    out = _run(cached, scenario)
    assert out["heavy"] == [], out["checks"]  # the first step imported neither torch nor lerobot
    if scenario == "config first":
        assert out["config_first"] == ["PendulumEnvConfig", 10.0]  # the repo's config class, its published defaults
    assert out["parsed"] == [True, True, 5.0]  # LeRobot's parser knows --env.type=<choice> and the repo's own fields
    assert out["made_from_parsed"] == 7
    assert out["config"] == [True, True, True]  # the real EnvConfig, and what the manifest records


def test_a_choice_released_before_lerobot_is_imported_stays_unregistered(cached):
    out = _run(cached, "unregistered")
    assert out["heavy"] == [], out["checks"]
    assert out["choice_after_unregister"] is False
    assert out["parsed"] == [True, True, 5.0] and out["config"] == [True, True, True]


def test_a_verdict_an_isolated_load_cached_does_not_spare_an_in_process_load_its_config_check(hub_module):
    """An isolated load never runs the config's code here, so its cached verdict says nothing of the config: the next
    in-process load imports it and checks it against the manifest (LeRobot with it); the one after that may not."""
    sha = push_env(ROOT / "envs" / "pendulum", "alice/pendulum-after-isolated", episodes=1, progress=False).sha
    ref = f"alice/pendulum-after-isolated@{sha}"
    trust("alice/pendulum-after-isolated", sha)
    assert "cached" not in _run(ref, "load only", isolation="process")["checks"]  # ran the checks, cached their verdict
    first = _run(ref, "load only")
    assert "cached" in first["checks"] and first["heavy"] == ["lerobot", "torch"]  # the config checked here
    second = _run(ref, "load only")
    assert "cached" in second["checks"] and second["heavy"] == []


@pytest.fixture(scope="module")
def cached_reach(hub_module) -> str:
    """envs/reach (declares a LeRobot env processor, ``clip_action``) pushed, trusted, and loaded once in a process of
    its own (which runs its checks, the processors' dry run included, and caches their verdict)."""
    sha = push_env(ROOT / "envs" / "reach", "alice/reach-first-step", episodes=1, progress=False).sha
    ref = f"alice/reach-first-step@{sha}"
    trust("alice/reach-first-step", sha)
    first = _run(ref, "load only")
    assert "cached" not in first["checks"] and first["heavy"] == ["lerobot", "torch"]  # the processors built and dry-run
    return ref


def test_a_cached_env_with_processors_steps_without_torch_or_lerobot_and_builds_them_on_use(cached_reach):
    """The processors' check passed before for this commit with these packages: the verdict says so, and the first
    step needs neither torch nor LeRobot; the processors are built (with both) the moment something asks for them."""
    out = _run(cached_reach, "load only")
    assert "cached" in out["checks"] and out["heavy"] == [], out["checks"]
    used = _run(cached_reach, "processors on use")
    assert used["heavy"] == []
    assert used["processors"] == [[], ["ClipActionProcessorStep"]] and used["clipped"] == [1.0]  # reach's [-1, 1] bounds


def test_a_processors_check_that_failed_fails_again_though_the_other_checks_verdict_is_cached(hub_module, tmp_path):
    """A dry run that fails leaves a verdict of the feature and fingerprint checks (they passed), which does not say the
    processors passed: the next load runs them again and fails as loudly."""
    folder = tmp_path / "pendulum-bad-steps"
    shutil.copytree(ROOT / "envs" / "pendulum", folder, ignore=shutil.ignore_patterns("__pycache__"))
    with (folder / "pyproject.toml").open("a") as f:
        f.write('\n[[tool.hub-envs.processors]]\nname = "flat"\nentry_point = "flatten_state"\nstage = "pre"\n')
        f.write('kwargs = { keys = ["observation.nope"] }\n')
    sha = push_env(folder, "alice/pendulum-bad-steps", episodes=1, progress=False).sha  # push_env does no dry run
    verdicts = hub_envs_home() / check_cache.CACHE_DIR
    before = set(verdicts.glob("*.json"))
    for attempt in ("first", "second"):
        with pytest.raises(ProcessorError, match=r"processors\[0\] \('flat', stage pre\) failed on a live observation"):
            load_env(f"alice/pendulum-bad-steps@{sha}", trust_remote_code=True)
        assert len(set(verdicts.glob("*.json")) - before) == 1, attempt  # the feature and fingerprint checks' verdict


def test_an_isolated_load_refuses_processors_from_the_envs_own_code_though_they_passed_in_process(hub_module, tmp_path):
    """Processors from the env's own code would run in this process: an isolated load refuses them, also when an
    in-process load cached a verdict that they passed."""
    folder = tmp_path / "pendulum-own-steps"
    shutil.copytree(ROOT / "envs" / "pendulum", folder, ignore=shutil.ignore_patterns("__pycache__"))
    (folder / "own_steps.py").write_text(OWN_STEP)
    with (folder / "pyproject.toml").open("a") as f:
        f.write('\n[[tool.hub-envs.processors]]\nname = "same"\nentry_point = "own_steps:Same"\nstage = "pre"\n')
    sha = push_env(folder, "alice/pendulum-own-steps", episodes=1, progress=False).sha
    ref = f"alice/pendulum-own-steps@{sha}"
    assert [type(s).__name__ for s in load_env(ref, trust_remote_code=True).processors()[0].steps] == ["Same"]
    assert "cached" in load_env(ref, trust_remote_code=True).report.fingerprint
    with pytest.raises(IsolationUnavailableError, match=r"declares env processors from its own code \(same\)"):
        load_env(ref, trust_remote_code=True, isolation="process")


#: Repo ids on either side of huggingface_hub's rules (lengths, edges, '--', '..', '.git', characters).
REPO_IDS = [
    "user/name",
    "u/n",
    "user_/_name",
    "user/name.v2",
    "User-1/Name_2.x",
    "a" * 96 + "/name",
    "user/" + "b" * 96,
    "user/" + "b" * 97,
    "user/-name",
    "user/name-",
    "user/.name",
    "user/name.",
    "-user/name",
    "user./name",
    "user/na--me",
    "user/na..me",
    "user/name.git",
    "user/name.gi",
    "user/_",
    "user/-",
    "user/na_me",
    "user/nam e",
    "user/café",
    "user/name\n",
]


@pytest.mark.parametrize("repo_id", REPO_IDS)
def test_repo_ids_are_checked_by_huggingface_hubs_own_rules_without_importing_its_client(repo_id):
    from huggingface_hub.errors import HFValidationError
    from huggingface_hub.utils import validate_repo_id

    from hub_envs.repo.format import repo_id_problem

    try:
        validate_repo_id(repo_id)
        # what 0.35 lets through and 1.x refuses: a trailing newline (its pattern ends in $), non-ASCII letters (\w)
        hf_accepts = "\n" not in repo_id and repo_id.isascii()
    except HFValidationError:
        hf_accepts = False
    assert (repo_id_problem(repo_id) is None) == hf_accepts, repo_id_problem(repo_id)


def test_the_cache_folder_of_a_repo_is_the_one_huggingface_hub_names(tmp_path):
    from huggingface_hub.file_download import repo_folder_name

    from hub_envs.repo.hub_cache import cache_snapshots_dir

    folder = repo_folder_name(repo_id="alice/pendulum-first-step", repo_type="model")
    assert cache_snapshots_dir("alice/pendulum-first-step", tmp_path) == tmp_path / folder / "snapshots"
