"""load_env measured side by side: wrapper overhead, warm load vs LeRobot's make_env, cold load vs a bare download.

The example envs ``envs/pendulum`` and ``envs/hover`` are pushed to a loopback Hub (``push_env``,
4 episodes) and loaded back pinned, as a user would. Figures (medians over ``repeats``, each a ratio
measured in the same run):

* ``wrapper_overhead_<env>``: steps/s of ``loaded.make()`` (``gym.make`` of the registered id:
  TimeLimit, OrderEnforcing) ÷ steps/s of ``EnvClass(**cfg.gym_kwargs)`` built directly; same
  seeded actions, same reset schedule, alternating which goes first. Goal >= 0.95.
* ``warm_load_vs_lerobot``: seconds of ``load_env("user/name@sha", trust_remote_code=True)`` (cached,
  with its integrity check and its feature and fingerprint checks) ÷ seconds of LeRobot's
  ``make_env("user/name@sha", trust_remote_code=True)`` on the same repo. Goal <= 1.0. Each sample
  runs in a fresh process, forked from a process that has imported only lerobot, hub-envs and
  gymnasium (no env code, no simulator, nothing registered), as a new ``python`` would after its
  imports; the samples of the two loaders alternate. Reported per env, with each stage's share
  (``LoadReport.timings``) and the same ratio with ``check=False``; the figure is the worst env.
* ``cold_load_vs_snapshot``: seconds of ``load_env`` into an empty Hugging Face cache over loopback
  (download, verification, import, registration, checks) ÷ seconds of a bare ``snapshot_download``
  into an empty cache plus importing the env and config classes with plain importlib. Goal <= 1.2.
  In one process, alternating; the env code is forgotten between samples.
* ``first_files_direct_vs_hf``: seconds to fetch the files a cold load needs before it can import (the env's
  code, assets, manifest and ``meta/info.json``), 8 at a time into an empty cache, with hub-envs' one ``GET``
  per file (``hub_io._get_into_cache``) ÷ with ``hf_hub_download`` (a ``HEAD``, then the ``GET``). Why
  hub-envs writes these into huggingface_hub's cache itself; alternating, worst env. Informational.

Run: ``python -m benchmarks.bench_load [--repeats 7] [--profile]``; ``run()`` returns the dict.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import json
import multiprocessing
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
ENVS = ("pendulum", "hover")
WRAPPER_STEPS = {"pendulum": 4000, "hover": 1200}


# --- fresh processes for warm loads ------------------------------------------------------------


def _warm_sample(which: str, ref: str, endpoint: str, home: str, check: bool) -> dict:
    from hub_envs.testing import hub_environment

    with hub_environment(endpoint, home):
        if which == "hub_envs":
            from hub_envs.loading.load import load_env

            t = time.perf_counter()
            loaded = load_env(ref, trust_remote_code=True, check=check)
            seconds = time.perf_counter() - t
            return {"seconds": seconds, "timings": loaded.report.timings}
        from lerobot.envs.factory import make_env

        t = time.perf_counter()
        make_env(ref, trust_remote_code=True)
        return {"seconds": time.perf_counter() - t}


class FreshProcesses:
    """Forks a 'zygote' that has imported lerobot, hub-envs and gymnasium and nothing env-specific;
    every :meth:`sample` forks a new process from it, runs one call, and reports back."""

    def __init__(self) -> None:
        import gymnasium  # noqa: F401  - what both loaders import before any env
        import lerobot.envs.factory  # noqa: F401

        import hub_envs.loading.load  # noqa: F401
        import hub_envs.testing  # noqa: F401

        ctx = multiprocessing.get_context("fork")
        self.conn, child = ctx.Pipe()
        self.process = ctx.Process(target=self._serve, args=(child,), daemon=True)
        self.process.start()

    @staticmethod
    def _serve(conn) -> None:
        while True:
            args = conn.recv()
            if args is None:
                return
            r, w = os.pipe()
            pid = os.fork()
            if pid == 0:  # the sample: a fresh copy of the zygote
                os.close(r)
                try:
                    result = _warm_sample(*args)
                except BaseException as e:  # noqa: BLE001
                    result = {"error": f"{type(e).__name__}: {e}"}
                os.write(w, json.dumps(result).encode())
                os._exit(0)
            os.close(w)
            with os.fdopen(r) as f:
                data = f.read()
            os.waitpid(pid, 0)
            conn.send(json.loads(data or '{"error": "the sample process died"}'))

    def sample(self, *args) -> dict:
        self.conn.send(args)
        result = self.conn.recv()
        if "error" in result:
            raise RuntimeError(f"warm-load sample {args[:2]} failed: {result['error']}")
        return result

    def close(self) -> None:
        self.conn.send(None)
        self.process.join(10)


# --- measurements ------------------------------------------------------------------------------


def _steps_per_s(env, actions, episode_length: int) -> float:
    env.reset(seed=0)
    t = time.perf_counter()
    for i, a in enumerate(actions):
        if i and i % episode_length == 0:
            env.reset(seed=i)
        env.step(a)
    return len(actions) / (time.perf_counter() - t)


def wrapper_overhead(loaded, n_steps: int, repeats: int) -> dict:
    import numpy as np

    raw_env = loaded.env_class(**loaded.config.gym_kwargs)
    hub_env = loaded.make()
    space = raw_env.action_space
    space.seed(0)
    actions = [space.sample() for _ in range(n_steps)]
    length = int(loaded.config.episode_length)
    _steps_per_s(raw_env, actions[:50], length), _steps_per_s(hub_env, actions[:50], length)  # warm up
    raw, hub = [], []
    for rep in range(repeats):
        order = [(raw_env, raw), (hub_env, hub)] if rep % 2 == 0 else [(hub_env, hub), (raw_env, raw)]
        for env, out in order:
            out.append(_steps_per_s(env, actions, length))
    raw_env.close()
    hub_env.close()
    ratios = [h / r for h, r in zip(hub, raw)]
    return {
        "raw_steps_per_s": round(statistics.median(raw)),
        "load_env_steps_per_s": round(statistics.median(hub)),
        "ratio": round(float(np.median(ratios)), 3),
        "wrappers": _wrappers(loaded),
    }


def _wrappers(loaded) -> list[str]:
    env, names = loaded.make(), []
    while hasattr(env, "env"):
        names.append(type(env).__name__)
        env = env.env
    return names


def _bare_import(path: Path, manifest, name: str) -> tuple:
    """What any loader must do at least: import the env's package with plain importlib."""
    spec = importlib.util.spec_from_loader(name, loader=None, is_package=True)
    pkg = importlib.util.module_from_spec(spec)
    pkg.__path__ = [str(path)]
    sys.modules[name] = pkg
    out = []
    for entry in (manifest.env_entry_point, manifest.config_entry_point):
        module, _, attr = entry.partition(":")
        out.append(getattr(importlib.import_module(f"{name}.{module}"), attr))
    return tuple(out)


def cold_load(repo: str, sha: str, endpoint: str, tmp: Path, repeats: int) -> dict:
    from huggingface_hub import snapshot_download

    from hub_envs.envcode.importing import forget_env_folder, module_key
    from hub_envs.loading.load import load_env
    from hub_envs.repo.format import Manifest
    from hub_envs.testing import hub_environment

    ours, bare, stages = [], [], []
    for rep in range(repeats + 1):  # the first round warms up imports and is dropped
        for which in ("ours", "bare") if rep % 2 == 0 else ("bare", "ours"):
            home = tmp / f"cold-{repo.replace('/', '-')}-{rep}-{which}"
            with hub_environment(endpoint, home):
                if which == "ours":
                    t = time.perf_counter()
                    loaded = load_env(f"{repo}@{sha}", trust_remote_code=True)
                    seconds = time.perf_counter() - t
                    loaded.unregister()
                    forget_env_folder(module_key(repo, sha))
                    if rep:
                        ours.append(seconds)
                        stages.append(loaded.report.timings)
                else:
                    name = f"bare_{rep}"
                    t = time.perf_counter()
                    path = Path(snapshot_download(repo, revision=sha))
                    _bare_import(path, Manifest.read(path), name)
                    seconds = time.perf_counter() - t
                    for m in [m for m in sys.modules if m == name or m.startswith(name + ".")]:
                        del sys.modules[m]
                    if rep:
                        bare.append(seconds)
            shutil.rmtree(home, ignore_errors=True)
    ratios = [a / b for a, b in zip(ours, bare)]
    return {
        "load_env_s": round(statistics.median(ours), 4),
        "snapshot_download_import_s": round(statistics.median(bare), 4),
        "ratio": round(statistics.median(ratios), 3),
        "stages_s": {k: round(statistics.median(s.get(k, 0.0) for s in stages), 4) for k in stages[0]},
    }


def first_files(repo: str, sha: str, endpoint: str, tmp: Path, repeats: int) -> dict:
    """The files a cold load fetches before anything else, by one GET each vs by hf_hub_download (see the docstring)."""
    import concurrent.futures

    from huggingface_hub import HfApi, hf_hub_download

    from hub_envs.loading.source import needed_first
    from hub_envs.repo import hub_io
    from hub_envs.repo.format import HUB_FILES, is_on_demand_file
    from hub_envs.testing import hub_environment

    with hub_environment(endpoint, tmp / "first-list"):
        siblings = HfApi().repo_info(repo, revision=sha).siblings or []
    names = [  # as hub_io.resolve_snapshot(lazy=True, first=needed_first) picks them
        s.rfilename
        for s in siblings
        if not is_on_demand_file(s.rfilename) and s.rfilename not in HUB_FILES and needed_first(s.rfilename)
    ]

    def direct(name: str) -> str | None:
        return hub_io._get_into_cache(repo, sha, name, token=None, cache_dir=None)

    def hf(name: str) -> str:
        return hf_hub_download(repo, name, revision=sha, repo_type=hub_io.REPO_TYPE)

    times: dict[str, list[float]] = {"direct": [], "hf": []}
    for rep in range(repeats + 1):  # the first round warms up and is dropped
        for which in ("direct", "hf") if rep % 2 == 0 else ("hf", "direct"):
            with hub_environment(endpoint, tmp / f"first-{which}-{rep}"):
                HfApi().repo_info(repo, revision=sha)  # the client's HTTP session exists before the clock starts
                with concurrent.futures.ThreadPoolExecutor(hub_io.MAX_WORKERS) as pool:
                    t = time.perf_counter()
                    got = list(pool.map(direct if which == "direct" else hf, names))
                    seconds = time.perf_counter() - t
                if which == "direct" and not all(got):
                    raise RuntimeError(f"{repo}: the one-GET fetch fell back to hf_hub_download for {names}: {got}")
                if rep:
                    times[which].append(seconds)
    return {
        "files": len(names),
        "direct_s": round(statistics.median(times["direct"]), 4),
        "hf_hub_download_s": round(statistics.median(times["hf"]), 4),
        "ratio": round(statistics.median(a / b for a, b in zip(times["direct"], times["hf"])), 3),
    }


def warm_load(zygote: FreshProcesses, ref: str, endpoint: str, home: str, repeats: int) -> dict:
    for which in ("hub_envs", "lerobot"):  # warm up: both loaders' first calls fill what they cache
        zygote.sample(which, ref, endpoint, home, True)
    ours, theirs, nocheck, stages = [], [], [], []
    for rep in range(repeats):
        calls = [("hub_envs", True), ("lerobot", True), ("hub_envs", False)]
        for which, check in calls if rep % 2 == 0 else calls[::-1]:
            result = zygote.sample(which, ref, endpoint, home, check)
            if which == "lerobot":
                theirs.append(result["seconds"])
            elif check:
                ours.append(result["seconds"])
                stages.append(result["timings"])
            else:
                nocheck.append(result["seconds"])
    med = statistics.median
    stage_s = {k: med(s.get(k, 0.0) for s in stages) for k in stages[0] if k != "total"}
    total = med(ours)
    return {
        "load_env_s": round(total, 4),
        "lerobot_make_env_s": round(med(theirs), 4),
        "load_env_no_checks_s": round(med(nocheck), 4),
        "ratio": round(med(a / b for a, b in zip(ours, theirs)), 3),
        "ratio_no_checks": round(med(a / b for a, b in zip(nocheck, theirs)), 3),
        "stage_share": {k: round(v / total, 3) for k, v in stage_s.items()},
        "check_share": round(stage_s.get("checks", 0.0) / total, 3),
    }


def profile_load(ref: str) -> None:
    """cProfile of one warm load_env in this process (by cumulative time)."""
    import cProfile
    import pstats

    from hub_envs.loading.load import load_env

    prof = cProfile.Profile()
    prof.enable()
    load_env(ref, trust_remote_code=True).unregister()
    prof.disable()
    print(f"\n--- cProfile, warm load_env({ref!r}) ---")
    pstats.Stats(prof).sort_stats("cumulative").print_stats(30)


def run(repeats: int = 7, verbose: bool = True, profile: bool = False) -> dict:
    """Push the example envs to a loopback Hub, then measure; return the figures."""
    zygote = FreshProcesses()  # before anything env-specific is imported in this process
    from hub_envs import load_env, push_env
    from hub_envs.testing import HubServer, hub_environment

    results: dict = {"repeats": repeats, "cpu_count": os.cpu_count(), "load_average_before": os.getloadavg()}
    tmp = Path(tempfile.mkdtemp(prefix="bench-load-"))
    try:
        with HubServer(tmp / "hub-data") as server:
            with hub_environment(server.endpoint, tmp / "pusher"):
                shas = {name: push_env(REPO / "envs" / name, f"bench/{name}", episodes=4, progress=False).sha for name in ENVS}
            home = tmp / "home"
            for name in ENVS:
                repo, sha = f"bench/{name}", shas[name]
                ref = f"{repo}@{sha}"
                with hub_environment(server.endpoint, home):
                    loaded = load_env(ref, trust_remote_code=True)  # fills the cache the warm loads use
                    results[f"wrapper_{name}"] = wrapper_overhead(loaded, WRAPPER_STEPS[name], repeats)
                    if profile:
                        profile_load(ref)
                    loaded.unregister()
                results[f"warm_{name}"] = warm_load(zygote, ref, server.endpoint, str(home), repeats)
                results[f"cold_{name}"] = cold_load(repo, sha, server.endpoint, tmp, repeats)
                results[f"first_files_{name}"] = first_files(repo, sha, server.endpoint, tmp, repeats)
                if verbose:
                    print(
                        f"{name}: wrapper {results[f'wrapper_{name}']['ratio']}, warm {results[f'warm_{name}']['ratio']} "
                        f"(checks {results[f'warm_{name}']['check_share']:.0%}), cold {results[f'cold_{name}']['ratio']}",
                        file=sys.stderr,
                    )
    finally:
        zygote.close()
        shutil.rmtree(tmp, ignore_errors=True)
    for name in ENVS:
        results[f"wrapper_overhead_{name}"] = results[f"wrapper_{name}"]["ratio"]
        results[f"warm_load_vs_lerobot_{name}"] = results[f"warm_{name}"]["ratio"]
        results[f"cold_load_vs_snapshot_{name}"] = results[f"cold_{name}"]["ratio"]
    worst_warm = max(ENVS, key=lambda n: results[f"warm_{n}"]["ratio"])
    results["warm_load_vs_lerobot"] = results[f"warm_{worst_warm}"]["ratio"]
    results["warm_load_check_share"] = results[f"warm_{worst_warm}"]["check_share"]
    results["warm_load_no_checks_vs_lerobot"] = max(results[f"warm_{n}"]["ratio_no_checks"] for n in ENVS)
    results["cold_load_vs_snapshot"] = max(results[f"cold_{n}"]["ratio"] for n in ENVS)
    results["first_files_direct_vs_hf"] = max(results[f"first_files_{n}"]["ratio"] for n in ENVS)
    results["load_average_after"] = os.getloadavg()
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--profile", action="store_true", help="also print a cProfile of a warm load_env")
    args = parser.parse_args()
    print(json.dumps(run(args.repeats, profile=args.profile), indent=2))


if __name__ == "__main__":
    main()
