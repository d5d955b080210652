"""The three example envs (envs/pendulum, envs/hover, envs/reach) honour the local env folder contract.

Each env is loaded the way hub-envs loads it: the folder imported as a synthetic package by
``import_env_folder`` (so the env's relative imports run), the entry points from its
``pyproject.toml`` resolved by ``resolve_entry_point``, and the env built as
``EnvClass(**cfg.gym_kwargs)``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import inspect
import json
import shutil
import subprocess
import sys
import tomllib
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pybullet as p
import pytest
from gymnasium.envs.registration import EnvSpec
from gymnasium.utils.env_checker import check_env
from lerobot.configs.types import FeatureType
from lerobot.envs.configs import EnvConfig
from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_IMAGE, OBS_STATE

from hub_envs.envcode.importing import import_env_folder, resolve_entry_point

ENVS_DIR = Path(__file__).resolve().parents[1] / "envs"
NAMES = ("pendulum", "hover", "reach")

# every configuration of every env, with the observation shapes each must have (written out here,
# not computed by the env's code: hover's agent_pos is 12 + (fps // 2) * A)
CONFIGS = {
    "pendulum-state": ("pendulum", {"obs_type": "state"}, {"agent_pos": (3,)}, (1,)),
    "pendulum-pixels": ("pendulum", {"obs_type": "pixels_agent_pos"}, {"agent_pos": (3,), "pixels": (64, 64, 3)}, (1,)),
    "hover-one_d_rpm-30": ("hover", {"act_type": "one_d_rpm", "fps": 30}, {"agent_pos": (27,)}, (1,)),
    "hover-one_d_rpm-48": ("hover", {"act_type": "one_d_rpm", "fps": 48}, {"agent_pos": (36,)}, (1,)),
    "hover-rpm-30": ("hover", {"act_type": "rpm", "fps": 30}, {"agent_pos": (72,)}, (4,)),
    "hover-rpm-48": ("hover", {"act_type": "rpm", "fps": 48}, {"agent_pos": (108,)}, (4,)),
    "reach-pixels": ("reach", {}, {"agent_pos": (14,), "pixels": (96, 96, 3)}, (7,)),
    "reach-env_state": (
        "reach",
        {"obs_type": "environment_state_agent_pos"},
        {"agent_pos": (14,), "environment_state": (3,)},
        (7,),
    ),
}
LEROBOT_KEY = {"agent_pos": OBS_STATE, "pixels": OBS_IMAGE, "environment_state": OBS_ENV_STATE}


def manifest(name: str) -> dict:
    return tomllib.loads((ENVS_DIR / name / "pyproject.toml").read_text())


def load(name: str):
    """(env class, config class, package) of ``envs/<name>``, imported as hub-envs imports it."""
    tool = manifest(name)["tool"]["hub-envs"]
    pkg = import_env_folder(ENVS_DIR / name, key=f"test-example-{name}")
    return resolve_entry_point(pkg, tool["env"]), resolve_entry_point(pkg, tool["config"]), pkg


def make(config_id: str):
    name, overrides, _, _ = CONFIGS[config_id]
    env_cls, cfg_cls, _ = load(name)
    cfg = cfg_cls(**overrides)
    return env_cls(**cfg.gym_kwargs), cfg


def actions_for(env, seed: int, n: int) -> list[np.ndarray]:
    env.action_space.seed(seed)
    return [env.action_space.sample() for _ in range(n)]


def rollout(env, seed: int, actions) -> list:
    """(obs, reward, terminated, truncated, info) per step; a finished episode is reset without a seed."""
    obs, info = env.reset(seed=seed)
    out = [(obs, 0.0, False, False, info)]
    for a in actions:
        obs, reward, terminated, truncated, info = env.step(a)
        out.append((obs, reward, terminated, truncated, info))
        if terminated or truncated:
            obs, info = env.reset()
            out.append((obs, 0.0, False, False, info))
    return out


def assert_same_steps(a: list, b: list) -> None:
    assert len(a) == len(b)
    for t, (x, y) in enumerate(zip(a, b, strict=True)):
        assert x[0].keys() == y[0].keys()
        for key in x[0]:
            assert x[0][key].dtype == y[0][key].dtype
            assert np.array_equal(x[0][key], y[0][key]), f"step {t}: {key} differs"
        assert x[1:4] == y[1:4], f"step {t}: reward/terminated/truncated differ: {x[1:4]} vs {y[1:4]}"
        assert x[4] == y[4], f"step {t}: info differs"


def digest(steps: list) -> str:
    h = hashlib.sha256()
    for obs, reward, terminated, truncated, info in steps:
        for key in sorted(obs):
            h.update(key.encode() + np.ascontiguousarray(obs[key]).tobytes())
        h.update(np.float64(reward).tobytes() + bytes([terminated, truncated, info["is_success"]]))
    return h.hexdigest()


@pytest.fixture
def closing():
    envs = []
    yield envs.append
    for env in envs:
        env.close()


# --- the folder format ------------------------------------------------------------------------------


@pytest.mark.parametrize("name", NAMES)
def test_folder_follows_the_local_env_format(name):
    folder = ENVS_DIR / name
    project = manifest(name)["project"]
    assert project["name"] and project["version"] and project["description"]
    assert any(dep.startswith("gymnasium") for dep in project["dependencies"])
    if name != "pendulum":
        assert any(dep.startswith("pybullet") for dep in project["dependencies"])
    assert not (folder / "env.py").exists(), "env.py is reserved for hub-envs' generated entry point"
    assert not (folder / "__init__.py").exists()

    env_cls, cfg_cls, pkg = load(name)
    assert issubclass(env_cls, gym.Env)
    assert env_cls.__module__.startswith(pkg.__name__ + ".")  # imported inside the synthetic package
    assert dataclasses.is_dataclass(cfg_cls) and issubclass(cfg_cls, EnvConfig)
    assert cfg_cls not in EnvConfig.get_known_choices().values(), "hub-envs registers the config, not the env"
    fields = {f.name: f for f in dataclasses.fields(cfg_cls)}
    assert {"task", "fps", "episode_length", "features", "features_map"} <= set(fields)
    cfg = cfg_cls()
    assert isinstance(cfg.episode_length, int) and cfg.episode_length > 0
    assert isinstance(cfg.task, str) and isinstance(cfg.fps, int)
    assert "max_episode_steps" not in cfg.gym_kwargs
    json.dumps(cfg.gym_kwargs)  # plain values, serialisable into a manifest


# --- spaces and features ----------------------------------------------------------------------------


@pytest.mark.parametrize("config_id", list(CONFIGS))
def test_observations_and_actions_match_the_config_features(config_id, closing):
    _, _, expected_obs, expected_action = CONFIGS[config_id]
    env, cfg = make(config_id)
    closing(env)

    assert set(cfg.features) == {ACTION, *expected_obs}
    assert cfg.features[ACTION].type is FeatureType.ACTION and cfg.features[ACTION].shape == expected_action
    assert cfg.features_map[ACTION] == ACTION
    for key, shape in expected_obs.items():
        feature = cfg.features[key]
        assert feature.shape == shape
        assert (
            feature.type
            is {"agent_pos": FeatureType.STATE, "pixels": FeatureType.VISUAL, "environment_state": FeatureType.ENV}[key]
        )
        assert cfg.features_map[key] == LEROBOT_KEY[key]

    assert isinstance(env.observation_space, gym.spaces.Dict)
    assert set(env.observation_space.spaces) == set(expected_obs)
    for key, shape in expected_obs.items():
        space = env.observation_space[key]
        assert space.shape == shape
        assert space.dtype == (np.uint8 if key == "pixels" else np.float32)
    assert env.action_space.shape == expected_action and env.action_space.dtype == np.float32
    assert np.all(env.action_space.low == -1) and np.all(env.action_space.high == 1)
    assert env.metadata["render_fps"] == cfg.fps and env.metadata["render_modes"] == ["rgb_array"]

    obs, info = env.reset(seed=0)
    assert type(info["is_success"]) is bool
    for a in actions_for(env, 0, 5):
        assert obs in env.observation_space
        for key, shape in expected_obs.items():
            assert obs[key].shape == shape and obs[key].dtype == env.observation_space[key].dtype
        obs, reward, terminated, truncated, info = env.step(a)
        assert type(info["is_success"]) is bool and type(terminated) is bool and type(truncated) is bool
        assert isinstance(reward, float)
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    assert frame.min() < frame.max(), "the frame is blank"
    if "pixels" in obs:
        assert np.array_equal(obs["pixels"], frame)


@pytest.mark.parametrize("config_id", list(CONFIGS))
def test_gymnasium_check_env_passes_without_warnings(config_id):
    name, overrides, _, _ = CONFIGS[config_id]
    env_cls, cfg_cls, _ = load(name)
    cfg = cfg_cls(**overrides)
    # through an EnvSpec so that check_env also makes fresh envs for its render and close checks
    spec = EnvSpec(id=f"hub_envs_test/{name.capitalize()}-v0", entry_point=env_cls, kwargs=cfg.gym_kwargs)
    env = gym.make(spec)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            check_env(env.unwrapped)
        assert [str(w.message) for w in caught] == []
    finally:
        env.close()


# --- determinism --------------------------------------------------------------------------------------


@pytest.mark.parametrize("config_id", list(CONFIGS))
def test_same_seed_same_rollout_and_different_seed_different(config_id, closing):
    env, _ = make(config_id)
    other, _ = make(config_id)
    closing(env)
    closing(other)
    actions = actions_for(env, 11, 50)

    first = rollout(env, 3, actions)
    rollout(env, 4, actions_for(env, 12, 20))  # something else in between
    assert_same_steps(first, rollout(env, 3, actions))
    assert_same_steps(first, rollout(other, 3, actions))  # and in another instance
    assert digest(rollout(env, 5, actions)) != digest(first)


def load_env_class(name: str):
    return resolve_entry_point(
        import_env_folder(ENVS_DIR / name, key=f"test-example-{name}"), manifest(name)["tool"]["hub-envs"]["env"]
    )


def test_same_seed_same_rollout_in_a_new_process():
    """Bit-identical across processes. The child runs this file's own rollout code, without lerobot (10 s to import)."""
    config_ids = ("pendulum-pixels", "hover-rpm-30", "reach-pixels")
    jobs = {}
    for config_id in config_ids:
        env, cfg = make(config_id)
        jobs[config_id] = (CONFIGS[config_id][0], cfg.gym_kwargs)
        env.close()
    script = "\n".join(
        [
            "import hashlib, json, sys, tomllib",
            "from pathlib import Path",
            "import numpy as np",
            "from hub_envs.envcode.importing import import_env_folder, resolve_entry_point",
            f"ENVS_DIR = Path({str(ENVS_DIR)!r})",
            *(inspect.getsource(f) for f in (manifest, load_env_class, actions_for, rollout, digest)),
            "for config_id, (name, kwargs) in json.loads(sys.argv[1]).items():",
            "    env = load_env_class(name)(**kwargs)",
            "    print(config_id, digest(rollout(env, 7, actions_for(env, 7, 50))))",
            "    env.close()",
        ]
    )
    result = subprocess.run([sys.executable, "-c", script, json.dumps(jobs)], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "lerobot" not in script
    lines = [line.split() for line in result.stdout.splitlines() if line.split() and line.split()[0] in CONFIGS]
    assert [line[0] for line in lines] == list(config_ids), result.stdout + result.stderr
    for config_id, theirs in lines:
        env, _ = make(config_id)
        try:
            assert digest(rollout(env, 7, actions_for(env, 7, 50))) == theirs, config_id
        finally:
            env.close()


# --- get_state / reset_to ----------------------------------------------------------------------------


def record(env, seed: int, actions) -> tuple[list, list]:
    """States before each action and the step results, without resets (the env may run past its end)."""
    env.reset(seed=seed)
    states, steps = [], []
    for a in actions:
        states.append(env.get_state())
        steps.append(env.step(a))
    return states, steps


def replay_from(env, state, actions) -> list:
    env.reset_to(state)
    return [env.step(a) for a in actions]


@pytest.mark.parametrize("config_id", list(CONFIGS))
def test_reset_to_a_mid_episode_state_replays_bit_identically(config_id, closing):
    env, _ = make(config_id)
    fresh, _ = make(config_id)
    closing(env)
    closing(fresh)
    actions = actions_for(env, 21, 40)
    states, steps = record(env, 21, actions)
    final_state = env.get_state()
    k = 15

    state = states[k]
    assert state.dtype == np.float64 and state.ndim == 1
    obs_k = env.reset_to(state)
    assert obs_k.keys() == steps[k - 1][0].keys()
    for key in obs_k:  # reset_to returns the observation that was seen at that state
        assert np.array_equal(obs_k[key], steps[k - 1][0][key]), key
    assert np.array_equal(env.get_state(), state)

    for target in (env, fresh):  # the same env after running on, and a new one (its own pybullet client)
        assert_same_steps(replay_from(target, state, actions[k:]), steps[k:])
        assert np.array_equal(target.get_state(), final_state)


@pytest.mark.parametrize("config_id", ["hover-one_d_rpm-30", "hover-rpm-30"])
def test_hover_reset_to_is_exact_on_the_ground(config_id, closing):
    """Contact with the ground leaves state inside pybullet (contact points, impulses); the env drops it every step."""
    env, _ = make(config_id)
    closing(env)
    actions = [a - 0.8 for a in actions_for(env, 1, 100)]  # mostly below hover thrust: the drone lands
    states, steps = record(env, 1, actions)
    for k in (40, 60, 80):
        assert states[k][2] < 0.03, "the drone should be on the ground here"
        env.reset_to(states[k])
        assert p.getClosestPoints(env._drone, env._plane, 0.001, physicsClientId=env._client)
        assert_same_steps(replay_from(env, states[k], actions[k:]), steps[k:])


def test_reach_reset_to_is_exact_with_the_arm_on_the_floor(closing):
    env, _ = make("reach-env_state")
    closing(env)
    actions = [np.array([0, 1, 0, 0.8, 0, 1, 0], dtype=np.float32)] * 60  # bend down into the floor
    states, steps = record(env, 2, actions)
    k = 45
    env.reset_to(states[k])
    assert p.getClosestPoints(env.arm.body, env._plane, 0.001, physicsClientId=env._client), "the arm should touch the floor here"
    replayed = replay_from(env, states[k], actions[k:])
    assert_same_steps(replayed, steps[k:])


def test_reset_to_rejects_a_state_of_the_wrong_size(closing):
    for config_id in ("pendulum-state", "hover-one_d_rpm-30", "reach-env_state"):
        env, _ = make(config_id)
        closing(env)
        env.reset(seed=0)
        with pytest.raises(ValueError, match="state of shape"):
            env.reset_to(np.zeros(len(env.get_state()) + 1))


# --- configuration errors -----------------------------------------------------------------------------


def test_unsupported_hover_act_type_is_a_clear_error():
    env_cls, cfg_cls, _ = load("hover")
    for build in (lambda: cfg_cls(act_type="pid"), lambda: env_cls(act_type="pid")):
        with pytest.raises(ValueError) as err:
            build()
        message = str(err.value)
        assert "act_type" in message and "'pid'" in message and "one_d_rpm" in message and "'rpm'" in message
    with pytest.raises(ValueError, match="fps"):
        cfg_cls(fps=7)  # the physics runs at 240 Hz


def test_unsupported_obs_types_are_clear_errors():
    for name in ("pendulum", "reach"):
        env_cls, cfg_cls, _ = load(name)
        with pytest.raises(ValueError, match="obs_type='pixels_only'"):
            cfg_cls(obs_type="pixels_only")
        with pytest.raises(ValueError, match="obs_type"):
            env_cls(obs_type="pixels_only")


# --- pendulum -----------------------------------------------------------------------------------------


def test_pendulum_is_gymnasiums_pendulum_v1(closing):
    from gymnasium.envs.classic_control.pendulum import PendulumEnv as GymPendulum

    env, _ = make("pendulum-state")
    ref = GymPendulum()
    closing(env)
    closing(ref)
    obs, _ = env.reset(seed=42)
    ref_obs, _ = ref.reset(seed=42)
    assert np.array_equal(obs["agent_pos"], ref_obs)
    for a in actions_for(env, 42, 100):
        obs, reward, *_ = env.step(a)
        ref_obs, ref_reward, *_ = ref.step(2.0 * a)  # our [-1, 1] is Pendulum-v1's [-2, 2] N m
        assert np.array_equal(obs["agent_pos"], ref_obs)
        assert reward == ref_reward


def test_pendulum_success_means_upright_and_still(closing):
    env, _ = make("pendulum-pixels")
    closing(env)
    env.reset(seed=0)
    zero = np.zeros(1, dtype=np.float32)
    cases = {(0.0, 0.0): True, (2 * np.pi + 0.05, 0.2): True, (0.3, 0.0): False, (0.0, 1.5): False, (np.pi, 0.0): False}
    for (theta, theta_dot), upright in cases.items():
        env.reset_to(np.array([theta, theta_dot]))
        _, reward, _, _, info = env.step(zero)
        assert info["is_success"] is upright, (theta, theta_dot)
        if upright:
            assert reward > -0.1
    # the picture follows the angle: the red rod is above the centre when upright, below when hanging
    height = env.observation_space["pixels"].shape[0]
    for theta, rod_above in ((0.0, True), (np.pi, False)):
        frame = env.reset_to(np.array([theta, 0.0]))["pixels"].astype(int)
        rows = np.nonzero(((frame[..., 0] > 150) & (frame[..., 1] < 150)).any(axis=1))[0]
        assert len(rows) > height // 4
        assert bool(rows.mean() < height / 2) is rod_above


# --- hover --------------------------------------------------------------------------------------------


def hover_state(env, pos, rpy=(0.0, 0.0, 0.0)) -> np.ndarray:
    quat = p.getQuaternionFromEuler(rpy)
    return np.concatenate([pos, quat, np.zeros(6), np.zeros(env.buffer_size * env.act_dim)])


def test_hover_at_target_is_success_and_hover_rpm_holds_it(closing):
    env, cfg = make("hover-rpm-30")
    closing(env)
    _, info = env.reset(seed=0)
    assert info["is_success"] is False  # starts near the ground
    env.reset_to(hover_state(env, [0.0, 0.0, 1.0]))
    for _ in range(cfg.fps):  # one second at exactly the hover RPM
        obs, reward, terminated, truncated, info = env.step(np.zeros(4, dtype=np.float32))
        assert info["is_success"] is True and not terminated and not truncated
        assert reward > 1.99
    assert np.allclose(obs["agent_pos"][:3], [0.0, 0.0, 1.0], atol=1e-3)
    # flying through the target is not hovering at it
    moving = hover_state(env, [0.0, 0.0, 1.0])
    moving[9] = 0.5  # vertical velocity, m/s
    env.reset_to(moving)
    obs, _, _, _, info = env.step(np.zeros(4, dtype=np.float32))
    assert np.linalg.norm(obs["agent_pos"][:3] - [0.0, 0.0, 1.0]) < 0.05 and info["is_success"] is False


def test_hover_truncates_when_out_of_bounds_or_tilted(closing):
    env, _ = make("hover-one_d_rpm-30")
    closing(env)
    env.reset(seed=0)
    zero = np.zeros(1, dtype=np.float32)
    for pos, rpy in [
        ([1.6, 0, 1], (0, 0, 0)),
        ([0, -1.6, 1], (0, 0, 0)),
        ([0, 0, 2.1], (0, 0, 0)),
        ([0, 0, 1], (0.5, 0, 0)),
        ([0, 0, 1], (0, -0.5, 0)),
    ]:
        env.reset_to(hover_state(env, pos, rpy))
        _, reward, terminated, truncated, info = env.step(zero)
        assert truncated is True and terminated is False, (pos, rpy)
    env.reset_to(hover_state(env, [0.5, 0.5, 1.0], (0.2, -0.2, 1.0)))
    assert env.step(zero)[3] is False


def test_hover_one_d_rpm_can_take_off_and_hover(closing):
    """A PD altitude controller on the single RPM command reaches the target from the start."""
    env, cfg = make("hover-one_d_rpm-30")
    closing(env)
    obs, info = env.reset(seed=1)
    successes = []
    for _ in range(cfg.episode_length):
        z, vz = obs["agent_pos"][2], obs["agent_pos"][8]
        a = np.clip([2.0 * (1.0 - z) - 2.0 * vz], -1, 1).astype(np.float32)
        obs, reward, terminated, truncated, info = env.step(a)
        assert not truncated
        successes.append(info["is_success"])
    assert all(successes[-cfg.fps :]), "hovering at the target for the last second"
    assert not any(successes[:10])


# --- hover: the card's picture is framed on the drone ----------------------------------------------------
#
# Measured on the rendered pixels: the drone is the only dark or saturated thing in hover's pictures (the floor's
# checks and the sky are light; the target sphere, green, is left out), so the bounding box of those pixels is the
# drone's. Before the card had its own camera the drone was ~30 px wide of 256 and 16 px from the bottom edge.

FRAME = 256
MIN_DRONE_WIDTH = 48  # px of FRAME: rotors and arms visible
MIN_MARGIN = FRAME // 8  # px between the drone and every edge of the frame


def drone_box(frame: np.ndarray) -> tuple[int, int, int, int] | None:
    """(x0, y0, x1, y1) of the drone's pixels, or None when none is in the frame."""
    f = frame[..., :3].astype(int)
    r, g, b = f[..., 0], f[..., 1], f[..., 2]
    green = (g > r + 40) & (g > b + 40)  # the target sphere
    ys, xs = np.nonzero((f.min(axis=-1) < 110) & ~green)
    return None if len(xs) == 0 else (int(xs.min()), int(ys.min()), int(xs.max()), int(ys.max()))


def assert_framed(frames, what: str) -> None:
    for i, frame in enumerate(frames):
        assert frame.shape[:2] == (FRAME, FRAME), (what, frame.shape)
        box = drone_box(frame)
        assert box is not None, f"{what}, frame {i}: no drone in the picture"
        x0, y0, x1, y1 = box
        assert x1 - x0 + 1 >= MIN_DRONE_WIDTH, f"{what}, frame {i}: the drone is {x1 - x0 + 1} px wide ({box})"
        assert min(x0, y0, FRAME - 1 - x1, FRAME - 1 - y1) >= MIN_MARGIN, f"{what}, frame {i}: at the edge ({box})"


def card_media_env(extra: dict | None = None):
    """hover as push_env makes it for the card: its pyproject's [tool.hub-envs.media] gym_kwargs, at 256 px."""
    env_cls, cfg_cls, _ = load("hover")
    media = manifest("hover")["tool"]["hub-envs"].get("media", {}).get("gym_kwargs", {})
    return env_cls(**{**cfg_cls().gym_kwargs, **media, "render_width": FRAME, "render_height": FRAME, **(extra or {})})


def test_hovers_card_camera_keeps_the_drone_framed_wherever_it_flies(closing):
    """Over a random-action episode that climbs to the ceiling and at the corners of the flight volume (where the
    episode is truncated), the card's camera shows the drone big and away from the frame's edges."""
    env = card_media_env()
    closing(env)
    env.action_space.seed(4)
    env.reset(seed=4)
    frames, top = [env.render()], 0.0
    for t in range(240):
        _, _, _, truncated, _ = env.step(env.action_space.sample())
        top = max(top, float(env.get_state()[2]))
        if t % 6 == 0:
            frames.append(env.render())
        if truncated:
            break
    assert top > 1.5, "seed 4's random actions fly the drone above 1.5 m (the ceiling is 2 m)"
    assert_framed(frames, "seed 4")
    corners = [(x, y, z) for x in (-1.45, 1.45) for y in (-1.45, 1.45) for z in (0.02, 1.95)]
    for pos in corners:
        env.reset_to(hover_state(env, pos, (0.35, -0.35, 0.0)))
        assert_framed([env.render()], f"at {pos}")


def test_hover_render_camera_is_checked_and_its_default_views_the_flight_volume(closing):
    """render()'s default camera (no card settings) sees the drone on the ground and at the target; a malformed
    render_camera is a ValueError naming the entry."""
    env_cls, cfg_cls, _ = load("hover")
    env = env_cls(**{**cfg_cls().gym_kwargs, "render_width": FRAME, "render_height": FRAME})
    closing(env)
    for z in (0.02, 1.0):
        env.reset_to(hover_state(env, (0.0, 0.0, z)))
        box = drone_box(env.render())
        assert box is not None and min(box[0], box[1], FRAME - 1 - box[2], FRAME - 1 - box[3]) >= 8, (z, box)
    for camera, match in [
        ({"target": "moon"}, "target"),
        ({"zoom": 2.0}, "unknown entries"),
        ({"distance": 0}, "distance"),
        ("drone", "must be a dict"),
    ]:
        with pytest.raises(ValueError, match=match):
            env_cls(render_camera=camera)


def test_hovers_card_gif_is_framed_on_the_drone_and_says_how_it_was_rendered(hub):
    """push_env renders the card's GIF with the camera the author set in pyproject.toml; the card states it."""
    import imageio.v3 as iio

    from hub_envs import push_env

    pushed = push_env(ENVS_DIR / "hover", "alice/hover-card", episodes=3, progress=False)
    gif = hub.api.hf_hub_download("alice/hover-card", "media/rollout.gif", revision=pushed.sha)
    frames = iio.imread(gif, index=None)
    assert len(frames) == 3 * 60 // 2  # 3 episodes, 60 steps, every 2nd (15 frames a second at 30 fps)
    assert_framed(frames, "the card's GIF")
    card = Path(hub.api.hf_hub_download("alice/hover-card", "README.md", revision=pushed.sha)).read_text()
    (note,) = [line for line in card.splitlines() if line.startswith("*Random-action rollouts")]
    assert "seeds 0, 1, 2" in note and "real time (30 fps)" in note
    assert "make(render_camera={'target': 'drone'" in note and "render_width=256, render_height=256)" in note


def test_a_media_table_the_env_refuses_is_named_before_the_dataset_is_built(hub, tmp_path, capsys):
    from hub_envs import errors, push_env

    def with_media(table: str) -> Path:
        folder = tmp_path / f"hover-{len(list(tmp_path.iterdir()))}"
        shutil.copytree(ENVS_DIR / "hover", folder, ignore=shutil.ignore_patterns("__pycache__"))
        text = (folder / "pyproject.toml").read_text().split("[tool.hub-envs.media]")[0]
        (folder / "pyproject.toml").write_text(text + table)
        return folder

    cases = [
        ('[tool.hub-envs.media]\ngym_kwargs = { render_camera = { target = "moon" } }\n', "target"),
        ("[tool.hub-envs.media]\ngym_kwargs = { camera_zoom = 2.0 }\n", "camera_zoom"),
        ("[tool.hub-envs.media]\ncamera = { target = [0, 0, 1] }\n", "unknown keys"),
        ("[tool.hub-envs.media]\ngym_kwargs = { when = 1979-05-27 }\n", "not a string, number"),
        ("media = 3\n", "must be a table"),  # under [tool.hub-envs]
    ]
    for table, match in cases:
        folder = with_media(table)
        with pytest.raises(errors.EnvFolderError, match=match) as e:
            push_env(folder, "alice/hover-bad-media", episodes=1)
        assert "pyproject.toml" in str(e.value) and "media" in str(e.value), str(e.value)
        assert "Generating the random-action dataset" not in capsys.readouterr().err
    assert not hub.api.repo_exists("alice/hover-bad-media")


# --- reach --------------------------------------------------------------------------------------------


def test_reach_success_with_end_effector_at_target(closing):
    env, _ = make("reach-pixels")
    closing(env)
    _, info = env.reset(seed=3)
    assert info["is_success"] is False
    state = env.get_state()
    away = env.reset_to(state)["pixels"]
    state[14:17] = env.end_effector_position()  # put the target on the end effector
    at_ee = env.reset_to(state)["pixels"]
    assert not np.array_equal(away, at_ee), "the target is visible in the image"
    obs, reward, terminated, truncated, info = env.step(np.zeros(7, dtype=np.float32))
    assert info["is_success"] is True and terminated is True and truncated is False
    assert -0.05 < reward <= 0.0


def test_reach_targets_are_sampled_per_seed_away_from_the_start(closing):
    env, _ = make("reach-env_state")
    closing(env)
    targets = []
    for seed in range(5):
        obs, info = env.reset(seed=seed)
        target = env.get_state()[14:17]
        assert np.array_equal(obs["environment_state"], target.astype(np.float32))
        assert np.all(target >= [0.3, -0.3, 0.15]) and np.all(target <= [0.7, 0.3, 0.6])
        assert np.linalg.norm(env.end_effector_position() - target) >= 0.15
        assert info["is_success"] is False
        targets.append(target)
    assert len({tuple(t) for t in targets}) == 5


def test_reach_is_solvable_with_actions_within_an_episode(closing):
    """Joint-space steps toward an IK solution reach the target: success comes from actions too."""
    env, cfg = make("reach-env_state")
    closing(env)
    for seed in range(3):
        obs, _ = env.reset(seed=seed)
        target = obs["environment_state"].astype(np.float64)
        goal = np.array(
            p.calculateInverseKinematics(env.arm.body, 6, target.tolist(), maxNumIterations=200, physicsClientId=env._client)
        )
        rewards = []
        for _ in range(cfg.episode_length):
            q = obs["agent_pos"][:7]
            obs, reward, terminated, truncated, info = env.step(np.clip((goal - q) / 0.05, -1, 1).astype(np.float32))
            rewards.append(reward)
            if terminated:
                break
        assert info["is_success"] is True and terminated, seed
        assert rewards[-1] > rewards[0]


def test_close_releases_the_pybullet_client():
    for config_id in ("hover-one_d_rpm-30", "reach-env_state"):
        env, _ = make(config_id)
        client = env._client
        assert p.getConnectionInfo(physicsClientId=client)["isConnected"] == 1
        env.close()
        assert p.getConnectionInfo(physicsClientId=client)["isConnected"] == 0
        env.close()  # closing twice is fine
