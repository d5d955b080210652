"""``hub-envs reproduce`` on a local Ray cluster vs the local backend, with the same 2 workers.

``envs/hover`` is pushed to a loopback Hub with ``EPISODES`` episodes (a ``--config.episode_length`` variant
keeps the run short) and reproduced, pinned, as a user would: the replay of every dataset episode plus the
re-run of the random-policy benchmark (the same number of episodes again), in one pass of the rollout engine.

* ``local``: ``reproduce(..., backend="local", workers=2)`` (a forked process pool).
* ``ray``: ``RayBackend(workers=2)`` with no address: a local Ray started with 2 CPUs (``ray_startup_s`` is
  how long ``ray.init`` took), then ``reproduce(..., backend=that)``: a first run (``ray_first_run_s``: the
  worker processes start, import hub-envs and lerobot and load the env) and ``repeats`` timed runs.

Figures: ``ray_vs_local_reproduce`` = episodes/s of the episode pass on Ray ÷ on the local backend (medians;
goal >= 0.8); ``ray_startup_s``; ``ray_episode_ms`` / ``local_episode_ms``: wall time per reproduced episode.

``--niceness``: then a second local Ray whose workers run at nice 0 (the backend keeps Ray's default, 15) is
measured the same way against the local backend (``ray_nice0_vs_local_reproduce``): what ``worker_niceness=0``
would be worth on a machine other work keeps busy (on an idle machine, nothing).

Run: ``python benchmarks/bench_ray.py [--repeats 2] [--niceness]``; ``run()`` returns the dict.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
EPISODES = 200
EPISODE_LENGTH = 60


def _episodes_seconds(report) -> float:
    return float(report.timings["episodes"])


def _side_by_side(repo: str, backend, repeats: int, kw: dict) -> tuple[list[float], list[float]]:
    """Episode-pass seconds of ``repeats`` reproductions, local then Ray in each repeat."""
    from hub_envs import reproduce

    local, remote = [], []
    for _ in range(repeats):
        local.append(_episodes_seconds(reproduce(repo, workers=2, **kw)))
        remote.append(_episodes_seconds(reproduce(repo, backend=backend, **kw)))
    return local, remote


def run(repeats: int = 2, verbose: bool = True, niceness: bool = False) -> dict:
    from hub_envs import push_env, reproduce
    from hub_envs.backends.ray import RayBackend
    from hub_envs.testing import HubServer, hub_environment

    out: dict = {"episodes": EPISODES, "episode_length": EPISODE_LENGTH, "load_average_before": os.getloadavg()}
    with tempfile.TemporaryDirectory(prefix="bench-ray-") as tmp_name:
        tmp = Path(tmp_name)
        with HubServer(tmp / "hub-data") as server, hub_environment(server.endpoint, tmp / "home"):
            t = time.perf_counter()
            pushed = push_env(
                REPO / "envs" / "hover",
                "bench/hover-ray",
                episodes=EPISODES,
                config={"episode_length": EPISODE_LENGTH},
                determinism_steps=10,
                progress=False,
            )
            out["push_s"] = round(time.perf_counter() - t, 2)
            repo = f"bench/hover-ray@{pushed.sha}"
            kw = {"trust_remote_code": True, "write": False, "progress": False}
            rollouts = None
            first = reproduce(repo, workers=2, **kw)  # warm: the snapshot in the cache, the check cache filled
            rollouts = len(first.replay.episodes) + sum(len(b.seeds) for b in first.benchmarks)
            assert first.reproduced, first.summary()
            backend = RayBackend(workers=2)
            with backend:
                out["ray_startup_s"] = round(backend.startup_seconds, 2)
                t = time.perf_counter()
                cold = reproduce(repo, backend=backend, **kw)
                out["ray_first_run_s"] = round(time.perf_counter() - t, 2)
                out["ray_first_run_episodes_s"] = round(_episodes_seconds(cold), 2)
                assert cold.reproduced, cold.summary()
                local, remote = _side_by_side(repo, backend, repeats, kw)
            if niceness:  # the same with the workers at nice 0
                nice = RayBackend(workers=2, worker_niceness=0)
                with nice:
                    assert reproduce(repo, backend=nice, **kw).reproduced  # warm its workers
                    local0, remote0 = _side_by_side(repo, nice, repeats, kw)
                out["nice0_local_episodes_s"] = [round(x, 3) for x in local0]
                out["nice0_ray_episodes_s"] = [round(x, 3) for x in remote0]
                out["ray_nice0_vs_local_reproduce"] = round(statistics.median(local0) / statistics.median(remote0), 3)
            out["rollouts_per_run"] = rollouts
            out["local_episodes_s"] = [round(x, 3) for x in local]
            out["ray_episodes_s"] = [round(x, 3) for x in remote]
            lm, rm = statistics.median(local), statistics.median(remote)
            out["local_episodes_per_s"] = round(rollouts / lm, 1)
            out["ray_episodes_per_s"] = round(rollouts / rm, 1)
            out["ray_vs_local_reproduce"] = round(lm / rm, 3)
            out["local_episode_ms"] = round(1000 * lm / rollouts, 2)
            out["ray_episode_ms"] = round(1000 * rm / rollouts, 2)
    out["load_average_after"] = os.getloadavg()
    if verbose:
        print(json.dumps(out, indent=2))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--niceness", action="store_true", help="also measure a local Ray at Ray's default niceness")
    args = parser.parse_args()
    run(repeats=args.repeats, niceness=args.niceness)


if __name__ == "__main__":
    main()
