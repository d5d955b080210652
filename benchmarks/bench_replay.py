"""Replay-verify speed vs raw env stepping, and ``hub-envs reproduce`` on 2 workers vs 1.

The example envs are pushed to a loopback Hub (``push_env``) and loaded back pinned, as a user would.
Variants: ``pendulum`` (state, the cheapest step: overhead shows most), ``pendulum_image`` (the
same with a 64x64 camera image, compared pixel for pixel) and ``hover`` (pybullet).

Measured side by side in each repeat (medians over ``repeats``):

* ``raw``: ``env = loaded.make()``; per episode ``reset(seed)`` then ``step(a)`` for the recorded
  actions; nothing kept, nothing compared (the limit).
* ``replay``: :func:`hub_envs.harness.replay.replay_dataset` on 1 worker: read the dataset, replay every
  episode through the rollout engine, compare every observation, reward, done/success flag and
  recorded state exactly. steps/s = replayed env steps / wall time.
* ``reproduce_w1`` / ``reproduce_w2``: the whole :func:`hub_envs.operations.reproduce` (load, fingerprint,
  replay, benchmark re-run, reports) on ``hover`` with 1 and 2 worker processes.

Figures: ``replay_vs_raw`` = min over variants of replay / raw (goal >= 0.8);
``reproduce_speedup_2workers`` = reproduce_w1 time / reproduce_w2 time (goal >= 1.6 on 2 idle cores).
The machine's load average and a calibration (pure CPU work on 2 forked processes vs 1, ``machine_2process_ceiling``)
are recorded: other processes on a shared machine lower the speedup.

Run: ``python benchmarks/bench_replay.py [--repeats 3] [--profile]``; ``run()`` returns the dict.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
VARIANTS = {"pendulum": ("pendulum", 30, None), "pendulum_image": ("pendulum", 10, "image"), "hover": ("hover", 16, None)}
REPRODUCE_VARIANT = "hover"
REPRODUCE_EPISODES = 24


def _env_folder(tmp: Path, name: str, edit: str | None) -> Path:
    src = REPO / "envs" / name
    if edit is None:
        return src
    dest = tmp / f"{name}-{edit}"
    shutil.copytree(src, dest, ignore=shutil.ignore_patterns("__pycache__"))
    cfg = dest / "config.py"
    cfg.write_text(cfg.read_text().replace('obs_type: str = "state"', 'obs_type: str = "pixels_agent_pos"'))
    return dest


def _raw(loaded, seeds: list[int], actions: list) -> float:
    env = loaded.make()
    steps = 0
    t = time.perf_counter()
    for seed, acts in zip(seeds, actions):
        env.reset(seed=seed)
        for a in acts:
            env.step(a)
            steps += 1
    dt = time.perf_counter() - t
    env.close()
    return steps / dt


def _replay(loaded) -> float:
    from hub_envs.harness.replay import replay_dataset

    t = time.perf_counter()
    result = replay_dataset(loaded.make, loaded.dataset_root, loaded.config.features_map, workers=1, progress=False)
    dt = time.perf_counter() - t
    assert result.ok, result.summary()
    return result.steps / dt


def _burn(n: int) -> int:
    s = 0
    for i in range(n):
        s += i * i
    return s


def _pool_ceiling(n: int = 2_000_000, tasks: int = 4) -> float:
    """Pure-Python CPU work on 2 forked processes vs 1: what this machine allows right now (2.0 when idle)."""
    import multiprocessing

    t = time.perf_counter()
    for _ in range(tasks):
        _burn(n)
    serial = time.perf_counter() - t
    with multiprocessing.get_context("fork").Pool(2) as pool:
        t = time.perf_counter()
        pool.map(_burn, [n] * tasks)
        parallel = time.perf_counter() - t
    return serial / parallel


def _reproduce(repo: str, workers: int, out: Path) -> float:
    from hub_envs import reproduce

    t = time.perf_counter()
    report = reproduce(repo, trust_remote_code=True, workers=workers, out=out, progress=False)
    dt = time.perf_counter() - t
    assert report.reproduced, report.summary()
    return dt


def run(repeats: int = 3, verbose: bool = True, profile: bool = False) -> dict:
    """Push the example envs to a loopback Hub, then measure; return the figures."""
    from hub_envs import load_env, push_env
    from hub_envs.dataset.reader import read_episode_frames, read_episode_meta
    from hub_envs.testing import HubServer, hub_environment

    results: dict = {"cpu_count": os.cpu_count(), "repeats": repeats, "load_average_before": os.getloadavg()}
    tmp = Path(tempfile.mkdtemp(prefix="bench-replay-"))
    try:
        with HubServer(tmp / "hub-data") as server, hub_environment(server.endpoint, tmp / "home"):
            repos = {}
            for variant, (name, episodes, edit) in VARIANTS.items():
                n = REPRODUCE_EPISODES if variant == REPRODUCE_VARIANT else episodes
                pushed = push_env(_env_folder(tmp, name, edit), f"bench/{variant}", episodes=n, progress=False)
                repos[variant] = f"bench/{variant}@{pushed.sha}"
            for variant, repo in repos.items():
                loaded = load_env(repo, trust_remote_code=True)
                metas = read_episode_meta(loaded.dataset_root)
                seeds = [m["seed"] for m in metas]
                actions = [read_episode_frames(loaded.dataset_root, m["episode_index"], keys=["action"])["action"] for m in metas]
                _replay(loaded)  # warm-up: imports, page cache
                raw, replay = [], []
                for _ in range(repeats):
                    raw.append(_raw(loaded, seeds, actions))
                    replay.append(_replay(loaded))
                r, p = statistics.median(raw), statistics.median(replay)
                results[variant] = {
                    "frames": sum(len(a) for a in actions),
                    "raw_steps_per_s": round(r, 1),
                    "replay_steps_per_s": round(p, 1),
                    "replay_vs_raw": round(p / r, 3),
                }
                if profile and variant == "pendulum":
                    import cProfile
                    import pstats

                    prof = cProfile.Profile()
                    prof.runcall(_replay, loaded)
                    print(f"\n--- cProfile, replay_dataset on {variant}, workers=1 (by tottime) ---")
                    pstats.Stats(prof).sort_stats("tottime").print_stats(20)
                loaded.unregister()
            repo = repos[REPRODUCE_VARIANT]
            _reproduce(repo, 2, tmp / "warm")
            times: dict[int, list[float]] = {1: [], 2: []}
            ceiling = []
            for i in range(repeats):
                for w in (1, 2):
                    times[w].append(_reproduce(repo, w, tmp / f"out-{w}-{i}"))
                ceiling.append(_pool_ceiling())
            t1, t2 = statistics.median(times[1]), statistics.median(times[2])
            results["reproduce"] = {
                "variant": REPRODUCE_VARIANT,
                "episodes": REPRODUCE_EPISODES,
                "seconds_w1": round(t1, 3),
                "seconds_w2": round(t2, 3),
                "machine_2process_ceiling": round(statistics.median(ceiling), 3),
            }
            results["reproduce_speedup_2workers"] = round(t1 / t2, 3)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    results["replay_vs_raw"] = min(results[v]["replay_vs_raw"] for v in VARIANTS)
    results["load_average_after"] = os.getloadavg()
    if verbose:
        print_table(results)
    return results


def print_table(results: dict) -> None:
    print(f"\nReplay-verify vs raw stepping, steps/s (median of {results['repeats']}, {results['cpu_count']} CPUs)")
    print(f"{'variant':15} {'frames':>7} {'raw':>10} {'replay':>10} {'ratio':>7}")
    for v in VARIANTS:
        r = results[v]
        print(
            f"{v:15} {r['frames']:>7} {r['raw_steps_per_s']:>10.0f} {r['replay_steps_per_s']:>10.0f} {r['replay_vs_raw']:>7.2f}"
        )
    rp = results["reproduce"]
    print(
        f"reproduce {rp['variant']} ({rp['episodes']} episodes): {rp['seconds_w1']:.2f}s on 1 worker, {rp['seconds_w2']:.2f}s on 2; "
        f"pure CPU work on 2 processes gets {rp['machine_2process_ceiling']:.2f}x on this machine right now"
    )
    la = results["load_average_before"]
    print(
        f"replay_vs_raw = {results['replay_vs_raw']:.2f} (goal >= 0.8), reproduce_speedup_2workers = "
        f"{results['reproduce_speedup_2workers']:.2f} (goal >= 1.6); load average before: {la[0]:.2f}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--profile", action="store_true", help="also print a cProfile of the replay")
    args = parser.parse_args()
    run(repeats=args.repeats, profile=args.profile)


if __name__ == "__main__":
    main()
