"""Isolated envs measured side by side with in-process ones and with gymnasium's own way to run an env in another
process: the cost of the worker process, on an idle machine and on a busy one.

The example envs ``envs/hover`` and ``envs/pendulum`` are pushed to a loopback Hub and loaded twice, in-process and
with ``isolation="process"``. Figures (medians over ``repeats``; in each sample the envs compared take turns of 50
steps, rotating who goes first, so that all of them see the same load of a shared machine):

* ``isolated_overhead_vs_gym_async``: (seconds per step of ``loaded.make()`` with the env in a worker process -
  seconds per step in-process) ÷ (the same for gymnasium's ``AsyncVectorEnv`` of that one env with shared memory -
  in-process): what isolation adds to a step, against what gymnasium's own subprocess env adds. The worse of
  pendulum and hover. Goal <= 0.5.
* ``isolated_overhead_vs_gym_async_busy``: the same while the benchmark keeps every other CPU busy (one
  ``python -c "while True: pass"`` per CPU but one: a training job, a second env, a browser). Goal <= 1.0.
* ``isolated_vec8_pendulum`` (and ``_busy``): steps/s of ``loaded.make_vec(8)`` isolated ÷ the in-process
  ``SyncVectorEnv`` of 8. Goal >= 0.7.
* ``isolated_warm_load``: seconds of ``load_env(isolation="venv")`` with its venv cached, ``make()`` and the first
  ``reset`` ÷ seconds of a bare ``python -c "import numpy, gymnasium"``. Goal <= 2.0.
* details (not goals): ``isolated_step_hover`` (steps/s isolated ÷ in-process), the sandboxed hover ratio,
  worker start-up, each runner's microseconds per step in both conditions, and the hover ratio with
  ``hub_envs.isolation.doorbell`` off (``*_sleeping``: both sides sleep at once) and with
  ``hub_envs.isolation.affinity`` off (``*_unpinned``).

Run: ``python -m benchmarks.bench_isolation [--repeats 5]``; ``run()`` returns the dict.
"""

from __future__ import annotations

import argparse
import contextlib
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


def _overhead_vs(rates: dict[str, list[float]], num: str, den: str, base: str = "in_process") -> float:
    """Median over samples of (num's seconds per step - base's) ÷ (den's - base's)."""
    ratios = [(1 / n - 1 / b) / (1 / d - 1 / b) for n, d, b in zip(rates[num], rates[den], rates[base], strict=True) if d < b]
    return round(statistics.median(ratios), 3) if ratios else math.inf


def _us_per_step(rates: dict[str, list[float]]) -> dict[str, float]:
    return {name: round(1e6 / statistics.median(r), 1) for name, r in rates.items()}


@contextlib.contextmanager
def _busy(n: int):
    """``n`` processes that keep a CPU busy each (``python -c "while True: pass"``), stopped on the way out."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]
    try:
        time.sleep(0.5)  # let them run
        yield
    finally:
        for proc in procs:
            proc.kill()
        for proc in procs:
            proc.wait()


def _gym_async(gym_id: str):
    """gymnasium's own way to run an env in another process: ``AsyncVectorEnv`` of one env, shared memory."""
    import gymnasium as gym

    return gym.vector.AsyncVectorEnv([lambda: gym.make(gym_id)], shared_memory=True, context="fork")


def _against_gym(here: dict, iso: dict, repeats: int, extra: dict | None = None) -> dict:
    """Per env: steps/s of in-process, isolated and gymnasium's AsyncVectorEnv(1), interleaved."""
    out = {}
    for name in ("pendulum", "hover"):
        envs = {"gym_async": _gym_async(here[name].gym_id), "in_process": here[name].make(), "isolated": iso[name].make()}
        try:
            runners = {n: (env, None) for n, env in envs.items()}
            runners.update((extra or {}).get(name, lambda envs: {})(envs))
            out[name] = _ratios(runners, STEPS[name], repeats)
        finally:
            for env in envs.values():
                env.close()
    return out


def _vec8(here: dict, iso: dict, repeats: int) -> dict:
    vecs = {"isolated": iso["pendulum"].make_vec(8), "in_process": here["pendulum"].make_vec(8)}
    try:
        return _ratios({n: (env, None) for n, env in vecs.items()}, STEPS["pendulum"], repeats)
    finally:
        for env in vecs.values():
            env.close()


def run(repeats: int = 5, verbose: bool = True) -> dict:
    from hub_envs import load_env, push_env
    from hub_envs.isolation.doorbell import available_cpus
    from hub_envs.isolation.sandbox import sandbox_support
    from hub_envs.testing import HubServer, hub_environment

    out: dict = {"sandbox_support": sandbox_support()}
    burners = max(1, available_cpus() - 1)
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

            # idle: isolated, in-process and gymnasium's AsyncVectorEnv side by side; for hover also the sandboxed
            # env and the isolated one with the busy-wait off (sleeping) and with affinity off (unpinned)
            def hover_details(envs: dict) -> dict:  # each its own env: a worker's choice of ways is its own
                envs.update(sandboxed=boxed.make(), sleeping=iso["hover"].make(), unpinned=iso["hover"].make())
                return {
                    "sandboxed": (envs["sandboxed"], None),
                    "isolated_sleeping": (envs["sleeping"], None, False),
                    "isolated_unpinned": (envs["unpinned"], False),
                }

            idle = _against_gym(here, iso, repeats, {"hover": hover_details})
            busy_vec8: dict = {}
            with _busy(burners):
                busy = _against_gym(here, iso, repeats)
                busy_vec8 = _vec8(here, iso, repeats)
            idle_vec8 = _vec8(here, iso, repeats)

            for suffix, rates in (("", idle), ("_busy", busy)):
                per_env = {name: _overhead_vs(r, "isolated", "gym_async") for name, r in rates.items()}
                out[f"isolated_overhead_vs_gym_async{suffix}"] = max(per_env.values())
                out[f"isolated_overhead_vs_gym_async{suffix}_per_env"] = per_env
                out[f"isolated_step_hover{suffix}"] = _median_ratio(rates["hover"], "isolated")
                out[f"gym_async_step_hover{suffix}"] = _median_ratio(rates["hover"], "gym_async")
                out[f"us_per_step{suffix}"] = {name: _us_per_step(r) for name, r in rates.items()}
            out["isolated_step_hover_sleeping"] = _median_ratio(idle["hover"], "isolated_sleeping")
            out["isolated_step_hover_unpinned"] = _median_ratio(idle["hover"], "isolated_unpinned")
            out["sandboxed_step_hover"] = _median_ratio(idle["hover"], "sandboxed")
            out["isolated_vec8_pendulum"] = _median_ratio(idle_vec8, "isolated")
            out["isolated_vec8_pendulum_busy"] = _median_ratio(busy_vec8, "isolated")
            out["vec8_pendulum_steps_per_s"] = {name: round(statistics.median(r)) for name, r in idle_vec8.items()}
            out["busy_cpus"] = burners

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
