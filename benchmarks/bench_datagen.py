"""Dataset generation speed: raw env stepping vs hub-envs' pipeline vs LeRobot's add_frame path.

Same env, same seeds, same episodes for all three, on two variants of gymnasium's Pendulum:

* ``state``: dict observation ``{"agent_pos": (3,)}``
* ``image``: plus ``{"pixels": (64, 64, 3) uint8}``, a small frame drawn with numpy

Measured (frames/s, median over ``repeats``):

* ``raw``: reset(seed) + action_space.seed + step(action_space.sample()) until done; nothing kept.
* ``hub_envs_w1`` / ``hub_envs_w2``: ``iter_episodes`` (1 or 2 worker processes) →
  ``EpisodeFrames.from_rollout`` → ``write_lerobot_dataset`` into a temp folder.
* ``lerobot``: the same rollouts fed frame by frame to ``LeRobotDataset.create(use_videos=False)``
  → ``add_frame`` → ``save_episode`` → ``finalize``.

Ratios: ``datagen_vs_lerobot = hub_envs / lerobot`` and ``datagen_vs_raw = hub_envs / raw``, where
``hub_envs`` is the faster of w1/w2 (the pipeline as one would run it on this machine); the w1
ratios are reported too. Each is the median over ``repeats`` of the repeat's own ratio (the runs of a repeat
are side by side, so a change of the machine's load between repeats does not enter it); the w1 pipeline's
CPU-time ratio to raw stepping (its threads included) is recorded as ``datagen_w1_vs_raw_cpu``: on a busy host
it shows what the code costs when the wall clock mostly shows the neighbours.

Camera frames are PNG-encoded in a helper process (:mod:`hub_envs.dataset.png_process`) while the next episodes are
made. Like the imports, it is started once per process: by the warm-up run here; a helper that finished stays for the
next dataset of the process (up to ``IDLE_SECONDS``), so a process writing its first dataset pays one fork more
(``png_helper_start_ms``, measured here in this process as it is after the runs: heavier after LeRobot's import).

Run: ``python benchmarks/bench_datagen.py [--repeats 3] [--profile]``; ``run()`` returns the dict.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
from gymnasium.envs.classic_control.pendulum import PendulumEnv

from hub_envs.dataset.writer import EpisodeFrames, write_lerobot_dataset
from hub_envs.harness.rollout import iter_episodes

FPS = 30
TASK = "Swing the pendulum up."
MAX_STEPS = 200


class DictPendulum(gym.Env):
    """gymnasium's Pendulum with a dict observation, optionally with a rendered 64x64 frame."""

    metadata = {"render_modes": []}

    def __init__(self, image: bool = False, size: int = 64, max_episode_steps: int = MAX_STEPS):
        self.inner = PendulumEnv()
        self.image, self.size, self.max_episode_steps = image, size, max_episode_steps
        spaces = {"agent_pos": self.inner.observation_space}
        if image:
            spaces["pixels"] = gym.spaces.Box(0, 255, (size, size, 3), np.uint8)
        self.observation_space = gym.spaces.Dict(spaces)
        self.action_space = self.inner.action_space
        self.t = 0

    def _obs(self, o: np.ndarray) -> dict:
        obs = {"agent_pos": o}
        if self.image:
            s, th = self.size, float(self.inner.state[0])
            img = np.full((s, s, 3), 40, dtype=np.uint8)
            cx, cy = int(s / 2 + 0.35 * s * np.sin(th)), int(s / 2 - 0.35 * s * np.cos(th))
            img[max(cy - 3, 0) : cy + 3, max(cx - 3, 0) : cx + 3] = (230, 80, 30)
            img[s // 2 - 1 : s // 2 + 1, s // 2 - 1 : s // 2 + 1] = 255
            obs["pixels"] = img
        return obs

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        o, info = self.inner.reset(seed=seed)
        self.t = 0
        return self._obs(o), info

    def step(self, action):
        o, r, terminated, truncated, info = self.inner.step(action)
        self.t += 1
        return self._obs(o), r, terminated, truncated or self.t >= self.max_episode_steps, info


def features_for(image: bool) -> tuple[dict, dict]:
    features = {
        "observation.state": {"dtype": "float32", "shape": [3], "names": ["cos_theta", "sin_theta", "theta_dot"]},
        "action": {"dtype": "float32", "shape": [1], "names": ["torque"]},
        "next.reward": {"dtype": "float32", "shape": [1], "names": None},
        "next.done": {"dtype": "bool", "shape": [1], "names": None},
        "next.success": {"dtype": "bool", "shape": [1], "names": None},
    }
    features_map = {"agent_pos": "observation.state", "action": "action"}
    if image:
        features["observation.image"] = {"dtype": "image", "shape": [64, 64, 3], "names": ["height", "width", "channels"]}
        features_map["pixels"] = "observation.image"
    return features, features_map


def bench_raw(image: bool, seeds: list[int], cpu: list | None = None) -> float:
    """Frames/s of wall time (and, into ``cpu``, frames/s of this process's CPU time)."""
    env = DictPendulum(image)
    n = 0
    t0, c0 = time.perf_counter(), time.process_time()
    for seed in seeds:
        env.reset(seed=seed)
        env.action_space.seed(seed)
        for _ in range(MAX_STEPS):
            _, _, terminated, truncated, _ = env.step(env.action_space.sample())
            n += 1
            if terminated or truncated:
                break
    if cpu is not None:
        cpu.append(n / (time.process_time() - c0))
    return n / (time.perf_counter() - t0)


def bench_hub_envs(image: bool, seeds: list[int], workers: int, out: Path, cpu: list | None = None) -> float:
    """Frames/s of wall time (and, into ``cpu``, frames/s of this process's CPU time, its threads included)."""
    features, features_map = features_for(image)
    t0, c0 = time.perf_counter(), time.process_time()
    rollouts = iter_episodes(lambda: DictPendulum(image), seeds, max_steps=MAX_STEPS, workers=workers, progress=False)
    summary = write_lerobot_dataset(
        out,
        repo_id="bench/pendulum",
        fps=FPS,
        features=features,
        episodes=(EpisodeFrames.from_rollout(r, features_map) for r in rollouts),
        task=TASK,
        progress=False,
    )
    if cpu is not None:
        cpu.append(summary.frames / (time.process_time() - c0))
    return summary.frames / (time.perf_counter() - t0)


def bench_lerobot(image: bool, seeds: list[int], out: Path) -> float:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from hub_envs.dataset.writer import rollout_to_frames

    features, features_map = features_for(image)
    features = {k: {**ft, "shape": tuple(ft["shape"])} for k, ft in features.items()}  # LeRobot wants tuples
    t0 = time.perf_counter()
    ds = LeRobotDataset.create("bench/pendulum-lerobot", fps=FPS, features=features, root=out, use_videos=False)
    n = 0
    for r in iter_episodes(lambda: DictPendulum(image), seeds, max_steps=MAX_STEPS, progress=False):
        frames = rollout_to_frames(r, features_map)
        frames["next.reward"] = frames["next.reward"].reshape(-1, 1)
        frames["next.done"] = frames["next.done"].reshape(-1, 1)
        frames["next.success"] = frames["next.success"].reshape(-1, 1)
        for t in range(r.length):
            ds.add_frame({**{k: v[t] for k, v in frames.items()}, "task": TASK})
        ds.save_episode()
        n += r.length
    ds.finalize()
    return n / (time.perf_counter() - t0)


def profile_hub_envs(image: bool, seeds: list[int], top: int = 25) -> None:
    import cProfile
    import pstats

    with tempfile.TemporaryDirectory() as tmp:
        prof = cProfile.Profile()
        prof.enable()
        bench_hub_envs(image, seeds, 1, Path(tmp) / "ds")
        prof.disable()
    print(f"\n--- cProfile, hub-envs pipeline, workers=1, {'image' if image else 'state'} variant (by tottime) ---")
    pstats.Stats(prof).sort_stats("tottime").print_stats(top)


def run(repeats: int = 3, episodes: dict[str, int] | None = None, verbose: bool = True) -> dict:
    """Benchmark both variants; return frames/s and ratios (``datagen_vs_lerobot``, ``datagen_vs_raw``)."""
    episodes = episodes or {"state": 30, "image": 15}
    results: dict = {"cpu_count": os.cpu_count(), "repeats": repeats, "max_steps": MAX_STEPS}
    tmp = Path(tempfile.mkdtemp(prefix="bench-datagen-"))
    try:
        for variant, n_eps in episodes.items():
            image = variant == "image"
            seeds = list(range(n_eps))
            bench_hub_envs(image, seeds[:2], 1, tmp / "warmup")  # imports, caches
            shutil.rmtree(tmp / "warmup", ignore_errors=True)
            runs: dict[str, list[float]] = {"raw": [], "hub_envs_w1": [], "hub_envs_w2": [], "lerobot": []}
            cpu: dict[str, list[float]] = {"raw": [], "hub_envs_w1": []}
            for rep in range(repeats):
                w1_first = rep % 2 == 0  # raw beside each pipeline run, neither always first
                runs["raw"].append(bench_raw(image, seeds, cpu["raw"]))
                for w in (1, 2) if w1_first else (2, 1):
                    out = tmp / f"{variant}-w{w}-{rep}"
                    runs[f"hub_envs_w{w}"].append(bench_hub_envs(image, seeds, w, out, cpu["hub_envs_w1"] if w == 1 else None))
                    shutil.rmtree(out, ignore_errors=True)
                out = tmp / f"{variant}-lerobot-{rep}"
                runs["lerobot"].append(bench_lerobot(image, seeds, out))
                shutil.rmtree(out, ignore_errors=True)
            med = {k: statistics.median(v) for k, v in runs.items()}
            best = [max(a, b) for a, b in zip(runs["hub_envs_w1"], runs["hub_envs_w2"])]

            def ratio(num: list[float], den: list[float]) -> float:
                return round(statistics.median([a / b for a, b in zip(num, den)]), 3)

            results[variant] = {
                "episodes": n_eps,
                "frames_per_s": {k: round(v, 1) for k, v in med.items()},
                "datagen_vs_lerobot": ratio(best, runs["lerobot"]),
                "datagen_vs_raw": ratio(best, runs["raw"]),
                "datagen_vs_raw_each": [round(a / b, 3) for a, b in zip(best, runs["raw"])],
                "datagen_w1_vs_lerobot": ratio(runs["hub_envs_w1"], runs["lerobot"]),
                "datagen_w1_vs_raw": ratio(runs["hub_envs_w1"], runs["raw"]),
                "datagen_w2_vs_raw": ratio(runs["hub_envs_w2"], runs["raw"]),
                "datagen_w1_vs_raw_cpu": ratio(cpu["hub_envs_w1"], cpu["raw"]),
            }
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    results["png_helper_start_ms"] = _png_helper_start_ms()
    results["datagen_vs_lerobot"] = min(results[v]["datagen_vs_lerobot"] for v in episodes)
    results["datagen_vs_raw"] = min(results[v]["datagen_vs_raw"] for v in episodes)
    if verbose:
        print_table(results, list(episodes))
    return results


def _png_helper_start_ms(repeats: int = 5) -> float | None:
    """Median ms to fork a PNG helper and end it, from this process (what a first dataset pays once)."""
    from hub_envs.dataset import png_process

    png_process._close_idle()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        helper = png_process.acquire()
        if helper is None:
            return None
        helper.close()
        times.append((time.perf_counter() - t0) * 1e3)
    return round(statistics.median(times), 1)


def print_table(results: dict, variants: list[str]) -> None:
    cols = ["raw", "hub_envs_w1", "hub_envs_w2", "lerobot"]
    print(f"\nDataset generation, frames/s (median of {results['repeats']}, {results['cpu_count']} CPUs)")
    print(
        f"{'variant':8} " + " ".join(f"{c:>12}" for c in cols) + f" {'vs_lerobot':>11} {'vs_raw':>8} {'w1 vs raw':>10}"
        f" {'w2 vs raw':>10} {'w1 cpu':>7}  vs_raw each repeat"
    )
    for v in variants:
        r = results[v]
        fps = r["frames_per_s"]
        print(
            f"{v:8} "
            + " ".join(f"{fps[c]:>12.0f}" for c in cols)
            + f" {r['datagen_vs_lerobot']:>11.2f} {r['datagen_vs_raw']:>8.2f} {r['datagen_w1_vs_raw']:>10.2f}"
            f" {r['datagen_w2_vs_raw']:>10.2f} {r['datagen_w1_vs_raw_cpu']:>7.2f}  "
            + " ".join(f"{x:.2f}" for x in r["datagen_vs_raw_each"])
        )
    print(
        f"datagen_vs_lerobot = {results['datagen_vs_lerobot']:.2f} (goal >= 3), datagen_vs_raw = {results['datagen_vs_raw']:.2f} (goal >= 0.6); "
        f"a PNG helper's start and end: {results['png_helper_start_ms']} ms (once per process)"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--profile", action="store_true", help="also print a cProfile of the hub-envs pipeline")
    args = parser.parse_args()
    run(repeats=args.repeats)
    if args.profile:
        profile_hub_envs(False, list(range(30)))
        profile_hub_envs(True, list(range(15)))


if __name__ == "__main__":
    main()
