"""``make bench``: run every benchmark, print one table of figures against their goals, write JSON and the README.

Each figure is a ratio measured side by side in one run (medians of several repeats: the machine
may be shared and noisy). The figures and every module's details go to ``benchmarks/out/latest.json``; a run of
some modules (``--only``) replaces theirs there and keeps the others'. ``benchmarks/README.md`` (each figure,
its goal, the last value and when it was measured) is generated from that file, at the end of every full run
or on demand:

    python -m benchmarks.run                         # all of them (several minutes); writes the README too
    python -m benchmarks.run --only load download    # some; --write-readme to update the README from them too
    python -m benchmarks.run --write-readme          # run nothing: the README from benchmarks/out/latest.json

The modules run in this order, ``bench_load`` first: it forks its "fresh process" for warm loads
before anything imports env code or a simulator. A module that is missing (``bench_replay`` may not
be there yet) or that fails is reported as such; the others still run.
"""

from __future__ import annotations

import argparse
import importlib
import json
import operator
import os
import platform
import sys
import time
import traceback
from datetime import UTC, datetime
from pathlib import Path

OUT = Path(__file__).resolve().parent / "out" / "latest.json"
README = Path(__file__).resolve().parent / "README.md"

#: module -> keyword arguments of its run()
MODULES: dict[str, dict] = {
    "bench_load": {"repeats": 9},
    "bench_startup": {"repeats": 7},
    "bench_first_step": {"repeats": 7},
    "bench_download": {"clients": 8, "size_mb": 32, "repeats": 3},
    "bench_datagen": {"repeats": 5},
    "bench_replay": {"repeats": 5},
    "bench_eval": {"repeats": 3, "episodes": 100},
    "bench_server": {"repeats": 3, "n_files": 100, "size_mb": 16},
    "bench_push": {"repeats": 3},
    "bench_pages": {"rounds": 5, "requests_per_round": 100},
    "bench_isolation": {"repeats": 5},
    "bench_lfs": {"push_mb": 1024, "size_mb": 64, "big_mb": 200, "repeats": 9},
    "bench_video": {"episodes": 20},
    "bench_ray": {"repeats": 2},
}

GE, LE, EQ = (">=", operator.ge), ("<=", operator.le), ("==", operator.eq)
#: figure -> (module that measures it, goal or None, what it is)
FIGURES: dict[str, tuple[str, tuple | None, str]] = {
    "wrapper_overhead_pendulum": ("bench_load", (GE, 0.95), "steps/s via load_env ÷ EnvClass(**gym_kwargs)"),
    "wrapper_overhead_hover": ("bench_load", (GE, 0.95), "same, pybullet quadrotor"),
    "warm_load_vs_lerobot": ("bench_load", (LE, 1.0), "warm load_env with checks ÷ lerobot make_env (worst env)"),
    "warm_load_vs_lerobot_pendulum": ("bench_load", (LE, 1.0), "  pendulum"),
    "warm_load_vs_lerobot_hover": ("bench_load", (LE, 1.0), "  hover"),
    "warm_load_check_share": ("bench_load", None, "share of the check stage in the worst warm load"),
    "warm_load_no_checks_vs_lerobot": ("bench_load", None, "warm load_env with check=False ÷ lerobot make_env (worst env)"),
    "cold_load_vs_snapshot": ("bench_load", (LE, 1.2), "cold load_env ÷ snapshot_download + import (worst env)"),
    "cold_load_vs_snapshot_pendulum": ("bench_load", (LE, 1.2), "  pendulum"),
    "cold_load_vs_snapshot_hover": ("bench_load", (LE, 1.2), "  hover"),
    "first_files_direct_vs_hf": ("bench_load", None, "a cold load's first files: one GET each ÷ hf_hub_download (worst env)"),
    "datagen_vs_lerobot": ("bench_datagen", (GE, 3.0), "dataset frames/s ÷ LeRobot add_frame/save_episode"),
    "datagen_vs_raw": ("bench_datagen", (GE, 0.6), "dataset frames/s ÷ raw env stepping (worst variant: state, image)"),
    "png_helper_start_ms": (
        "bench_datagen",
        None,
        "  ms a process's first camera dataset pays to fork the PNG helper (and end it)",
    ),
    "replay_vs_raw": ("bench_replay", (GE, 0.8), "replay-verify steps/s ÷ raw env stepping"),
    "reproduce_parallel_efficiency": (
        "bench_replay",
        (GE, 0.95),
        "reproduce's 2-worker speedup ÷ pure CPU work's on 2 processes, measured right after it (the host's ceiling)",
    ),
    "reproduce_speedup_2workers": ("bench_replay", None, "  reproduce on 1 worker ÷ on 2 (time)"),
    "reproduce_parallel_efficiency_vs_env": (
        "bench_replay",
        None,
        "  the same speedup ÷ the env's own, stepped raw on 2 forked processes vs 1 right after it",
    ),
    "eval_vs_lerobot_eval": (
        "bench_eval",
        (GE, 1.5),
        "episodes/s: hub-envs evaluate ÷ lerobot-eval at batch 1 (the same episodes), tiny TD-MPC checkpoint, pendulum, 100 seeds",
    ),
    "eval_success_rate_difference": ("bench_eval", (EQ, 0), "  largest success rate difference among the three, same seeds"),
    "eval_return_max_abs_difference": (
        "bench_eval",
        None,
        "  largest per-episode return difference to lerobot-eval at batch 1 (float summation order)",
    ),
    "eval_vs_lerobot_eval_batch10": (
        "bench_eval",
        None,
        "  same ÷ lerobot-eval --eval.batch_size=10 (batched inference: other float arithmetic, so not quite the same episodes)",
    ),
    "cli_help_s": ("bench_startup", (LE, 0.5), "seconds: hub-envs --help (no torch, no lerobot)"),
    "cli_trust_s": ("bench_startup", (LE, 0.5), "seconds: hub-envs trust user/name@<sha>"),
    "push_env_help_s": ("bench_startup", (LE, 0.5), "seconds: push_env --help"),
    "cli_help_vs_python": ("bench_startup", None, "hub-envs --help ÷ python -c pass"),
    "first_step_vs_gymnasium": (
        "bench_first_step",
        (LE, 3.0),
        "a fresh process from import to first step: load_env of a cached state-only env (pendulum) ÷ gymnasium.make('Pendulum-v1')",
    ),
    "first_step_peak_rss_mb": ("bench_first_step", None, "  MiB: that process's peak RSS (gymnasium's beside it in the details)"),
    "first_step_lerobot_vs_gymnasium": (
        "bench_first_step",
        None,
        "  the same with LeRobot's make_env of that repo ÷ gymnasium's",
    ),
    "server_download_mb_s": ("bench_download", None, "MiB/s to 8 concurrent snapshot_downloads"),
    "server_errors": ("bench_download", (EQ, 0), "failed or corrupt downloads among them"),
    "push_build_s_pendulum": ("bench_push", None, "seconds: push's local work (checks, dataset, card), pendulum, 10 eps"),
    "push_build_s_hover": ("bench_push", None, "  same, hover"),
    "push_env_peak_rss_mb_100": ("bench_push", None, "MiB: push_env's peak RSS, hover 100 episodes"),
    "push_env_peak_rss_mb_1600": ("bench_push", None, "  same, 1600 episodes"),
    "push_env_rss_growth": ("bench_push", None, "  1600 ÷ 100 (bounded: near 1)"),
    "push_env_constructions_pendulum": ("bench_push", None, "env objects built during that push, pendulum"),
    "push_env_constructions_hover": ("bench_push", None, "  same, hover"),
    "repush_unchanged_vs_push": ("bench_push", (LE, 0.1), "seconds: unchanged re-push of hover ÷ its first push"),
    "repo_page_rps": ("bench_pages", None, "requests/s: an env's web page (one client, keep-alive)"),
    "api_info_rps": ("bench_pages", None, "requests/s: GET /api/models/{repo} beside it (the same client)"),
    "repo_page_vs_api": ("bench_pages", None, "repo page ÷ API request (requests/s)"),
    "isolated_overhead_vs_gym_async": (
        "bench_isolation",
        (LE, 0.5),
        "isolated step's cost over in-process ÷ gymnasium AsyncVectorEnv(1, shared memory)'s (worse of pendulum, hover)",
    ),
    "isolated_overhead_vs_gym_async_busy": (
        "bench_isolation",
        (LE, 1.0),
        "  same, every other CPU kept busy (a python -c 'while True: pass' per CPU but one)",
    ),
    "isolated_step_hover": ("bench_isolation", None, "steps/s of hover in a worker process ÷ in-process"),
    "isolated_step_hover_busy": ("bench_isolation", None, "  same, every other CPU kept busy"),
    "isolated_vec8_pendulum": ("bench_isolation", (GE, 0.7), "8 pendulums in isolated workers ÷ in-process SyncVectorEnv of 8"),
    "isolated_vec8_pendulum_busy": ("bench_isolation", (GE, 0.7), "  same, every other CPU kept busy"),
    "isolated_warm_load": (
        "bench_isolation",
        (LE, 2.0),
        "load_env(isolation='venv') cached + make + reset ÷ python -c 'import numpy, gymnasium'",
    ),
    "isolated_step_hover_sleeping": (
        "bench_isolation",
        None,
        "  hover in a worker, both sides sleeping in the socket (hub_envs.isolation.doorbell off) ÷ in-process",
    ),
    "sandboxed_step_hover": ("bench_isolation", None, "steps/s of hover in a sandboxed worker ÷ in-process"),
    "worker_start_s": ("bench_isolation", None, "seconds: start a worker and import hover's code"),
    "sandboxed_worker_start_s": ("bench_isolation", None, "seconds: the same, sandboxed"),
    "server_push_rss_mb": ("bench_lfs", (LE, 300), "MiB: server peak RSS over a 1 GiB push (LFS, streamed)"),
    "client_push_rss_mb": ("bench_lfs", None, "MiB: pushing client's peak RSS over that push"),
    "lfs_upload_vs_regular": ("bench_lfs", None, "64 MiB file up through LFS ÷ inline base64 (MiB/s)"),
    "lfs_download_mb_s": ("bench_lfs", None, "MiB/s: hf_hub_download of that LFS file"),
    "cold_load_big_vs_small": ("bench_lfs", (LE, 1.1), "cold load_env, 200 MiB dataset ÷ 1 MiB dataset (same env)"),
    "video_size_ratio": ("bench_video", (LE, 0.2), "dataset bytes, reach 20 eps: camera as MP4 (push_env's GOP 10) ÷ as PNG"),
    "video_size_ratio_lerobot_gop": ("bench_video", None, "  same with LeRobot's GOP 2 (--video_gop=2)"),
    "video_random_frame_ms": ("bench_video", None, "ms to decode one frame at a random time (LeRobot's decoder), GOP 10"),
    "video_random_frame_ms_lerobot_gop": ("bench_video", None, "  same, GOP 2"),
    "video_write_vs_png": ("bench_video", None, "seconds writing that dataset: MP4 ÷ PNG"),
    "video_worst_mean_abs_error": ("bench_video", None, "worst decoded frame's mean |error| (0-255; replay accepts <= 8)"),
    "video_min_psnr_db": ("bench_video", None, "lowest per-frame PSNR of the decoded frames (dB)"),
    "ray_vs_local_reproduce": (
        "bench_ray",
        (GE, 0.8),
        "episodes/s, 200-episode hover reproduce: local Ray (2 CPUs) ÷ local backend (2 workers)",
    ),
    "ray_startup_s": ("bench_ray", None, "seconds: ray.init of that local Ray"),
    "ray_first_run_s": ("bench_ray", None, "seconds: its first reproduce (workers start, import, load the env)"),
    "ray_episode_ms": ("bench_ray", None, "ms of wall time per reproduced episode on Ray (2 workers)"),
    "local_episode_ms": ("bench_ray", None, "  same, local backend"),
}


def run(only: list[str] | None = None) -> dict:
    started = time.perf_counter()
    out: dict = {
        "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "machine": {
            "cpu_count": os.cpu_count(),
            "python": platform.python_version(),
            "platform": platform.platform(),
            "load_average_before": os.getloadavg(),
        },
        "details": {},
        "skipped": {},
    }
    for name, kwargs in MODULES.items():
        if only and name not in only and name.removeprefix("bench_") not in only:
            continue
        print(f"--- {name} ---", file=sys.stderr, flush=True)
        t = time.perf_counter()
        try:
            module = importlib.import_module(f"benchmarks.{name}")
        except ModuleNotFoundError as e:
            out["skipped"][name] = f"not present ({e})"
            print(f"{name}: skipped, {out['skipped'][name]}", file=sys.stderr)
            continue
        when, load = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"), os.getloadavg()
        try:
            out["details"][name] = module.run(**kwargs)
        except Exception as e:  # noqa: BLE001 - one failing benchmark must not hide the others
            out["skipped"][name] = f"failed: {type(e).__name__}: {e}"
            traceback.print_exc()
            continue
        out["details"][name]["seconds"] = round(time.perf_counter() - t, 1)
        out["details"][name]["measured"] = {"date": when, "load_average_before": load}
    _collect(out)
    out["machine"]["load_average_after"] = os.getloadavg()
    out["seconds"] = round(time.perf_counter() - started, 1)
    return out


def _collect(out: dict) -> None:
    """The figures and their verdicts, from the modules' details."""
    for figure, (module, _goal, _) in FIGURES.items():
        value = out["details"].get(module, {}).get(figure)
        if value is not None:
            out[figure] = value
    out["goals_met"] = {f: _verdict(out.get(f), FIGURES[f][1]) for f in FIGURES if FIGURES[f][1] and f in out}


def merge(previous: dict, new: dict) -> dict:
    """``new`` (a run of some modules) over ``previous`` (the last results): the modules ``new`` ran replace theirs,
    the others' details, figures and failures are kept."""
    merged = {**new, "details": {**previous.get("details", {}), **new["details"]}}
    merged["skipped"] = {k: v for k, v in previous.get("skipped", {}).items() if k not in new["details"]} | new["skipped"]
    for figure in FIGURES:
        merged.pop(figure, None)
    _collect(merged)
    return merged


def _verdict(value, goal) -> bool | None:
    if value is None or goal is None:
        return None
    (_, op), threshold = goal
    return bool(op(value, threshold))


def table(out: dict) -> str:
    """The figures as a Markdown table (what the README shows)."""
    rows = ["| figure | value | goal | verdict | what |", "|---|---:|---|---|---|"]
    for figure, (module, goal, what) in FIGURES.items():
        value = out.get(figure)
        shown = (
            "—"
            if value is None
            else (
                f"{value:.0f}"
                if figure == "server_download_mb_s" or figure.endswith("_rps")
                else f"{value:.0%}"
                if figure.endswith("share")
                else f"{value:g}"
            )
        )
        goal_text = f"{goal[0][0]} {goal[1]:g}" if goal else "—"
        verdict = (
            ("pass" if _verdict(value, goal) else "**fail**")
            if goal and value is not None
            else ("not run" if value is None else "info")
        )
        if value is None and module in out.get("skipped", {}):
            verdict = f"not run: {out['skipped'][module][:60]}"
        rows.append(f"| `{figure}` | {shown} | {goal_text} | {verdict} | {what} |")
    return "\n".join(rows)


def readme(out: dict) -> str:
    """``benchmarks/README.md``: every figure with its goal, the last value measured and when (from ``out``)."""
    runs = []
    for module in MODULES:
        measured = out.get("details", {}).get(module, {}).get("measured")
        if measured:
            la = measured.get("load_average_before") or [float("nan")]
            runs.append(f"`{module}` {measured['date']} (load average {la[0]:.2f} before)")
        elif module in out.get("skipped", {}):
            runs.append(f"`{module}` {out['skipped'][module][:80]}")
    machine = out.get("machine", {})
    return "\n".join(
        [
            "# Benchmarks",
            "",
            "<!-- Generated by `python -m benchmarks.run` (every full run, or `--write-readme`) from",
            "     benchmarks/out/latest.json. Do not edit by hand: the history of these values is in git. -->",
            "",
            "`make bench` runs every module of [`run.py`](run.py) (several minutes); `python -m benchmarks.run --only "
            "replay datagen` runs some (their results replace theirs in `benchmarks/out/latest.json`, the others' are "
            "kept) and `--write-readme` regenerates this page from that file. Each figure is a ratio of two things "
            "measured side by side in the same run, the median of several repeats: the machine is shared and noisy. "
            "What each module measures, and how, is in its docstring; the per-repeat values and every detail are in "
            "`benchmarks/out/latest.json`.",
            "",
            f"Last values on a {machine.get('cpu_count', '?')}-CPU machine, Python {machine.get('python', '?')}; measured: "
            + "; ".join(runs)
            + ".",
            "",
            table(out),
            "",
        ]
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--only", nargs="*", help="module names (load, startup, first_step, download, datagen, replay, eval, server, pages, ...)"
    )
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument(
        "--write-readme",
        action="store_true",
        help=f"write {README.relative_to(README.parent.parent)} from the results (alone: from --out, running nothing)",
    )
    args = parser.parse_args()
    previous = json.loads(args.out.read_text()) if args.out.is_file() else {}
    if args.write_readme and args.only is None:
        if not previous:
            raise SystemExit(f"{args.out} does not exist: run the benchmarks first (python -m benchmarks.run).")
        README.write_text(readme(previous))
        print(f"Written {README} from {args.out}")
        return
    out = run(args.only)
    if args.only:
        out = merge(previous, out)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=2, default=str) + "\n")
    la = out["machine"]["load_average_before"]
    print(
        f"\nBenchmarks, {out['date']} ({out['machine']['cpu_count']} CPUs, load average {la[0]:.2f} before, "
        f"{out['seconds']:.0f} s)\n"
    )
    print(table(out))
    print(f"\nWritten to {args.out}")
    if args.write_readme or not args.only:
        README.write_text(readme(out))
        print(f"Written {README}")


if __name__ == "__main__":
    main()
