"""Hub envs inside LeRobot: its own EnvHub loader, its draccus pipeline configs, its train and eval
scripts, and env processors between env and policy in its eval loop.

Real parts only: the loopback Hub server, huggingface_hub, LeRobot 0.4.4's make_env / parser /
lerobot_train.train / lerobot_eval.eval_main / rollout, gymnasium, draccus, torch on the CPU.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import draccus
import gymnasium as gym
import numpy as np
import pytest
import torch
from helpers import TINY, copy_env, republish
from lerobot.configs.eval import EvalPipelineConfig
from lerobot.configs.train import TrainPipelineConfig

from hub_envs import _compat, errors, load_env, push_env
from hub_envs.cli import main as cli_main
from hub_envs.envcode.registration import snapshot_registries
from hub_envs.errors import UnpinnedRevisionWarning
from hub_envs.lerobot.env import HubEnv, install_hooks, make_env, make_env_pre_post_processors
from hub_envs.testing import hub_environment

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = {"pendulum": ROOT / "envs" / "pendulum", "hover": ROOT / "envs" / "hover", "reach": ROOT / "envs" / "reach"}

#: A repo-local env processor step, shipped in the env folder next to the env's code.
OBS_STEPS = '''"""Env processor steps of this env (declared in pyproject.toml)."""
from dataclasses import dataclass

from lerobot.processor.pipeline import ObservationProcessorStep
from lerobot.utils.constants import OBS_STATE


@dataclass
class ScaleState(ObservationProcessorStep):
    factor: float = 1.0

    def observation(self, observation):
        out = dict(observation)
        out[OBS_STATE] = observation[OBS_STATE] * self.factor
        return out

    def transform_features(self, features):
        return features
'''

PROCESSORS_TOML = """
[[tool.hub-envs.processors]]
name = "scale_state"
entry_point = "obs_steps:ScaleState"
stage = "pre"
kwargs = { factor = 2.0 }

[[tool.hub-envs.processors]]
name = "clip"
entry_point = "clip_action"
stage = "post"
kwargs = { low = [-0.2], high = [0.2] }
"""

#: A tiny ACT: seconds on a CPU.
TINY_ACT = [
    "--policy.type=act",
    "--policy.push_to_hub=false",
    "--policy.device=cpu",
    "--policy.dim_model=32",
    "--policy.n_heads=2",
    "--policy.dim_feedforward=64",
    "--policy.n_encoder_layers=1",
    "--policy.n_decoder_layers=1",
    "--policy.chunk_size=10",
    "--policy.n_action_steps=10",
    "--policy.use_vae=false",
    "--policy.pretrained_backbone_weights=null",
]


#: lerobot-train's flag for in-training env evaluation (renamed in LeRobot 0.5).
EVAL_FREQ = _compat.train_eval_freq_flag()


def _pendulum_pixels(tmp_path: Path) -> Path:
    """envs/pendulum observing pixels too (LeRobot's ACT needs an image), with two env processors."""
    folder = copy_env(
        tmp_path,
        EXAMPLES["pendulum"],
        "pendulum_pixels",
        {
            "config.py": lambda s: s.replace('obs_type: str = "state"', 'obs_type: str = "pixels_agent_pos"'),
            "pyproject.toml": lambda s: s + PROCESSORS_TOML,
        },
    )
    (folder / "obs_steps.py").write_text(OBS_STEPS)
    return folder


@pytest.fixture(scope="module")
def published(hub_module, tmp_path_factory):
    """Every example env, the tiny env, and the processor-carrying pendulum variant, pushed once."""
    tmp = tmp_path_factory.mktemp("envs")
    shas = {"tiny": push_env(TINY, "alice/tiny", episodes=1, progress=False).sha}
    for name, folder in EXAMPLES.items():
        shas[name] = push_env(folder, f"alice/{name}", episodes=1, progress=False).sha
    shas["pendulum-pixels"] = push_env(_pendulum_pixels(tmp), "alice/pendulum-pixels", episodes=2, progress=False).sha
    return shas


@pytest.fixture(scope="module")
def one_step_checkpoint(hub_module, published, tmp_path_factory) -> Path:
    """``hub-envs train`` of a tiny ACT for one step on pendulum-pixels: its ``pretrained_model`` folder."""
    out = tmp_path_factory.mktemp("train") / "run"
    args = ["train", *_hub_args("pendulum-pixels", published["pendulum-pixels"]), *TINY_ACT, "--batch_size=4"]
    args += ["--num_workers=0", f"--{EVAL_FREQ}=0", "--steps=1", "--save_freq=1", f"--output_dir={out}"]
    assert cli_main(args) == 0
    return out / "checkpoints" / "last" / "pretrained_model"


def _hub_args(name: str, sha: str, *extra: str) -> list[str]:
    return ["--env.type=hub", f"--env.repo_id=alice/{name}", f"--env.revision={sha}", "--env.trust_remote_code=true", *extra]


# --- 1. LeRobot's own EnvHub loader ------------------------------------------------------------


def test_lerobot_make_env_loads_each_example_repo_pinned_to_its_sha(hub_module, published, tmp_path):
    from lerobot.envs.factory import make_env as lerobot_make_env
    from lerobot.envs.utils import check_env_attributes_and_types, preprocess_observation

    with hub_environment(hub_module.endpoint, tmp_path / "fresh_home"):  # nothing cached: env.py comes alone
        for name in ("tiny", *EXAMPLES):
            sha = published[name]
            envs = lerobot_make_env(f"alice/{name}@{sha}", n_envs=2, trust_remote_code=True)
            ((suite, tasks),) = envs.items()
            vec = tasks[0]
            assert isinstance(vec, gym.vector.SyncVectorEnv) and vec.num_envs == 2
            # env.py fetched the rest of its own commit (code, assets, manifest) into the same snapshot
            snapshot = tmp_path / "fresh_home" / "hub" / f"models--alice--{name}" / "snapshots" / sha
            manifest = json.loads((snapshot / "hub_env.json").read_text())
            code = [p for p in manifest["files"] if p.endswith(".py") or p.startswith("assets/")]
            assert len(code) >= 3 and all((snapshot / p).is_file() for p in code)
            assert not (snapshot / "dataset").exists()  # making envs does not need the dataset
            # what LeRobot's eval loop does with the first observation
            obs, _ = vec.reset(seed=[0, 1])
            with _no_warning():
                check_env_attributes_and_types(vec)
            batch = _add_envs_task(vec, preprocess_observation(obs))
            assert batch["task"] == [manifest["config"]["task"]] * 2
            features, features_map = manifest["config"]["features"], manifest["config"]["features_map"]
            expected = {features_map[k] for k in features if k != "action"}
            assert expected == set(batch) - {"task"}  # the keys the bundled dataset has
            assert tuple(batch["observation.state"].shape) == (2, *features["agent_pos"]["shape"])
            assert vec.call("_max_episode_steps") == (manifest["config"]["episode_length"],) * 2
            vec.step(np.stack([vec.single_action_space.sample() for _ in range(2)]))
            vec.close()
        # load_env on the same cache completes the partial snapshot env.py left (it has no dataset yet)
        loaded = load_env(f"alice/tiny@{published['tiny']}", trust_remote_code=True)
        assert loaded.open_dataset().num_episodes == 1


def _add_envs_task(vec, observation: dict) -> dict:
    """What LeRobot's eval loop adds to an observation batch: the envs' ``task_description`` (else ``task``).
    LeRobot 0.4 has it as ``lerobot.envs.utils.add_envs_task``; 0.5+ does it inline in ``rollout``."""
    try:
        observation["task"] = list(vec.call("task_description"))
    except (AttributeError, NotImplementedError):
        observation["task"] = list(vec.call("task"))
    return observation


class _no_warning:
    """Fail if LeRobot warns that the env lacks task / task_description."""

    def __enter__(self):
        import warnings

        self._cm = warnings.catch_warnings(record=True)
        self._rec = self._cm.__enter__()
        warnings.simplefilter("always")
        return self

    def __exit__(self, *exc):
        self._cm.__exit__(*exc)
        assert not [w for w in self._rec if "task_description" in str(w.message)]


def test_a_config_variant_publishes_from_the_same_folder_and_loads_everywhere(hub_module, tmp_path, capsys):
    """push_env --config.obs_type=pixels_agent_pos: pendulum's pixels variant, from the unedited folder."""
    from lerobot.envs.factory import make_env as lerobot_make_env

    folder = EXAMPLES["pendulum"]
    argv = ["push", f"--env_dir={folder}", "--repo_id=alice/pendulum-variant", "--episodes=2"]
    assert cli_main([*argv, "--config.obs_type=pixels_agent_pos", "--config.episode_length=40"]) == 0
    sha = hub_module.api.model_info("alice/pendulum-variant").sha
    loaded = load_env(f"alice/pendulum-variant@{sha}", trust_remote_code=True)
    try:
        assert loaded.manifest.config_overrides == {"episode_length": 40, "obs_type": "pixels_agent_pos"}
        assert loaded.config.obs_type == "pixels_agent_pos" and loaded.config.episode_length == 40
        assert "pixels" in loaded.config.features  # computed in __post_init__ from the field set at push
        assert loaded.manifest.dataset["features"]["observation.image"]["dtype"] == "video"  # a camera: video by default
        obs, _ = loaded.make().reset(seed=0)
        assert obs["pixels"].ndim == 3
    finally:
        loaded.unregister()
    card = Path(hub_module.api.hf_hub_download("alice/pendulum-variant", "README.md", revision=sha)).read_text()
    assert "`episode_length=40`, `obs_type=pixels_agent_pos`" in card
    with hub_environment(hub_module.endpoint, tmp_path / "fresh_home"):  # LeRobot's own loader, env.py alone
        vec = lerobot_make_env(f"alice/pendulum-variant@{sha}", n_envs=1, trust_remote_code=True)
        ((_, tasks),) = vec.items()
        obs, _ = tasks[0].reset(seed=[0])
        assert obs["pixels"].shape[0] == 1 and tasks[0].call("_max_episode_steps") == (40,)
    # the default variant from the same folder is still the state-only env; a field that does not exist is refused
    assert cli_main([*argv[:2], "--repo_id=alice/pendulum-default", "--episodes=1"]) == 0
    assert (
        "pixels"
        not in json.loads(Path(hub_module.api.hf_hub_download("alice/pendulum-default", "hub_env.json")).read_text())["config"][
            "features"
        ]
    )
    assert cli_main([*argv, "--config.no_such_field=1"]) == 1
    assert "has no field(s) ['no_such_field']" in capsys.readouterr().err


def test_lerobot_make_env_reports_success_through_final_info_and_refuses_without_trust(hub_module, published, tmp_path):
    from lerobot.envs.factory import make_env as lerobot_make_env

    with hub_environment(hub_module.endpoint, tmp_path / "home"):
        with pytest.raises(RuntimeError, match="Refusing to execute remote code"):
            lerobot_make_env(f"alice/tiny@{published['tiny']}", n_envs=1)
        assert not (tmp_path / "home" / "hub" / "models--alice--tiny").exists()  # nothing was even downloaded

        vec = lerobot_make_env(f"alice/tiny@{published['tiny']}", n_envs=2, trust_remote_code=True)["tiny-env"][0]
        vec.reset(seed=[0, 1])
        for t in range(30):
            _, _, terminated, truncated, info = vec.step(np.zeros((2, 1), dtype=np.float32))
            assert ("final_info" in info) == (t == 29)
        # LeRobot's rollout reads success from here (gymnasium 1.x, same-step autoreset)
        assert (
            truncated.all() and info["final_info"]["is_success"].dtype == bool and info["final_info"]["is_success"].shape == (2,)
        )
        vec.close()


# --- 2. hub envs in LeRobot's pipeline configs -------------------------------------------------


def test_lerobot_pipeline_configs_parse_the_hub_env_flags(published):
    sha = published["pendulum"]
    with pytest.warns(UnpinnedRevisionWarning, match=sha):
        cfg = draccus.parse(
            TrainPipelineConfig,
            args=[
                *_hub_args("pendulum", "main", "--env.overrides={g: 9.81}", "--env.episode_length=50"),
                "--dataset.repo_id=alice/pendulum",
                *TINY_ACT,
            ],
        )
    assert isinstance(cfg.env, HubEnv) and cfg.env.type == "hub"
    assert cfg.env.revision == sha  # a branch is replaced by the commit it resolved to
    assert cfg.env.episode_length == 50 and cfg.env.env_config.g == 9.81 and cfg.env.fps == 30
    assert cfg.env.features["agent_pos"].shape == (3,) and cfg.env.features_map["agent_pos"] == "observation.state"
    assert cfg.env.gym_kwargs["max_episode_steps"] == 50 and cfg.env.gym_kwargs["g"] == 9.81
    # what train_config.json holds decodes back to the same pinned env
    again = draccus.decode(TrainPipelineConfig, draccus.encode(cfg))
    assert again.env.revision == sha and again.env.episode_length == 50 and again.env.loaded is cfg.env.loaded

    # LeRobot's own make_env builds it from the gym registry, with the overridden time limit
    from lerobot.envs.factory import make_env as lerobot_make_env

    ((suite, tasks),) = lerobot_make_env(cfg.env, n_envs=1).items()
    vec = tasks[0]
    assert vec.call("_max_episode_steps") == (50,)
    vec.close()

    # the per-repo choice load_env registers, with the repo config's own fields as flags
    loaded = cfg.env.loaded
    ev = draccus.parse(
        EvalPipelineConfig,
        args=[
            f"--env.type={loaded.env_type}",
            "--env.g=5.0",
            "--env.episode_length=7",
            "--policy.type=act",
            "--eval.n_episodes=2",
            "--eval.batch_size=2",
        ],
    )
    assert isinstance(ev.env, loaded.config_class) and ev.env.g == 5.0
    vec = make_env(ev.env, n_envs=2)["pendulum"][0]
    assert vec.call("_max_episode_steps") == (7, 7) and vec.call("task_description") == ("Pendulum-v1",) * 2
    vec.close()

    with pytest.raises(draccus.utils.ParsingError) as info:
        draccus.parse(EvalPipelineConfig, args=["--env.type=hub", "--env.overrides={gravity: 3}"])
    assert "--env.repo_id" in str(info.value.__cause__)
    with pytest.raises(draccus.utils.ParsingError) as info:
        draccus.parse(EvalPipelineConfig, args=[*_hub_args("pendulum", sha), "--env.overrides={gravity: 3}"])
    assert isinstance(info.value.__cause__, errors.ConfigError) and "gravity" in str(info.value.__cause__)


def test_one_consent_flag_parses_with_either_env_choice(published):
    """``--env.trust_remote_code=true`` after ``--env.type=hub`` and after the per-repo choice ``user/name@<sha12>``
    alike, in lerobot-train's and lerobot-eval's configs (LeRobot's CLIs parse exactly these; before, the per-repo
    choice refused it: "The fields `trust_remote_code` are not valid for PendulumEnvConfig"). Never saved as true."""
    from hub_envs.lerobot.bridge import env_provenance

    sha = published["pendulum-pixels"]
    loaded = load_env(f"alice/pendulum-pixels@{sha}", trust_remote_code=True)  # what the plugin does first
    try:
        per_repo = [f"--env.type={loaded.env_type}", "--env.trust_remote_code=true"]
        for pipeline, extra in ((TrainPipelineConfig, ["--dataset.repo_id=alice/pendulum-pixels"]), (EvalPipelineConfig, [])):
            for env_flags in (_hub_args("pendulum-pixels", sha), per_repo):
                cfg = draccus.parse(pipeline, args=[*env_flags, *extra, *TINY_ACT])
                assert cfg.env.trust_remote_code is False and draccus.encode(cfg)["env"]["trust_remote_code"] is False
        assert isinstance(cfg.env, loaded.config_class) and cfg.env.type == loaded.env_type
        assert "trust_remote_code" not in env_provenance(cfg.env)["config"]  # not a value of the env's config
        assert make_env(cfg.env, n_envs=1)["pendulum"][0].num_envs == 1
    finally:
        loaded.unregister()


def test_hub_envs_cli_errors_are_one_clear_message(hub_module, published, capsys):
    assert cli_main(["eval", "--env.type=hub", "--policy.type=act"]) == 1
    assert "--env.repo_id=user/name" in capsys.readouterr().err
    assert cli_main(["eval", "--env.type=hub", "--env.repo_id=alice/tiny", f"--env.revision={published['tiny']}"]) == 1
    err = capsys.readouterr().err
    assert (
        "UntrustedCodeError" in err
        and "--env.trust_remote_code=true" in err
        and f"hub-envs trust alice/tiny@{published['tiny']}" in err
    )
    assert cli_main(["train", "--env.type=alice/tiny@0123456789ab", "--env.trust_remote_code=true"]) == 1
    assert "--env.revision=<the full 40-hex sha>" in capsys.readouterr().err


# --- 3. train then eval through LeRobot's own scripts -----------------------------------------


def _train_then_eval(
    out: Path, *, env_flags_train: list[str], env_flags_eval: list[str], train_eval: tuple[str, ...] = (f"--{EVAL_FREQ}=0",)
) -> dict:
    common = [*TINY_ACT, "--batch_size=4", "--num_workers=0", "--log_freq=100", *train_eval]
    assert cli_main(["train", *env_flags_train, *common, "--steps=3", "--save_freq=3", f"--output_dir={out / 'train'}"]) == 0
    model = out / "train" / "checkpoints" / "last" / "pretrained_model"
    assert (model / "model.safetensors").is_file() and (model / "hub_envs_provenance.json").is_file()
    assert (
        cli_main(
            [
                "eval",
                *env_flags_eval,
                f"--policy.path={model}",
                "--policy.device=cpu",
                "--eval.n_episodes=2",
                "--eval.batch_size=2",
                f"--output_dir={out / 'eval'}",
            ]
        )
        == 0
    )
    info = json.loads((out / "eval" / "eval_info.json").read_text())
    sidecar = json.loads((out / "eval" / "hub_envs_provenance.json").read_text())
    assert info["provenance"] == sidecar
    assert info["overall"]["n_episodes"] == 2 and np.isfinite(info["overall"]["avg_sum_reward"])
    return info


def test_train_then_eval_pendulum_through_lerobot_with_provenance(hub_module, published, tmp_path):
    sha = published["pendulum-pixels"]
    loaded = load_env(f"alice/pendulum-pixels@{sha}", trust_remote_code=True)
    # train: no --dataset flag = the env repo's bundled random-action dataset, and LeRobot's in-training
    # eval (lerobot_train makes its env without trust_remote_code); eval: 30-step episodes
    info = _train_then_eval(
        tmp_path,
        env_flags_train=_hub_args("pendulum-pixels", sha, "--env.episode_length=10"),
        env_flags_eval=_hub_args("pendulum-pixels", sha, "--env.episode_length=30"),
        train_eval=(f"--{EVAL_FREQ}=3", "--eval.n_episodes=1", "--eval.batch_size=1"),
    )
    assert (tmp_path / "train" / "eval" / "videos_step_000003" / "pendulum_0" / "eval_episode_0.mp4").is_file()
    prov = info["provenance"]
    assert prov["env"]["repo_id"] == "alice/pendulum-pixels" and prov["env"]["revision"] == sha
    assert prov["env"]["config"]["episode_length"] == 30
    assert prov["env"]["dataset_fingerprint"] == loaded.manifest.dataset["fingerprint"]
    assert [p["name"] for p in prov["env"]["processors"]] == ["scale_state", "clip"]
    training = prov["policy"]["training"]
    assert training["env"]["revision"] == sha and training["steps"] == 3
    assert training["dataset"]["fingerprint"] == loaded.manifest.dataset["fingerprint"] and training["dataset"]["is_env_dataset"]
    assert prov["versions"]["lerobot"] == str(_compat.LEROBOT_VERSION) and prov["versions"]["hub-envs"]
    assert info["per_group"]["pendulum"]["n_episodes"] == 2
    # the commands as another machine runs them: the env by repo id and sha, no path into this machine's snapshot
    for command in (training["command"], prov["command"]):
        assert not [a for a in command if str(loaded.path) in a], command
        assert "--env.repo_id=alice/pendulum-pixels" in command and f"--env.revision={sha}" in command


def test_train_then_eval_reach_with_images_and_its_action_clip(hub_module, published, tmp_path):
    sha = published["reach"]
    loaded = load_env(f"alice/reach@{sha}", trust_remote_code=True)
    # the per-repo choice (short sha) for training, the generic one for eval
    info = _train_then_eval(
        tmp_path,
        env_flags_train=[f"--env.type={loaded.env_type}", "--env.trust_remote_code=true"],
        env_flags_eval=_hub_args("reach", sha, "--env.episode_length=15"),
    )
    prov = info["provenance"]
    assert prov["env"]["revision"] == sha and prov["env"]["processors"] == [
        {"name": "clip_action", "entry_point": "clip_action", "stage": "post", "kwargs": {}}
    ]
    assert prov["env"]["config"]["features"]["pixels"]["shape"] == [96, 96, 3]
    assert prov["policy"]["training"]["dataset"]["is_env_dataset"]
    # trained with the per-repo choice (a short sha): the command records the commit in full, no snapshot path
    command = prov["policy"]["training"]["command"]
    assert command[:3] == ["hub-envs", "train", f"--env.type={loaded.env_type}"] and command[-1] == f"--env.revision={sha}"
    assert not [a for a in command if str(loaded.path) in a], command


@pytest.mark.parametrize("route", ["--env.discover_packages_path", "the lerobot_env_hub plugin"])
def test_lerobots_own_eval_cli_evaluates_a_hub_env(hub_module, published, one_step_checkpoint, tmp_path, route):
    """LeRobot's unmodified ``lerobot-eval`` console script, in a fresh process: with LeRobot's plugin flag on
    every version, and with no flag at all from LeRobot 0.5 on (it imports ``lerobot_env_*`` distributions)."""
    plain = route == "the lerobot_env_hub plugin"
    if plain and not _compat.env_configs_create_envs():
        pytest.skip(
            f"LeRobot {_compat.LEROBOT_VERSION} does not discover lerobot_env_* plugins (0.5 does); "
            "on 0.4 the --env.discover_packages_path route is the one"
        )
    sha = published["pendulum-pixels"]
    flags = [] if plain else ["--env.discover_packages_path=hub_envs.lerobot_plugin"]
    cmd = [
        str(Path(sys.executable).with_name("lerobot-eval")),
        *flags,
        *_hub_args("pendulum-pixels", sha, "--env.episode_length=8"),
        f"--policy.path={one_step_checkpoint}",
        "--policy.device=cpu",
        "--eval.n_episodes=2",
        "--eval.batch_size=2",
        f"--output_dir={tmp_path / 'eval'}",
    ]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-4000:]
    info = json.loads((tmp_path / "eval" / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 2 and "pendulum" in info["per_group"]


def _results_only(info):
    """LeRobot's eval_info without what differs between identical runs (timings, video paths)."""
    if isinstance(info, dict):
        return {k: _results_only(v) for k, v in info.items() if k not in ("eval_s", "eval_ep_s") and "video" not in k}
    if isinstance(info, list):
        return [_results_only(v) for v in info]
    return info


def test_hub_envs_eval_of_a_policy_on_an_isolated_env_matches_in_process(hub_module, published, one_step_checkpoint, tmp_path):
    """``hub-envs eval`` with ``--env.isolation=process`` and config fields set (the env's code and its config
    class run in workers only): the same per-episode results as the env evaluated in this process."""
    # pendulum with the pixels variant's fields: the checkpoint's features, without the variant's own processors
    env = _hub_args("pendulum", published["pendulum"], "--env.overrides={obs_type: pixels_agent_pos}", "--env.episode_length=6")
    runs = {}
    for isolation in ("none", "process"):
        out = tmp_path / isolation
        args = ["eval", *env, f"--env.isolation={isolation}", f"--policy.path={one_step_checkpoint}", "--policy.device=cpu"]
        assert cli_main([*args, "--eval.n_episodes=2", "--eval.batch_size=2", "--seed=3", f"--output_dir={out}"]) == 0
        runs[isolation] = json.loads((out / "eval_info.json").read_text())
    results = {k: _results_only({n: v[n] for n in ("per_task", "per_group", "overall") if n in v}) for k, v in runs.items()}
    assert results["process"] == results["none"] and runs["none"]["overall"]["n_episodes"] == 2
    assert runs["process"]["provenance"]["env"]["config"]["episode_length"] == 6


def test_consent_is_never_read_from_or_saved_into_a_config_file(hub_module, published, one_step_checkpoint, tmp_path):
    """A shared train_config.json cannot carry consent: it is saved as false, and a file saying true is ignored."""
    sha = published["pendulum-pixels"]
    saved = json.loads((one_step_checkpoint / "train_config.json").read_text())
    assert saved["env"]["trust_remote_code"] is False and saved["env"]["revision"] == sha
    saved["env"]["trust_remote_code"] = True  # what someone else's config file says
    saved["output_dir"] = str(tmp_path / "again")
    shared = tmp_path / "shared.json"
    shared.write_text(json.dumps(saved))
    # a fresh process: nothing of this repo was imported there, and its trust list is empty
    run = subprocess.run(
        [sys.executable, "-m", "hub_envs.cli", "train", f"--config_path={shared}"], capture_output=True, text=True, timeout=600
    )
    assert run.returncode == 1, run.stdout[-2000:] + run.stderr[-3000:]
    # LeRobot's parser reports it (draccus wraps errors raised while it builds a config): hub-envs' message inside
    assert f"alice/pendulum-pixels@{sha} contains Python code that would run" in run.stderr
    assert "nothing was imported" in run.stderr and "--env.trust_remote_code=true" in run.stderr
    assert not (tmp_path / "again").exists()


# --- 4. env processors ------------------------------------------------------------------------


def test_a_processor_declared_by_the_repo_is_applied_between_env_and_policy(published):
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.policies.factory import make_policy, make_pre_post_processors
    from lerobot.scripts.lerobot_eval import rollout
    from lerobot.utils.constants import OBS_STATE

    sha = published["pendulum-pixels"]
    cfg = draccus.parse(
        EvalPipelineConfig,
        args=[*_hub_args("pendulum-pixels", sha, "--env.episode_length=12"), "--eval.n_episodes=2", "--eval.batch_size=2"],
    )
    loaded = cfg.env.loaded
    pre, post = loaded.processors()
    assert [type(s).__name__ for s in pre.steps] == ["ScaleState"] and [type(s).__name__ for s in post.steps] == [
        "ClipActionProcessorStep"
    ]
    card = (loaded.path / "README.md").read_text()
    assert "## Env processors" in card and "| `clip` | post | `clip_action` |" in card  # the card tells users too

    torch.manual_seed(0)
    policy_cfg = ACTConfig(
        device="cpu",
        dim_model=32,
        n_heads=2,
        dim_feedforward=64,
        n_encoder_layers=1,
        n_decoder_layers=1,
        chunk_size=4,
        n_action_steps=4,
        use_vae=False,
        pretrained_backbone_weights=None,
    )
    policy = make_policy(policy_cfg, env_cfg=cfg.env)
    preprocessor, postprocessor = make_pre_post_processors(policy_cfg, dataset_stats=loaded.open_dataset().meta.stats)
    seen, policy_actions = [], []
    preprocessor.register_before_step_hook(lambda i, transition: seen.append(transition) if i == 0 else None)
    last = len(postprocessor.steps) - 1
    postprocessor.register_after_step_hook(lambda i, tr: policy_actions.append(tr["action"].clone()) if i == last else None)
    env_pre, env_post = make_env_pre_post_processors(cfg.env, policy_cfg)  # what lerobot_eval gets once hooked
    vec = make_env(cfg.env, n_envs=2)["pendulum"][0]
    out = rollout(vec, policy, env_pre, env_post, preprocessor, postprocessor, seeds=[3, 4])
    vec.close()

    # the policy's first input is the env's first observation, scaled by the repo's ScaleState(factor=2)
    first_state = seen[0]["observation"][OBS_STATE]
    for row, seed in enumerate((3, 4)):
        raw, _ = loaded.make().reset(seed=seed)
        np.testing.assert_allclose(first_state[row].numpy(), 2.0 * raw["agent_pos"], rtol=1e-6)
    # and every action the policy chose reached the env clipped to the repo's [-0.2, 0.2]
    chosen = torch.stack(policy_actions, dim=1)
    assert out["action"].shape == chosen.shape == (2, 12, 1)
    assert float(chosen.abs().max()) > 0.2  # so the clip did something
    torch.testing.assert_close(out["action"], chosen.clamp(-0.2, 0.2))


def test_install_hooks_route_lerobot_scripts_and_leave_other_envs_alone():
    from lerobot.envs import factory
    from lerobot.envs.configs import PushtEnv
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.scripts import lerobot_eval, lerobot_train

    install_hooks()
    assert lerobot_eval.make_env is make_env and lerobot_train.make_env_pre_post_processors is make_env_pre_post_processors
    pre, post = make_env_pre_post_processors(PushtEnv(), ACTConfig())
    ref_pre, ref_post = factory.make_env_pre_post_processors(PushtEnv(), ACTConfig())
    assert [type(s) for s in pre.steps] == [type(s) for s in ref_pre.steps] == []


def test_a_malformed_processor_declaration_is_a_clear_error(hub_module, tmp_path):
    cases = {
        'name = "c"\nentry_point = "clip_action"\nstage = "middle"': r"processors\[0\]\.stage = 'middle' must be \"pre\"",
        'name = "c"\nentry_point = "clip_action"': r"processors\[0\]\.stage is missing",
        'entry_point = "clip_action"\nstage = "post"': r"processors\[0\]\.name is missing",
        'name = "c"\nentry_point = "no_such_step"\nstage = "post"': r"processors\[0\]\.entry_point 'no_such_step' is not a built-in",
        'name = "c"\nentry_point = "clip_action"\nstage = "pre"': r"processors\[0\]\.stage is \"pre\" but ClipActionProcessorStep processes actions",
        'name = "c"\nentry_point = "clip_action"\nstage = "post"\nkwargs = { lo = 1 }': r"processors\[0\]\.kwargs \{'lo': 1\} do not fit ClipActionProcessorStep",
        'name = "c"\nentry_point = "flatten_state"\nstage = "pre"\nkwargs = { keys = ["observation.nope"] }': r"processors\[0\] \('c', stage pre\) failed on a live observation: KeyError",
        'name = "c"\nentry_point = "clip_action"\nstage = "post"\ncolor = "red"': r"processors\[0\]: unknown field\(s\) \['color'\]",
    }
    for i, (decl, message) in enumerate(cases.items()):
        folder = copy_env(
            tmp_path, TINY, f"bad{i}", {"pyproject.toml": lambda s, d=decl: s + f"\n[[tool.hub-envs.processors]]\n{d}\n"}
        )
        before = snapshot_registries()
        with pytest.raises(errors.ProcessorError, match=message) as info:
            if "live observation" in message:
                load_env(str(folder))  # the dry run needs check=True; push_env builds with check=False
            else:
                push_env(folder, f"alice/bad{i}", episodes=1, progress=False)
        assert "[tool.hub-envs]" in str(info.value)
        assert snapshot_registries() == before

    # a published manifest edited by hand is refused at load, naming hub_env.json and the field
    push_env(TINY, "alice/tiny-proc", episodes=1, progress=False)

    def bad_manifest(folder: Path):
        manifest = json.loads((folder / "hub_env.json").read_text())
        manifest["processors"] = [{"name": "clip", "entry_point": "clip_action", "stage": "post", "kwargs": [1, 2]}]
        (folder / "hub_env.json").write_text(json.dumps(manifest))

    sha = republish(hub_module.api, "alice/tiny-proc", bad_manifest)
    before = snapshot_registries()
    with pytest.raises(
        errors.ProcessorError, match=rf"alice/tiny-proc@{sha}: hub_env.json processors\[0\]\.kwargs must be a table"
    ):
        load_env(f"alice/tiny-proc@{sha}", trust_remote_code=True)
    assert snapshot_registries() == before


def test_declared_steps_can_be_builtins_or_lerobot_registry_steps():
    from lerobot.envs.utils import preprocess_observation

    from hub_envs.loading.processors import build_pipelines, parse_declarations

    specs = parse_declarations(
        [
            {
                "name": "flatten",
                "entry_point": "flatten_state",
                "stage": "pre",
                "kwargs": {"keys": ["observation.robot_state", "observation.state"]},
            },
            {"name": "resize", "entry_point": "image_crop_resize_processor", "stage": "pre", "kwargs": {"resize_size": [16, 16]}},
        ],
        where="hub_env.json",
    )
    pre, post = build_pipelines(specs)
    assert not post.steps
    rng = np.random.default_rng(0)
    env_obs = {  # a batch of 2, as a vector env returns it
        "robot_state": {"eef": {"pos": rng.random((2, 3)), "quat": rng.random((2, 4))}, "gripper": {"qpos": rng.random((2, 2))}},
        "agent_pos": rng.random((2, 1)).astype(np.float32),
        "pixels": rng.integers(0, 255, (2, 32, 32, 3), dtype=np.uint8),
    }
    out = pre(preprocess_observation(env_obs))
    expected = np.concatenate(
        [
            env_obs["robot_state"]["eef"]["pos"],
            env_obs["robot_state"]["eef"]["quat"],
            env_obs["robot_state"]["gripper"]["qpos"],
            env_obs["agent_pos"],
        ],
        axis=1,
    )
    np.testing.assert_allclose(out["observation.state"].numpy(), expected, rtol=1e-6)
    assert "observation.robot_state" not in out
    assert tuple(out["observation.image"].shape) == (2, 3, 16, 16)
