"""Isolated envs measured side by side with in-process ones: the cost of the worker process.

The example envs ``envs/hover`` and ``envs/pendulum`` are pushed to a loopback Hub and loaded twice,
in-process and with ``isolation="process"``. Figures (medians over ``repeats``; in each sample the envs
compared take turns of 50 steps, rotating who goes first, so that all of them see the same load of a
shared machine):

* ``isolated_step_hover``: steps/s of ``loaded.make()`` with the env in a worker process ÷ steps/s of the
  in-process ``loaded.make()``; same seeded actions, same reset schedule. Goal >= 0.85.
* ``isolated_vec8_pendulum``: steps/s of ``loaded.make_vec(8)`` isolated (8 pendulums over the CPUs'
  worker processes, one message per worker per vector step, observations through shared memory) ÷ the
  in-process ``SyncVectorEnv`` of 8. Goal >= 0.7.
* ``isolated_warm_load``: seconds of ``load_env(isolation="venv")`` with its venv cached, ``make()`` (a worker
  started in the venv) and the first ``reset`` ÷ seconds of a bare ``python -c "import numpy, gymnasium"``.
  Goal <= 2.0.
* details: worker start-up (``Worker.start_seconds``: spawn, import the env's code, first answer) for
  a plain worker and a sandboxed one, the sandboxed hover ratio, and both step ratios again with
  ``hub_envs.isolation.affinity`` off (``*_unpinned``: the same workers, placed by the scheduler alone, as
  before the parent and its workers were kept on one CPU while they wait for each other) and the hover ratio
  with ``hub_envs.isolation.doorbell`` off (``*_sleeping``: the same worker, both sides sleeping in the socket
  instead of busy-waiting a moment first). ``isolated_step_hover_best_turn``: the same ratio from each runner's
  fastest turn of 50 steps over all samples (the cost of the worker where the host's other tenants did not reach:
  on a shared 2-CPU VM an isolated step keeps both CPUs busy and suffers more from them than one in-process, so
  the goal's ratio moves with the host's load). Not goals.

Run: ``python -m benchmarks.bench_isolation [--repeats 5]``; ``run()`` returns the dict.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
STEPS = {"hover": 1500, "pendulum": 800}


def _interleaved(runners: dict, steps: int, seed: int, chunk: int = 50, best: dict | None = None) -> dict[str, float]:
    """Steps/s of each runner ``name -> (env, pin)`` or ``(env, pin, spin)``, stepped in turns of ``chunk``
    steps (rotating who goes first), so that every one of them sees the same load of a shared machine. ``pin``
    sets ``hub_envs.isolation.affinity.enabled`` and ``spin`` ``hub_envs.isolation.doorbell.enabled`` for that
    runner's turns (None: leave it on). ``best`` collects each runner's fastest turn (seconds per step)."""
    from hub_envs.isolation import affinity, doorbell

    plans = {}
    for name, (env, *_) in runners.items():
        env.action_space.seed(seed)
        plans[name] = [env.action_space.sample() for _ in range(steps)]
        env.reset(seed=seed)
    spent = dict.fromkeys(runners, 0.0)
    names = list(runners)
    for turn, start in enumerate(range(0, steps, chunk)):
        for name in names[turn % len(names) :] + names[: turn % len(names)]:
            env, pin, *spin = runners[name]
            affinity.enabled = True if pin is None else pin
            doorbell.enabled = True if not spin or spin[0] is None else spin[0]
            t = time.perf_counter()
            for a in plans[name][start : start + chunk]:
                _, _, term, trunc, _ = env.step(a)
                if not hasattr(env, "num_envs") and (term or trunc):
                    env.reset()
            took = time.perf_counter() - t
            spent[name] += took
            if best is not None and start + chunk <= steps:
                best[name] = min(best.get(name, math.inf), took / chunk)
    affinity.enabled = doorbell.enabled = True
    return {name: steps / spent[name] for name in runners}


def _ratios(runners: dict, steps: int, repeats: int, best: dict | None = None) -> dict[str, list[float]]:
    """Steps/s per runner over ``repeats`` interleaved samples (after a warm-up); ``best`` as in :func:`_interleaved`."""
    _interleaved(runners, 50, 0, chunk=10)
    rates: dict[str, list[float]] = {name: [] for name in runners}
    for i in range(repeats):
        for name, rate in _interleaved(runners, steps, i, best=best).items():
            rates[name].append(rate)
    return rates


def _median_ratio(rates: dict[str, list[float]], num: str, den: str = "in_process") -> float:
    return round(statistics.median(a / b for a, b in zip(rates[num], rates[den], strict=True)), 3)


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

            envs = {"isolated": iso["hover"].make(), "in_process": here["hover"].make(), "sandboxed": boxed.make()}
            try:
                runners = {name: (env, None) for name, env in envs.items()}
                runners["isolated_unpinned"] = (envs["isolated"], False)  # the same worker, the scheduler placing it
                runners["isolated_sleeping"] = (envs["isolated"], None, False)  # the same worker, no busy-wait
                best: dict[str, float] = {}
                rates = _ratios(runners, STEPS["hover"], repeats, best)
            finally:
                for env in envs.values():
                    env.close()
            out["isolated_step_hover"] = _median_ratio(rates, "isolated")
            out["isolated_step_hover_best_turn"] = round(best["in_process"] / best["isolated"], 3)
            out["hover_best_turn_us_per_step"] = {name: round(s * 1e6, 1) for name, s in best.items()}
            out["isolated_step_hover_unpinned"] = _median_ratio(rates, "isolated_unpinned")
            out["isolated_step_hover_sleeping"] = _median_ratio(rates, "isolated_sleeping")
            out["sandboxed_step_hover"] = _median_ratio(rates, "sandboxed")
            out["hover_steps_per_s"] = {name: round(statistics.median(r)) for name, r in rates.items()}

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

            vecs = {"isolated": iso["pendulum"].make_vec(8), "in_process": here["pendulum"].make_vec(8)}
            try:
                runners = {name: (env, None) for name, env in vecs.items()}
                runners["isolated_unpinned"] = (vecs["isolated"], False)
                rates = _ratios(runners, STEPS["pendulum"], repeats)
            finally:
                for env in vecs.values():
                    env.close()
            out["isolated_vec8_pendulum"] = _median_ratio(rates, "isolated")
            out["isolated_vec8_pendulum_unpinned"] = _median_ratio(rates, "isolated_unpinned")
            out["vec8_pendulum_steps_per_s"] = {name: round(statistics.median(r)) for name, r in rates.items()}
            out["load_average"] = [round(x, 2) for x in os.getloadavg()]
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
