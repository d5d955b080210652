"""Isolated envs measured side by side with in-process ones: the cost of the worker process.

The example envs ``envs/hover`` and ``envs/pendulum`` are pushed to a loopback Hub and loaded twice,
in-process and with ``isolation="process"``. Figures (medians over ``repeats``; each sample times both,
alternating which goes first):

* ``isolated_step_hover``: steps/s of ``loaded.make()`` with the env in a worker process ÷ steps/s of the
  in-process ``loaded.make()``; same seeded actions, same reset schedule. Goal >= 0.85.
* ``isolated_vec8_pendulum``: steps/s of ``loaded.make_vec(8)`` isolated (8 pendulums over the CPUs'
  worker processes, one message per worker per vector step, observations through shared memory) ÷ the
  in-process ``SyncVectorEnv`` of 8. Goal >= 0.7.
* ``isolated_warm_load``: seconds of ``load_env(isolation="venv")`` with its venv cached, ``make()`` (a worker
  started in the venv) and the first ``reset`` ÷ seconds of a bare ``python -c "import numpy, gymnasium"``.
  Goal <= 2.0.
* details: worker start-up (``Worker.start_seconds``: spawn, import the env's code, first answer) for
  a plain worker and a sandboxed one, and the sandboxed hover ratio (not a goal).

Run: ``python -m benchmarks.bench_isolation [--repeats 5]``; ``run()`` returns the dict.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
STEPS = {"hover": 1500, "pendulum": 800}


def _steps_per_s(env, steps: int, seed: int = 0) -> float:
    env.action_space.seed(seed)
    actions = [env.action_space.sample() for _ in range(steps)]
    env.reset(seed=seed)
    t = time.perf_counter()
    for a in actions:
        _, _, term, trunc, _ = env.step(a)
        if np.any(term) or np.any(trunc):
            if not hasattr(env, "num_envs"):
                env.reset()
    return steps / (time.perf_counter() - t)


def _ratio(make_isolated, make_here, steps: int, repeats: int) -> tuple[float, list[float], list[float]]:
    iso_env, here_env = make_isolated(), make_here()
    try:
        _steps_per_s(iso_env, 50)
        _steps_per_s(here_env, 50)  # warm both
        ratios, iso_rates, here_rates = [], [], []
        for i in range(repeats):
            if i % 2:
                h = _steps_per_s(here_env, steps, i)
                s = _steps_per_s(iso_env, steps, i)
            else:
                s = _steps_per_s(iso_env, steps, i)
                h = _steps_per_s(here_env, steps, i)
            ratios.append(s / h)
            iso_rates.append(s)
            here_rates.append(h)
        return statistics.median(ratios), iso_rates, here_rates
    finally:
        iso_env.close()
        here_env.close()


def run(repeats: int = 5, verbose: bool = True) -> dict:
    from hub_envs import load_env, push_env
    from hub_envs.isolation.sandbox import sandbox_support
    from hub_envs.testing import HubServer, hub_environment

    out: dict = {"sandbox_support": sandbox_support()}
    with tempfile.TemporaryDirectory() as tmp_s:
        tmp = Path(tmp_s)
        with HubServer(tmp / "hub-data") as server, hub_environment(server.endpoint, tmp / "hf"):
            refs = {
                name: f"bench/{name}@{push_env(REPO / 'envs' / name, f'bench/{name}', episodes=1, progress=False).sha}"
                for name in ("hover", "pendulum")
            }
            here = {n: load_env(r, trust_remote_code=True) for n, r in refs.items()}
            iso = {n: load_env(r, trust_remote_code=True, isolation="process", check=False) for n, r in refs.items()}
            boxed = load_env(refs["hover"], trust_remote_code=True, sandbox=True, check=False)

            starts, sandbox_starts = [], []
            for _ in range(repeats):
                env = iso["hover"].make()
                starts.append(env.unwrapped.worker.start_seconds)
                env.close()
                env = boxed.make()
                sandbox_starts.append(env.unwrapped.worker.start_seconds)
                env.close()
            out["worker_start_s"] = round(statistics.median(starts), 3)
            out["sandboxed_worker_start_s"] = round(statistics.median(sandbox_starts), 3)

            ratio, s, h = _ratio(iso["hover"].make, here["hover"].make, STEPS["hover"], repeats)
            out["isolated_step_hover"] = round(ratio, 3)
            out["hover_steps_per_s"] = {"isolated": round(statistics.median(s)), "in_process": round(statistics.median(h))}
            ratio, s, h = _ratio(boxed.make, here["hover"].make, STEPS["hover"], max(3, repeats // 2))
            out["sandboxed_step_hover"] = round(ratio, 3)

            # warm venv load: load_env(isolation="venv") with the venv cached, a worker started in it, first reset,
            # against a bare interpreter importing what the worker needs
            load_env(refs["pendulum"], trust_remote_code=True, isolation="venv", check=False)  # builds the venv once
            warm, bare = [], []
            for _ in range(repeats):
                t = time.perf_counter()
                loaded = load_env(refs["pendulum"], trust_remote_code=True, isolation="venv", check=False)
                env = loaded.make()
                env.reset(seed=0)
                warm.append(time.perf_counter() - t)
                env.close()
                t = time.perf_counter()
                subprocess.run([sys.executable, "-c", "import numpy, gymnasium"], check=True)
                bare.append(time.perf_counter() - t)
            out["isolated_warm_load"] = round(statistics.median(warm) / statistics.median(bare), 3)
            out["isolated_warm_load_s"] = round(statistics.median(warm), 3)

            ratio, s, h = _ratio(
                lambda: iso["pendulum"].make_vec(8), lambda: here["pendulum"].make_vec(8), STEPS["pendulum"], repeats
            )
            out["isolated_vec8_pendulum"] = round(ratio, 3)
            out["vec8_pendulum_steps_per_s"] = {
                "isolated": round(statistics.median(s)),
                "in_process": round(statistics.median(h)),
            }
    if verbose:
        print(json.dumps(out, indent=2))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    run(repeats=args.repeats)


if __name__ == "__main__":
    main()
