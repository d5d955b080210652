"""Rollouts → fast LeRobot v3.0 writer → LeRobot's real reader.

Envs here are gymnasium's Pendulum behind a tiny dict-observation env (optionally with a small
numpy-drawn image). Everything runs offline with HF_HOME in a temp folder.
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.envs.classic_control.pendulum import PendulumEnv

from hub_envs.dataset.reader import dataset_fingerprint, read_episode_frames, read_episode_meta, read_hub_envs_meta, read_info
from hub_envs.dataset.stats import STATS_NOTE
from hub_envs.dataset.writer import EpisodeFrames, dataset_features_from_config, rollout_to_frames, write_lerobot_dataset
from hub_envs.errors import ConfigError, DatasetError, EnvCodeError
from hub_envs.harness.rollout import EpisodeRollout, iter_episodes, run_episodes

IMG = 16
TASK = "Swing the pendulum up."


class DictPendulum(gym.Env):
    """Pendulum with obs {"agent_pos": (3,)} (+ {"pixels": (16, 16, 3)}); episode length depends on the seed.

    ``nan_at=(seed, t)`` puts a NaN in the observation of step t of that seed's episode.
    """

    metadata = {"render_modes": []}

    def __init__(
        self,
        image: bool = False,
        nan_at: tuple[int, int] | None = None,
        raise_at: int | None = None,
        raise_in_reset: bool = False,
    ):
        self.inner = PendulumEnv()
        self.image, self.nan_at, self.raise_at, self.raise_in_reset = image, nan_at, raise_at, raise_in_reset
        spaces = {"agent_pos": self.inner.observation_space}
        if image:
            spaces["pixels"] = gym.spaces.Box(0, 255, (IMG, IMG, 3), np.uint8)
        self.observation_space = gym.spaces.Dict(spaces)
        self.action_space = self.inner.action_space
        self.t, self.limit = 0, 0

    def _obs(self, o):
        o = o.copy()
        if self.nan_at is not None and (self.seed, self.t) == self.nan_at:
            o[1] = np.nan
        obs = {"agent_pos": o}
        if self.image:
            th = float(self.inner.state[0])
            img = np.zeros((IMG, IMG, 3), dtype=np.uint8)
            img[..., 2] = 60
            cx, cy = int(IMG / 2 + 5 * np.sin(th)), int(IMG / 2 - 5 * np.cos(th))
            img[max(cy - 1, 0) : cy + 2, max(cx - 1, 0) : cx + 2] = (250, 90, int(abs(th) * 40) % 256)
            obs["pixels"] = img
        return obs

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        if self.raise_in_reset:
            raise ValueError("reset exploded")
        o, info = self.inner.reset(seed=seed)
        self.seed = seed
        self.t, self.limit = 0, 20 + (seed or 0) % 3 * 7  # lengths 20, 27, 34
        return self._obs(o), info

    def step(self, action):
        if self.raise_at is not None and self.t == self.raise_at:
            raise RuntimeError("step exploded")
        o, r, terminated, _, info = self.inner.step(action)
        self.t += 1
        info = {**info, "is_success": bool(abs(self.inner.state[0]) < 0.5)}
        return self._obs(o), r, terminated, self.t >= self.limit, info

    def get_state(self):
        return np.asarray(self.inner.state, dtype=np.float64)


def features(image: bool) -> tuple[dict, dict]:
    feats = {
        "observation.state": {"dtype": "float32", "shape": [3], "names": ["cos", "sin", "theta_dot"]},
        "action": {"dtype": "float32", "shape": [1], "names": ["torque"]},
        "next.reward": {"dtype": "float32", "shape": [1], "names": None},
        "next.done": {"dtype": "bool", "shape": [1], "names": None},
        "next.success": {"dtype": "bool", "shape": [1], "names": None},
    }
    fmap = {"agent_pos": "observation.state", "action": "action"}
    if image:
        feats["observation.image"] = {"dtype": "image", "shape": [IMG, IMG, 3], "names": ["height", "width", "channels"]}
        fmap["pixels"] = "observation.image"
    return feats, fmap


SEEDS = [7, 8, 9, 10]


@pytest.fixture(scope="module", autouse=True)
def offline_hf_home(tmp_path_factory):
    """HF_HOME (and the datasets cache) in a temp folder, Hub offline, for the whole module."""
    home = tmp_path_factory.mktemp("hf_home")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("HF_HOME", str(home))
        mp.setenv("HF_LEROBOT_HOME", str(home / "lerobot"))
        mp.setenv("HF_DATASETS_CACHE", str(home / "datasets"))
        mp.setenv("HF_HUB_OFFLINE", "1")
        mp.setenv("HF_HUB_DISABLE_PROGRESS_BARS", "1")
        import datasets
        import huggingface_hub.constants

        mp.setattr(datasets.config, "HF_DATASETS_CACHE", home / "datasets")
        mp.setattr(datasets.config, "HF_HUB_OFFLINE", True, raising=False)
        mp.setattr(huggingface_hub.constants, "HF_HUB_OFFLINE", True)
        yield home


@pytest.fixture(scope="module")
def state_rollouts() -> list[EpisodeRollout]:
    return run_episodes(lambda: DictPendulum(), SEEDS, max_steps=100, record_states=True, progress=False)


@pytest.fixture(scope="module")
def image_rollouts() -> list[EpisodeRollout]:
    return run_episodes(lambda: DictPendulum(image=True), SEEDS, max_steps=100, progress=False)


def write(root: Path, rollouts, image: bool, **kw):
    feats, fmap = features(image)
    return write_lerobot_dataset(
        root,
        repo_id="test/pendulum",
        fps=30,
        features=feats,
        episodes=(EpisodeFrames.from_rollout(r, fmap) for r in rollouts),
        task=TASK,
        progress=False,
        **kw,
    )


@pytest.fixture(scope="module")
def state_ds(tmp_path_factory, state_rollouts):
    root = tmp_path_factory.mktemp("state") / "ds"
    summary = write(root, state_rollouts, False, extra_info={"env": {"repo": "me/pendulum", "sha": "abc"}})
    return root, summary


# --- rollouts ---------------------------------------------------------------------------------


def test_rollout_records_obs_before_action_and_seeds(state_rollouts):
    r0 = state_rollouts[0]
    assert [r.length for r in state_rollouts] == [20 + s % 3 * 7 for s in SEEDS]
    env = DictPendulum()
    obs, _ = env.reset(seed=SEEDS[0])
    np.testing.assert_array_equal(r0.observations["agent_pos"][0], obs["agent_pos"])
    env.action_space.seed(SEEDS[0])
    np.testing.assert_array_equal(r0.actions[0], env.action_space.sample())  # seeded random policy
    obs1, rew, *_ = env.step(r0.actions[0])
    np.testing.assert_array_equal(r0.observations["agent_pos"][1], obs1["agent_pos"])
    assert r0.rewards[0] == rew
    assert r0.states.shape == (r0.length, 2)  # (theta, theta_dot) before each action
    np.testing.assert_array_equal(r0.states[1], env.get_state())
    assert r0.truncated[-1] and not r0.truncated[:-1].any() and not r0.terminated.any()
    assert r0.is_success.dtype == bool


def test_plain_box_observation_is_stored_under_observation():
    (r,) = run_episodes(lambda: gym.make("Pendulum-v1"), [0], max_steps=3, progress=False)
    assert list(r.observations) == ["observation"] and r.observations["observation"].shape == (3, 3)


def test_max_steps_cut_is_a_truncation():
    (r,) = run_episodes(lambda: DictPendulum(), [1], max_steps=5, progress=False)
    assert r.length == 5 and r.truncated.tolist() == [False] * 4 + [True]


def test_workers_give_identical_rollouts(state_rollouts):
    make = lambda: DictPendulum(image=True)  # noqa: E731 - a lambda: fork workers need no pickling
    one = run_episodes(make, SEEDS, max_steps=100, record_states=True, workers=1, progress=False)
    two = run_episodes(make, SEEDS, max_steps=100, record_states=True, workers=2, progress=False)
    assert one == two
    assert [r.digest() for r in one] == [r.digest() for r in two]
    assert [r.index for r in two] == list(range(len(SEEDS)))
    assert [r.seed for r in two] == SEEDS
    np.testing.assert_array_equal(one[0].observations["agent_pos"], state_rollouts[0].observations["agent_pos"])


def test_replaying_recorded_actions_reproduces_observations(state_rollouts):
    replay = run_episodes(
        lambda: DictPendulum(), SEEDS, max_steps=100, policy=[r.actions for r in state_rollouts], progress=False
    )
    assert replay == [dataclasses.replace(r, states=None) for r in state_rollouts]
    # a callable policy gets (obs, step_index)
    seen = []
    run_episodes(
        lambda: DictPendulum(),
        [3],
        max_steps=4,
        policy=lambda obs, t: seen.append((sorted(obs), t)) or np.zeros(1, np.float32),
        progress=False,
    )
    assert seen == [(["agent_pos"], t) for t in range(4)]


@pytest.mark.parametrize("workers", [1, 2])
def test_nan_observation_is_an_env_code_error(workers):
    with pytest.raises(EnvCodeError, match=r"episode 1 \(seed 8\).*'agent_pos'.*step 5"):
        run_episodes(lambda: DictPendulum(nan_at=(8, 5)), SEEDS, max_steps=100, workers=workers, progress=False)


def test_env_raising_is_an_env_code_error():
    with pytest.raises(EnvCodeError, match=r"episode 0 \(seed 7\), step 3.*RuntimeError: step exploded"):
        run_episodes(lambda: DictPendulum(raise_at=3), SEEDS, max_steps=100, progress=False)
    with pytest.raises(EnvCodeError, match=r"episode 0 \(seed 7\).*reset.*ValueError: reset exploded"):
        run_episodes(lambda: DictPendulum(raise_in_reset=True), SEEDS, max_steps=100, workers=2, progress=False)
    with pytest.raises(ConfigError):
        run_episodes(lambda: DictPendulum(), [-1], max_steps=10, progress=False)


# --- the dataset, read by LeRobot ---------------------------------------------------------------


def test_lerobot_reads_state_dataset(state_ds, state_rollouts):
    import torch
    from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata

    from hub_envs._compat import lerobot_dataset_io

    io = lerobot_dataset_io()
    load_episodes, load_info, load_stats, load_tasks = io.load_episodes, io.load_info, io.load_stats, io.load_tasks

    root, summary = state_ds
    lengths = [r.length for r in state_rollouts]
    assert summary.frames == sum(lengths) and summary.episodes == len(SEEDS) and summary.seeds == tuple(SEEDS)
    assert summary.episode_lengths == tuple(lengths)
    returns = [r.episode_return for r in state_rollouts]
    assert summary.return_mean == pytest.approx(np.mean(returns), rel=1e-5)
    assert summary.return_min == pytest.approx(min(returns), rel=1e-5)
    assert summary.success_rate == np.mean([r.success for r in state_rollouts])

    ds = LeRobotDataset("test/pendulum", root=root)
    assert len(ds) == sum(lengths) and ds.num_episodes == len(SEEDS) and ds.fps == 30
    starts = np.cumsum([0, *lengths])
    eps = ds.meta.episodes
    assert list(eps["dataset_from_index"]) == starts[:-1].tolist()
    assert list(eps["dataset_to_index"]) == starts[1:].tolist()
    assert list(eps["length"]) == lengths
    assert list(eps["seed"]) == SEEDS  # the extra column does not bother LeRobot
    for e, r in enumerate(state_rollouts):
        for t in (0, r.length // 2, r.length - 1):
            item = ds[int(starts[e]) + t]
            assert item["episode_index"].item() == e and item["frame_index"].item() == t
            assert item["index"].item() == starts[e] + t
            assert item["timestamp"].item() == pytest.approx(t / 30, abs=1e-6)
            assert item["task"] == TASK
            assert torch.equal(item["observation.state"], torch.from_numpy(r.observations["agent_pos"][t]))
            assert item["action"].item() == r.actions[t, 0]
            assert item["next.reward"].item() == np.float32(r.rewards[t])
            assert item["next.done"].item() == (t == r.length - 1)
            assert item["next.success"].item() == r.is_success[t]

    meta = LeRobotDatasetMetadata("test/pendulum", root=root)
    assert meta.total_frames == sum(lengths) and meta.total_episodes == len(SEEDS)
    assert load_info(root).get("total_episodes") == len(SEEDS)
    assert json.loads((root / "meta" / "hub_envs.json").read_text())["env"] == {"repo": "me/pendulum", "sha": "abc"}
    assert len(load_episodes(root)) == len(SEEDS)
    assert load_tasks(root).index.tolist() == [TASK]

    # global stats: exact numpy values over all frames
    stats = load_stats(root)
    state = np.concatenate([r.observations["agent_pos"] for r in state_rollouts]).astype(np.float64)
    np.testing.assert_allclose(stats["observation.state"]["mean"], state.mean(0), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(stats["observation.state"]["std"], state.std(0), rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(stats["observation.state"]["min"], state.min(0).astype(np.float32))
    np.testing.assert_array_equal(stats["observation.state"]["max"], state.max(0).astype(np.float32))
    assert stats["observation.state"]["count"].tolist() == [sum(lengths)]
    rewards = np.concatenate([r.rewards for r in state_rollouts]).astype(np.float32).astype(np.float64)
    np.testing.assert_allclose(stats["next.reward"]["mean"], [rewards.mean()], rtol=1e-9)
    np.testing.assert_allclose(stats["next.reward"]["std"], [rewards.std()], rtol=1e-9)
    for key in ("observation.state", "action", "next.reward", "next.done", "timestamp", "index"):
        assert set(stats[key]) == {"min", "max", "mean", "std", "count", "q01", "q10", "q50", "q90", "q99"}
        assert stats[key]["q50"].shape == stats[key]["mean"].shape
    # a subset of episodes loads too (LeRobot's pushdown filter on episode_index)
    sub = LeRobotDataset("test/pendulum", root=root, episodes=[2])
    assert len(sub) == lengths[2] and sub[0]["index"].item() == starts[2]


def test_seeds_and_frames_readable_without_lerobot(state_ds, state_rollouts):
    root, summary = state_ds
    info = read_info(root)
    assert info["codebase_version"] == "v3.0" and read_hub_envs_meta(root)["seeds"] == SEEDS
    assert read_hub_envs_meta(root)["env"]["sha"] == "abc"
    assert list(info["features"])[-5:] == ["timestamp", "frame_index", "episode_index", "index", "task_index"]
    meta = read_episode_meta(root)
    assert [m["seed"] for m in meta] == SEEDS and [m["length"] for m in meta] == list(summary.episode_lengths)
    frames = read_episode_frames(root, 2)
    r = state_rollouts[2]
    np.testing.assert_array_equal(frames["observation.state"], r.observations["agent_pos"])
    np.testing.assert_array_equal(frames["action"], r.actions)
    np.testing.assert_array_equal(frames["next.reward"][:, 0], r.rewards.astype(np.float32))
    assert frames["frame_index"][:, 0].tolist() == list(range(r.length))
    assert summary.fingerprint == dataset_fingerprint(root)


@pytest.mark.filterwarnings("ignore::DeprecationWarning", "ignore::RuntimeWarning")  # inside LeRobot's own writer
def test_image_dataset_matches_lerobot_own_writer(tmp_path, image_rollouts):
    """Same frames through LeRobot's add_frame path and ours: every item LeRobot returns is identical."""
    import torch
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    feats, fmap = features(True)
    ours = tmp_path / "ours"
    write(ours, image_rollouts, True)
    theirs = tmp_path / "theirs"
    ref = LeRobotDataset.create(
        "test/ref",
        fps=30,
        features={k: {**f, "shape": tuple(f["shape"])} for k, f in feats.items()},
        root=theirs,
        use_videos=False,
    )
    for r in image_rollouts:
        frames = rollout_to_frames(r, fmap)
        for t in range(r.length):
            ref.add_frame({k: (v[t] if v.ndim > 1 else v[t : t + 1]) for k, v in frames.items()} | {"task": TASK})
        ref.save_episode()
    ref.finalize()

    a, b = LeRobotDataset("test/ours", root=ours), LeRobotDataset("test/ref", root=theirs)
    assert len(a) == len(b)
    for i in range(len(a)):
        x, y = a[i], b[i]
        assert x.keys() == y.keys()
        for k in x:
            if isinstance(x[k], torch.Tensor):
                assert x[k].dtype == y[k].dtype and torch.equal(x[k], y[k]), (i, k)
            else:
                assert x[k] == y[k], (i, k)
    # images come back as LeRobot converts them: CHW float in [0, 1]
    img = image_rollouts[1].observations["pixels"][3]
    item = a[image_rollouts[0].length + 3]
    assert torch.equal(item["observation.image"], torch.from_numpy(img).permute(2, 0, 1).float().div(255))
    # same files, same schemas, same stats keys and shapes (values differ: ours are exact)
    import pyarrow.parquet as pq

    for rel in ("data/chunk-000/file-000.parquet", "meta/tasks.parquet"):
        assert pq.read_schema(ours / rel).remove_metadata() == pq.read_schema(theirs / rel).remove_metadata()
    ours_meta = pq.read_schema(ours / "meta/episodes/chunk-000/file-000.parquet")
    theirs_meta = pq.read_schema(theirs / "meta/episodes/chunk-000/file-000.parquet")
    assert ours_meta.names == [*theirs_meta.names, "seed"]
    differing = {
        n: (str(ours_meta.field(n).type), str(theirs_meta.field(n).type))
        for n in theirs_meta.names
        if ours_meta.field(n).type != theirs_meta.field(n).type
    }
    assert not differing, differing
    info_a, info_b = read_info(ours), read_info(theirs)
    assert set(info_a) == set(info_b)  # the same keys (their order changed in LeRobot 0.5): none LeRobot does not know
    assert read_hub_envs_meta(ours)["stats"] == STATS_NOTE  # where our stats differ from LeRobot's, on purpose, said
    assert info_a["features"] == json.loads(json.dumps(info_b["features"]))
    sa, sb = (json.loads((p / "meta/stats.json").read_text()) for p in (ours, theirs))
    assert sa.keys() == sb.keys()
    for key in sa:
        assert {s: np.shape(v) for s, v in sa[key].items()} == {s: np.shape(v) for s, v in sb[key].items()}
    pixels = np.concatenate([r.observations["pixels"] for r in image_rollouts])
    np.testing.assert_allclose(np.ravel(sa["observation.image"]["mean"]), pixels.reshape(-1, 3).mean(0) / 255, rtol=1e-9)
    # decoding without LeRobot gives the recorded pixels
    np.testing.assert_array_equal(read_episode_frames(ours, 1)["observation.image"], image_rollouts[1].observations["pixels"])


def test_layout_is_the_installed_lerobots():
    """Our copy of LeRobot's v3.0 layout constants equals the installed lerobot's, name by name."""
    from hub_envs import _compat
    from hub_envs.dataset import layout

    theirs = _compat.lerobot_dataset_layout()
    assert {name: getattr(layout, name) for name in theirs} == theirs


def test_same_inputs_give_byte_identical_folders(tmp_path, image_rollouts):
    s1 = write(tmp_path / "a", image_rollouts, True, extra_info={"k": [1, 2]})
    again = run_episodes(lambda: DictPendulum(image=True), SEEDS, max_steps=100, workers=2, progress=False)
    s2 = write(tmp_path / "b", again, True, extra_info={"k": [1, 2]}, encode_in_background=False)
    assert s1.fingerprint == s2.fingerprint
    files = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(tmp_path / "b") for p in (tmp_path / "b").rglob("*") if p.is_file())
    for rel in files:
        assert (tmp_path / "a" / rel).read_bytes() == (tmp_path / "b" / rel).read_bytes(), rel


def test_camera_frames_from_worker_processes_are_the_same_and_leave_no_files(monkeypatch):
    """Worker processes hand big observations to the parent through files in /dev/shm, not the result pipe: the
    episodes are exactly those one process gives, and no file is left behind, also when the caller stops early."""
    import glob
    import os

    from hub_envs.harness import rollout

    monkeypatch.setattr(rollout, "_FILE_MIN_BYTES", 1)  # every observation through a file (the workers inherit it)

    def leftovers() -> list[str]:
        return glob.glob(f"/dev/shm/hub-envs-rollout-{os.getpid()}-*")

    make = lambda: DictPendulum(image=True)  # noqa: E731
    one = run_episodes(make, SEEDS, max_steps=100, record_states=True, workers=1, progress=False)
    two = run_episodes(make, SEEDS, max_steps=100, record_states=True, workers=2, progress=False)
    assert two == one and not leftovers()
    stopped = iter_episodes(make, SEEDS * 3, max_steps=100, record_states=True, workers=2, progress=False)
    assert next(stopped) == one[0]
    stopped.close()  # episodes written by the workers and never read
    assert not leftovers()


def test_failure_mid_write_leaves_nothing(tmp_path, state_rollouts):
    feats, fmap = features(False)

    def broken():
        yield EpisodeFrames.from_rollout(state_rollouts[0], fmap)
        yield EpisodeFrames.from_rollout(state_rollouts[1], fmap)
        raise OSError("disk on fire")

    root = tmp_path / "out" / "ds"
    with pytest.raises(DatasetError, match="disk on fire") as err:
        write_lerobot_dataset(root, repo_id="t/x", fps=30, features=feats, episodes=broken(), task=TASK, progress=False)
    assert str(root) in str(err.value)
    assert not root.exists() and list(root.parent.iterdir()) == []

    # an env failing during generation: the EnvCodeError comes through unchanged, nothing written
    rollouts = iter_episodes(lambda: DictPendulum(raise_at=3), SEEDS, max_steps=100, progress=False)
    with pytest.raises(EnvCodeError):
        write_lerobot_dataset(
            root,
            repo_id="t/x",
            fps=30,
            features=feats,
            task=TASK,
            progress=False,
            episodes=(EpisodeFrames.from_rollout(r, fmap) for r in rollouts),
        )
    assert list(root.parent.iterdir()) == []

    # frames that do not match the features
    bad = EpisodeFrames(0, 1, {"observation.state": np.zeros((3, 3), np.float32)})
    with pytest.raises(DatasetError, match="missing"):
        write_lerobot_dataset(root, repo_id="t/x", fps=30, features=feats, episodes=[bad], task=TASK, progress=False)
    assert list(root.parent.iterdir()) == []
    with pytest.raises(ConfigError, match=r"Video feature 'cam'.*\[height, width, 3\]"):  # video is RGB (yuv420p)
        write_lerobot_dataset(
            root, repo_id="t/x", fps=30, features={"cam": {"dtype": "video", "shape": [4, 4, 4]}}, episodes=[], task=TASK
        )


def test_existing_folder_needs_overwrite(tmp_path, state_rollouts):
    root = tmp_path / "ds"
    write(root, state_rollouts[:1], False)
    with pytest.raises(DatasetError, match="overwrite=True"):
        write(root, state_rollouts, False)
    assert read_info(root)["total_episodes"] == 1
    summary = write(root, state_rollouts, False, overwrite=True)
    assert read_info(root)["total_episodes"] == len(SEEDS) and summary.fingerprint == dataset_fingerprint(root)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]


def test_many_files_when_size_limits_are_small(tmp_path, state_rollouts):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    root = tmp_path / "ds"
    write(root, state_rollouts, False, data_files_size_in_mb=0.002, chunks_size=2)
    data_files = sorted(p.relative_to(root).as_posix() for p in (root / "data").rglob("*.parquet"))
    assert len(data_files) == len(SEEDS) and "data/chunk-001/file-000.parquet" in data_files
    ds = LeRobotDataset("test/many", root=root)
    assert len(ds) == sum(r.length for r in state_rollouts)
    assert [m["data/chunk_index"] for m in read_episode_meta(root)] == [0, 0, 1, 1]
    last = state_rollouts[-1]
    np.testing.assert_array_equal(read_episode_frames(root, 3)["observation.state"], last.observations["agent_pos"])
    assert ds[len(ds) - 1]["observation.state"].numpy().tolist() == last.observations["agent_pos"][-1].tolist()


def test_more_episodes_than_a_metadata_batch_are_written_with_their_seeds(tmp_path):
    """Episodes metadata is flushed in batches of 1000 rows: a dataset of more episodes (push_env --episodes=1000
    and up) keeps every episode's row and reset seed, and LeRobot reads it (this failed at the 1000th episode)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from hub_envs.dataset import writer

    n = writer._META_FLUSH_ROWS + 3
    features = {
        "observation.state": {"dtype": "float32", "shape": [2], "names": ["x", "v"]},
        "action": {"dtype": "float32", "shape": [1], "names": ["u"]},
    }
    episodes = (
        EpisodeFrames(
            i, seed=7000 + i, frames={"observation.state": np.full((2, 2), i, np.float32), "action": np.zeros((2, 1), np.float32)}
        )
        for i in range(n)
    )
    root = tmp_path / "ds"
    write_lerobot_dataset(
        root, repo_id="test/many-episodes", fps=10, features=features, episodes=episodes, task="t", progress=False
    )
    metas = read_episode_meta(root)
    assert [m["episode_index"] for m in metas] == list(range(n))
    assert [m["seed"] for m in metas] == [7000 + i for i in range(n)]
    ds = LeRobotDataset("test/many-episodes", root=root)
    assert ds.meta.total_episodes == n and len(ds) == 2 * n
    assert ds[2 * n - 1]["observation.state"].tolist() == [n - 1, n - 1]


def test_features_from_lerobot_env_config():
    from lerobot.envs.configs import PushtEnv

    feats = dataset_features_from_config(PushtEnv())
    assert feats["observation.image"] == {"dtype": "image", "shape": [384, 384, 3], "names": ["height", "width", "channels"]}
    assert feats["observation.state"] == {"dtype": "float32", "shape": [2], "names": ["agent_pos_0", "agent_pos_1"]}
    assert feats["action"]["dtype"] == "float32" and feats["action"]["shape"] == [2]
    assert [k for k in feats if k.startswith("next.")] == ["next.reward", "next.done", "next.success"]
    assert feats["next.done"]["dtype"] == "bool"


def test_hf_home_is_isolated(offline_hf_home):
    assert os.environ["HF_HOME"] == str(offline_hf_home) and os.environ["HF_HUB_OFFLINE"] == "1"


@pytest.mark.parametrize("channels", [1, 2, 3, 4])
def test_png_frames_decode_to_the_recorded_pixels_in_pil_and_opencv(channels):
    """The PNG encoder makes standard PNGs: PIL (LeRobot's decoder) and OpenCV return the exact pixels,
    for every channel count and odd sizes, and the same frames always give the same bytes."""
    import io

    import PIL.Image

    from hub_envs.dataset.codec import decode_png, encode_png

    rng = np.random.default_rng(channels)
    for h, w in ((1, 1), (5, 7), (48, 64)):
        noisy = rng.integers(0, 256, (3, h, w, channels), dtype=np.uint8)
        flat = np.repeat(np.repeat(rng.integers(0, 4, (3, 1, 1, channels), dtype=np.uint8) * 60, h, axis=1), w, axis=2)
        for frames in (noisy, flat):
            pngs = encode_png(frames)
            assert pngs == encode_png(frames.copy())
            for png, frame in zip(pngs, frames, strict=True):
                with PIL.Image.open(io.BytesIO(png)) as img:
                    pil = np.asarray(img)
                np.testing.assert_array_equal(pil.reshape(h, w, channels), frame)
                np.testing.assert_array_equal(decode_png(png), frame)


def test_scalar_columns_stats_computed_together_equal_each_computed_alone():
    """An episode's scalar columns get their stats in one batch: the values are those of each column alone, bit for
    bit (the same numpy summation order), in the dtypes the installed LeRobot writes."""
    from hub_envs.dataset.stats import vector_stats, vector_stats_many

    rng = np.random.default_rng(0)
    for n in (1, 2, 7, 129, 200, 1001):
        columns = [
            np.arange(n) / 30.0,  # timestamp
            rng.normal(size=(n, 1)).astype(np.float32),
            rng.normal(size=n).astype(np.float32) * 1e4,
            rng.random(n) < 0.2,
            np.arange(n, dtype=np.int64) + 10**6,
            np.full(n, 3, dtype=np.int64),
            rng.normal(size=(n, 3)).astype(np.float32),  # a vector column: computed alone
        ]
        together = vector_stats_many(columns)
        for col, got in zip(columns, together, strict=True):
            alone = vector_stats(col)
            assert got.keys() == alone.keys()
            for stat in alone:
                assert got[stat].dtype == alone[stat].dtype and got[stat].shape == alone[stat].shape, (n, stat)
                assert np.array_equal(got[stat], alone[stat]), (n, stat, got[stat], alone[stat])
