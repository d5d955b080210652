"""A new process's first step: what every script, notebook kernel, CI job and worker waits for before its env moves.

The example env ``envs/pendulum`` (state observations) is pushed to a loopback Hub, trusted, and loaded once in a
process of its own (that load downloads it and runs and caches its checks). Then, ``repeats`` times in turn, three
fresh ``python`` processes of this interpreter time themselves from their first import to the end of their first
``step`` (``time.perf_counter`` around the lines below; the interpreter's own start-up is the same for all three and
left out) and report their peak RSS:

* hub-envs: ``from hub_envs import load_env; env = load_env("bench/pendulum@<sha>").make(); env.reset(seed=0);
  env.step(a)`` (the trust list gives consent, the checks' verdict is cached: a user's second run);
* gymnasium: ``import gymnasium; env = gymnasium.make("Pendulum-v1"); ...`` (a built-in env);
* LeRobot: ``from lerobot.envs.factory import make_env; make_env("bench/pendulum@<sha>", trust_remote_code=True)``,
  then a reset and a step of its vector env (LeRobot's own way to run a Hub env; informational).

Figures (medians):

* ``first_step_vs_gymnasium``: hub-envs' seconds ÷ gymnasium's. Goal <= 3.
* ``first_step_peak_rss_mb``: hub-envs' peak RSS, MiB. Goal <= 200 (gymnasium's and LeRobot's beside it, as info).
* ``first_step_lerobot_vs_gymnasium``: LeRobot's ``make_env`` seconds ÷ gymnasium's (info).
* each child also reports whether torch or lerobot got imported (``heavy_imports``).

``--env reach`` measures ``envs/reach`` instead (it declares an env processor, ``clip_action``, whose check's cached
verdict spares the first step torch and LeRobot too); gymnasium's Pendulum-v1 stays the baseline (info).

Run: ``python -m benchmarks.bench_first_step [--repeats 7] [--env reach]``; ``run()`` returns the dict.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent

_PRELUDE = "import time, sys\nt0 = time.perf_counter()\n"
_REPORT = (
    "seconds = time.perf_counter() - t0\n"
    "heavy = sorted({m.split('.')[0] for m in sys.modules} & {'torch', 'lerobot'})\n"
    # VmHWM, not ru_maxrss: a child's ru_maxrss keeps the peak of the process it was forked from (Linux keeps it over exec)
    "rss = int(next(l for l in open('/proc/self/status') if l.startswith('VmHWM')).split()[1]) / 1024\n"
    "print('RESULT', json.dumps({'seconds': seconds, 'rss_mb': rss, 'heavy_imports': heavy}))\n"
)
SCRIPTS = {
    "hub_envs": (
        "from hub_envs import load_env\n"
        "env = load_env(sys.argv[1]).make()\n"
        "env.reset(seed=0)\n"
        "env.step(env.action_space.sample())\n"
    ),
    "gymnasium": (
        "import gymnasium\nenv = gymnasium.make('Pendulum-v1')\nenv.reset(seed=0)\nenv.step(env.action_space.sample())\n"
    ),
    "lerobot": (
        "from lerobot.envs.factory import make_env\n"
        "envs = make_env(sys.argv[1], trust_remote_code=True)\n"
        "vec = next(iter(next(iter(envs.values())).values()))\n"
        "vec.reset(seed=0)\n"
        "vec.step(vec.action_space.sample())\n"
    ),
}


def _child(which: str, ref: str, env: dict) -> dict:
    code = _PRELUDE + SCRIPTS[which] + "import json\n" + _REPORT
    out = subprocess.run([sys.executable, "-c", code, ref], env=env, capture_output=True, text=True, timeout=600)
    lines = [line for line in out.stdout.splitlines() if line.startswith("RESULT ")]
    if out.returncode != 0 or not lines:
        raise RuntimeError(f"the {which} first-step process failed ({out.returncode}): {out.stderr[-2000:]}")
    return json.loads(lines[-1].removeprefix("RESULT "))


def run(repeats: int = 7, lerobot: bool = True, env_name: str = "pendulum") -> dict:
    from hub_envs import push_env, trust
    from hub_envs.testing import HubServer, hub_environment

    which = ["hub_envs", "gymnasium"] + (["lerobot"] if lerobot else [])
    with tempfile.TemporaryDirectory() as tmp, HubServer(Path(tmp) / "hub-data") as server:
        home = Path(tmp) / "hf"
        with hub_environment(server.endpoint, home):
            sha = push_env(REPO / "envs" / env_name, f"bench/{env_name}", episodes=2, progress=False).sha
            trust(f"bench/{env_name}", sha)
            env = {k: v for k, v in os.environ.items() if k != "PYTHONSTARTUP"}  # what hub_environment set, as a user has it
        ref = f"bench/{env_name}@{sha}"
        first = _child("hub_envs", ref, env)  # downloads, imports, runs the checks and caches their verdict
        samples: dict[str, list[dict]] = {w: [] for w in which}
        for _ in range(repeats):  # interleaved: every process sees the same machine load
            for w in which:
                samples[w].append(_child(w, ref, env))
    med = {w: statistics.median(s["seconds"] for s in samples[w]) for w in which}
    rss = {w: statistics.median(s["rss_mb"] for s in samples[w]) for w in which}
    out = {
        "first_step_vs_gymnasium": round(med["hub_envs"] / med["gymnasium"], 2),
        "first_step_peak_rss_mb": round(rss["hub_envs"], 1),
        "first_step_s": round(med["hub_envs"], 3),
        "gymnasium_first_step_s": round(med["gymnasium"], 3),
        "gymnasium_peak_rss_mb": round(rss["gymnasium"], 1),
        "first_load_s": round(first["seconds"], 3),
        "heavy_imports": sorted({m for s in samples["hub_envs"] for m in s["heavy_imports"]}),
        "samples": {w: [round(s["seconds"], 3) for s in samples[w]] for w in which},
    }
    if lerobot:
        out |= {
            "first_step_lerobot_vs_gymnasium": round(med["lerobot"] / med["gymnasium"], 2),
            "lerobot_first_step_s": round(med["lerobot"], 3),
            "lerobot_peak_rss_mb": round(rss["lerobot"], 1),
        }
    return out


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--no-lerobot", action="store_true", help="leave LeRobot's make_env out (it takes seconds a sample)")
    parser.add_argument("--env", default="pendulum", choices=["pendulum", "reach"], help="the example env (envs/<name>)")
    args = parser.parse_args()
    print(json.dumps(run(args.repeats, lerobot=not args.no_lerobot, env_name=args.env), indent=2))
