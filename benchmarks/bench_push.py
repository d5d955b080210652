"""What a push costs before it publishes: ``build`` (checks, dataset, fingerprint, GIF, card) per example env.

For ``envs/pendulum`` and ``envs/hover``: seconds of ``build`` for 10 episodes on one worker
(median of ``repeats``), and how many times the env class was constructed during it (every
``make()`` in the process: checks, dataset, fingerprint, GIF, card). Publishing is measured by
``bench_server``. Figures: ``push_build_s_<env>`` and ``push_env_constructions_<env>``; the issue
that straightened push's data flow compares them with the figures before the change (its note).

``repush_unchanged_vs_push``: wall seconds of a second ``push_env`` of hover with nothing changed
(main already holds it: no dataset, no checks, no commit) ÷ the first, full push, to a loopback Hub,
alternating new repos per repeat. Goal <= 0.1.

``push_env_peak_rss_mb_<n>`` / ``push_env_rss_growth``: the peak RSS (``VmHWM``) of a ``push_env`` process of
hover with ``RSS_EPISODES`` episodes each (one process per push, same loopback Hub), and big ÷ small: push's
memory is bounded when that stays near 1 while the episodes grow 16x (the floor is the process's imports, torch
and lerobot among them). Not a goal.

Run: ``python -m benchmarks.bench_push [--repeats 3]``; ``run()`` returns the dict.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

from benchmarks import PRINT_PEAK_RSS_KIB

REPO = Path(__file__).resolve().parent.parent
ENVS = ("pendulum", "hover")


def _build_once(name: str, episodes: int) -> tuple[float, int]:
    from hub_envs import load_env
    from hub_envs.publishing.build import build

    loaded = load_env(REPO / "envs" / name, check=False)
    cls = loaded.env_class
    count = [0]
    original = cls.__init__

    def counting_init(self, *args, **kwargs):
        count[0] += 1
        original(self, *args, **kwargs)

    cls.__init__ = counting_init
    try:
        with tempfile.TemporaryDirectory() as tmp:
            staging = Path(tmp) / "repo"
            staging.mkdir()
            t = time.perf_counter()
            build(loaded, staging, repo_id=f"bench/{name}", episodes=episodes, seed=0, workers=1, progress=False)
            return time.perf_counter() - t, count[0]
    finally:
        cls.__init__ = original
        loaded.unregister()


def _repush(repeats: int, episodes: int) -> dict:
    from hub_envs import push_env
    from hub_envs.testing import HubServer, hub_environment

    full, again = [], []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        with HubServer(tmp / "hub-data") as server, hub_environment(server.endpoint, tmp / "home"):
            for i in range(repeats):
                repo = f"bench/hover-{i}"
                t = time.perf_counter()
                push_env(REPO / "envs" / "hover", repo, episodes=episodes, progress=False)
                full.append(time.perf_counter() - t)
                t = time.perf_counter()
                result = push_env(REPO / "envs" / "hover", repo, episodes=episodes, progress=False)
                again.append(time.perf_counter() - t)
                assert not result.created_commit
    return {
        "full_push_s": [round(x, 3) for x in full],
        "unchanged_repush_s": [round(x, 3) for x in again],
        "repush_unchanged_vs_push": round(statistics.median(again) / statistics.median(full), 3),
    }


RSS_EPISODES = (100, 1600)


def _push_rss() -> dict:
    import os
    import subprocess
    import sys

    from hub_envs.testing import HubServer, hub_environment

    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        with HubServer(tmp / "hub-data") as server, hub_environment(server.endpoint, tmp / "home"):
            for n in RSS_EPISODES:
                script = (
                    "from hub_envs import push_env; "
                    f"push_env({str(REPO / 'envs' / 'hover')!r}, 'bench/hover-rss-{n}', episodes={n}, progress=False); "
                    + PRINT_PEAK_RSS_KIB
                )
                done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=os.environ, check=True)
                out[f"push_env_peak_rss_mb_{n}"] = round(int(done.stdout.split()[-1]) / 1024)
    small, big = (out[f"push_env_peak_rss_mb_{n}"] for n in RSS_EPISODES)
    out["push_env_rss_growth"] = round(big / small, 3)
    return out


def run(repeats: int = 3, episodes: int = 10) -> dict:
    out: dict = {"episodes": episodes, "workers": 1}
    for name in ENVS:
        times, counts = [], []
        for _ in range(repeats):
            seconds, constructions = _build_once(name, episodes)
            times.append(seconds)
            counts.append(constructions)
        out[name] = {"seconds": times, "env_constructions": counts}
        out[f"push_build_s_{name}"] = round(statistics.median(times), 3)
        out[f"push_env_constructions_{name}"] = max(counts)
    repush = _repush(repeats, episodes)
    out["repush"] = repush
    out["repush_unchanged_vs_push"] = repush["repush_unchanged_vs_push"]
    out.update(_push_rss())
    return out


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    print(json.dumps(run(args.repeats), indent=2))
