"""Start-up of the command line: what a user waits for before ``hub-envs`` says anything.

Each command runs as a fresh process (the console scripts of this venv), ``repeats`` times in turn with
a bare ``python -c pass`` of the same interpreter, so both see the same machine load. The help
screens and ``hub-envs trust`` must not import torch or lerobot (``tests/test_compat.py`` asserts
that; this measures what it buys).

* ``cli_help_s``: median wall seconds of ``hub-envs --help``. Goal <= 0.5.
* ``cli_trust_s``: median wall seconds of ``hub-envs trust user/name@<sha>`` of a repo on a loopback Hub (it
  reads the commit's manifest, to trust that content, and writes the trust list of a throwaway
  ``HUB_ENVS_HOME``). Goal <= 0.5.
* ``push_env_help_s``: median wall seconds of ``push_env --help``. Goal <= 0.5.
* ``cli_help_vs_python``: ``hub-envs --help`` ÷ ``python -c pass`` (the interpreter's own start-up).

Run: ``python -m benchmarks.bench_startup [--repeats 7]``; ``run()`` returns the dict.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

BIN = Path(sys.executable).parent


def _wall(cmd: list[str], env: dict) -> float:
    t = time.perf_counter()
    subprocess.run(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
    return time.perf_counter() - t


def run(repeats: int = 7) -> dict:
    from hub_envs import push_env
    from hub_envs.testing import HubServer, hub_environment

    with tempfile.TemporaryDirectory() as tmp, HubServer(Path(tmp) / "hub-data") as server:
        with hub_environment(server.endpoint, Path(tmp) / "pusher"):
            sha = push_env(
                Path(__file__).resolve().parent.parent / "envs" / "pendulum", "bench/startup", episodes=2, progress=False
            ).sha
        home = Path(tmp) / "home"
        env = {
            **os.environ,
            "HUB_ENVS_HOME": str(home),
            "HF_HOME": str(Path(tmp) / "hf"),
            "HF_ENDPOINT": server.endpoint,
            "HF_HUB_DISABLE_TELEMETRY": "1",
        }
        commands = {
            "python": [sys.executable, "-c", "pass"],
            "cli_help_s": [str(BIN / "hub-envs"), "--help"],
            "cli_trust_s": [str(BIN / "hub-envs"), "trust", f"bench/startup@{sha}"],
            "push_env_help_s": [str(BIN / "push_env"), "--help"],
        }
        times: dict[str, list[float]] = {name: [] for name in commands}
        for _ in range(repeats):  # interleaved: every command sees the same load
            for name, cmd in commands.items():
                times[name].append(_wall(cmd, env))
    med = {name: statistics.median(ts) for name, ts in times.items()}
    return {
        "cli_help_s": round(med["cli_help_s"], 3),
        "cli_trust_s": round(med["cli_trust_s"], 3),
        "push_env_help_s": round(med["push_env_help_s"], 3),
        "cli_help_vs_python": round(med["cli_help_s"] / med["python"], 2),
        "python_startup_s": round(med["python"], 3),
        "samples": {name: [round(t, 3) for t in ts] for name, ts in times.items()},
    }


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    print(json.dumps(run(parser.parse_args().repeats), indent=2))
