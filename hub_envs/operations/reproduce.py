"""``reproduce``: does a published env still produce its published data and results? Its dataset replayed step by
step (:mod:`hub_envs.harness.replay`), its benchmarks re-run (:mod:`hub_envs.harness.benchmark`), its fingerprint
recomputed, with the provenance of both sides, in ``report.json``, ``report.md`` and ``report.png``.

Example:
    >>> from hub_envs import reproduce                                                    # doctest: +SKIP
    >>> report = reproduce("user/pendulum-lerobot", revision="<sha>", trust_remote_code=True)  # doctest: +SKIP
    >>> report.reproduced, report.paths["markdown"]                                       # doctest: +SKIP
    (True, 'reproduce-out/user/pendulum-lerobot/report.md')
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Unpack

from hub_envs.backends import Backend, make_backend
from hub_envs.dataset.env_meta import read_env_meta
from hub_envs.dataset.reader import dataset_fingerprint, read_episode_meta
from hub_envs.errors import ConfigError, FingerprintMismatchError, ReproductionError
from hub_envs.harness.benchmark import BenchmarkResult, BenchmarkRun
from hub_envs.harness.checks import verify_fingerprint
from hub_envs.harness.provenance import (
    closure_only,
    closure_run_with,
    drift_kinds,
    drift_note,
    ranked_differences,
    run_provenance,
    worker_provenance,
)
from hub_envs.harness.replay import Replay, ReplayResult
from hub_envs.harness.report import ReproduceReport, TaskReproduction
from hub_envs.harness.report_files import default_out_dir
from hub_envs.loading.isolated import CodeRun, code_run
from hub_envs.loading.load import load_env
from hub_envs.repo.format import code_digest

__all__ = ["reproduce", "ReproduceReport"]

DEFAULT_OUT = Path("reproduce-out")


def _provenance(loaded: Any, dataset_root: Path | None) -> dict[str, Any]:
    m = loaded.manifest
    prov: dict[str, Any] = run_provenance(loaded)  # isolation="venv": the versions the worker ran with
    closure_here = closure_run_with(loaded)  # the rest of the requirements' closure (the simulator they pull in)
    diffs = ranked_differences(m, {**closure_here, **prov["versions_here"]})  # the env's requirements and theirs first
    prov |= {
        "code_digest": code_digest(m.files),
        "seeds": {
            "dataset": list(m.dataset.get("seeds", [])),
            "fingerprint": list(m.fingerprint.get("seeds", [])),
            "benchmarks": {_benchmark_key(b): list(b.get("seeds", [])) for b in m.benchmarks},
        },
        "versions_published": dict(m.versions),
        "closure_published": closure_only(m),
        "closure_here": closure_here,
        "version_differences": {k: list(v) for k, v in diffs.items()},
        # the same, ranked (a list: report.json sorts the keys of objects): the most suspect first
        "version_drift": [
            {"package": k, "published": a, "here": b, "kind": kind}
            for (k, (a, b)), kind in zip(diffs.items(), drift_kinds(diffs, m).values(), strict=True)
        ],
        "worker": worker_provenance(loaded),
    }
    if dataset_root is not None:
        prov["dataset_fingerprint"] = dataset_fingerprint(dataset_root)
        try:
            prov["dataset_code_digest"] = read_env_meta(dataset_root).get("code_digest")
        except ReproductionError:
            prov["dataset_code_digest"] = None
        prov["seeds"]["dataset"] = [m_.get("seed") for m_ in read_episode_meta(dataset_root)]
    return prov


def _benchmark_key(entry: dict[str, Any]) -> str:
    """A benchmark's name in the provenance: a suite's per-task entries share theirs, so the task is named with it."""
    return f"{entry.get('name')} [{entry['task']}]" if entry.get("task") else str(entry.get("name"))


def _fingerprint(loaded: Any, ran: dict[int, Any] | None = None, recorded: dict[str, Any] | None = None) -> dict[str, Any]:
    """Recompute the manifest's golden-rollout fingerprint (``recorded``: a suite task's); ``ran``: random-policy
    rollouts by seed that the episodes pass ran already (:func:`_run_episodes`), used when they cover its seeds."""
    recorded = loaded.manifest.fingerprint if recorded is None else recorded
    if not recorded:
        return {"status": "none recorded", "ok": True}
    ran = ran or {}
    episodes = [ran[s] for s in recorded["seeds"]] if all(s in ran for s in recorded["seeds"]) else None
    try:
        verify_fingerprint(
            loaded.make,
            recorded,
            where=f"{loaded.repo_id}@{loaded.revision}",
            versions_note=lambda: drift_note(loaded),
            episodes=episodes,
        )
    except FingerprintMismatchError as e:
        return {"status": "drifted", "ok": False, "message": str(e).splitlines()[0], "digest": recorded.get("digest")}
    return {
        "status": f"matches ({len(recorded['seeds'])} seeds x {recorded['steps']} steps)",
        "ok": True,
        "digest": recorded.get("digest"),
    }


def _run_episodes(
    loaded: Any,
    *,
    replay: bool,
    benchmarks: bool,
    tolerance: float,
    backend: Backend,
    episodes: list[int] | None,
    resamples: int,
    progress: bool,
    token: str | None,
    timings: dict[str, float],
    trust_policy_code: bool = False,
    keep: tuple[list[int], int] = ([], 0),
    kept: dict[int, Any] | None = None,
    declared: list[dict[str, Any]] | None = None,
) -> tuple[ReplayResult | None, list[BenchmarkResult]]:
    """The replay and the benchmark re-runs. Replayed episodes and random-policy benchmark episodes go
    through ONE pass of the rollout engine (one worker pool, one queue); a checkpoint policy runs on its own.

    ``keep = (seeds, steps)``: the random-policy rollouts of those seeds go into ``kept`` (by seed) when the pass
    runs them for at least ``steps`` steps, so the golden-rollout fingerprint need not run them again. ``declared``: the
    benchmarks to re-run (default: the manifest's; a suite task: its own)."""
    rep = (
        Replay(loaded.make, loaded.dataset_root, loaded.config.features_map, tolerance=tolerance, episodes=episodes)
        if replay
        else None
    )
    try:
        runs = (
            [
                BenchmarkRun(loaded, b, resamples=resamples, token=token, trust_policy_code=trust_policy_code)
                for b in (loaded.manifest.benchmarks if declared is None else declared)
            ]
            if benchmarks
            else []
        )
        time_limit = int(loaded.config.episode_length)  # load_env registers it as max_episode_steps
        longest = max([rep.max_steps] if rep is not None else [1])
        # a random-policy episode may join when a longer max_steps cannot change it: the env's time limit ends it first
        joint = [r for r in runs if r.random_policy and (r.max_steps >= longest or time_limit <= r.max_steps)]
        longest = max([longest] + [r.max_steps for r in joint])
        seeds = (rep.seeds if rep is not None else []) + [s for r in joint for s in r.seeds]
        policy = (rep.policy if rep is not None else []) + [None for r in joint for _ in r.seeds]
        owners = [(rep, None)] * (len(rep.seeds) if rep is not None else 0) + [(None, r) for r in joint for _ in r.seeds]
        n_replay = len(rep.seeds) if rep is not None else 0
        desc = " and ".join(
            x
            for x in (
                f"replaying {n_replay} episodes" if rep is not None else "",
                f"re-running {len(seeds) - n_replay} benchmark episodes" if joint else "",
            )
            if x
        )
        keep_seeds = set(keep[0]) if kept is not None and longest >= keep[1] else set()
        t = time.perf_counter()
        if seeds:
            for i, rollout in enumerate(
                backend.episodes(
                    loaded,
                    seeds,
                    max_steps=longest,
                    policy=policy if n_replay else None,
                    record_states=rep.record_states if rep is not None else False,
                    progress=progress,
                    desc=desc[:1].upper() + desc[1:],
                )
            ):
                replay_owner, bench_owner = owners[i]
                (replay_owner.consume if replay_owner is not None else bench_owner.consume)(rollout)
                if bench_owner is not None and rollout.seed in keep_seeds:
                    kept.setdefault(rollout.seed, rollout)  # a seeded random-action episode, as the fingerprint's
        joint_seconds = time.perf_counter() - t
        steps_total = max(
            1, sum(len(a) for a in (rep.actions if rep is not None else [])) + sum(len(r.seeds) for r in joint) * time_limit
        )
        replay_share = (sum(len(a) for a in rep.actions) / steps_total) if rep is not None else 0.0
        replay_result = rep.finish(episodes_seconds=joint_seconds * replay_share) if rep is not None else None
        if replay_result is not None:
            timings["replay"] = replay_result.seconds
        results = []
        for r in runs:
            if r in joint:
                results.append(r.finish(episodes_seconds=joint_seconds * (1 - replay_share) / max(1, len(joint))))
            else:  # a checkpoint policy (or an unusual max_steps): its own pass
                results.append(r.run(loaded, backend=backend, progress=progress))
        timings["benchmarks"] = sum(b.seconds for b in results)
        return replay_result, results
    finally:
        if rep is not None:
            rep.close()


def _reproduce_tasks(loaded: Any, *, episodes: list[int] | None, timings: dict[str, float], **run: Any) -> list[TaskReproduction]:
    """A suite, task by task (:meth:`~hub_envs.loading.loaded.LoadedEnv.for_task`): the replay of the task's dataset
    episodes (of ``episodes``, when given), the re-run of its benchmarks, its golden-rollout fingerprint (from the
    benchmark's episodes when they cover its seeds), each in its task's env."""
    out = []
    for task in loaded.tasks:
        view, record = loaded.for_task(task), loaded.manifest.task_record(task)
        mine = [e for e in record["episodes"] if episodes is None or e in episodes]
        recorded = record.get("fingerprint") or {}
        ran: dict[int, Any] = {}
        replay_result, bench_results = _run_episodes(
            view,
            episodes=mine,
            timings={},
            keep=(list(recorded.get("seeds") or []), int(recorded.get("steps") or 0)),
            kept=ran,
            declared=[b for b in loaded.manifest.benchmarks if b.get("task") == task],
            **{**run, "replay": run["replay"] and bool(mine)},
        )
        fp = _fingerprint(view, ran, recorded=recorded)
        out.append(TaskReproduction(task, record["task_index"], replay_result, bench_results, fp))
    timings["replay"] = sum(t.replay.seconds for t in out if t.replay is not None)
    timings["benchmarks"] = sum(b.seconds for t in out for b in t.benchmarks)
    return out


def _dataset_notes(provenance: dict[str, Any]) -> list[str]:
    """What the provenance says about the dataset itself: changed after publishing, or recorded by other code."""
    notes = []
    published = provenance.get("published_dataset_fingerprint")
    if published and provenance["dataset_fingerprint"] != published:
        notes.append(
            "the dataset's files differ from the fingerprint the manifest was published with: "
            "the dataset was changed after push_env wrote it"
        )
    recorded_by = provenance.get("dataset_code_digest")
    if recorded_by and recorded_by != provenance["code_digest"]:
        notes.append(
            f"the dataset was recorded by other code (code digest {str(recorded_by)[:16]}…) than this commit holds "
            f"({provenance['code_digest'][:16]}…): the env's code changed after the data was recorded"
        )
    return notes


def reproduce(
    repo_id: str,
    *,
    revision: str | None = None,
    trust_remote_code: bool = False,
    workers: int | None = None,
    tolerance: float = 0.0,
    out: str | Path | None = None,
    replay: bool = True,
    benchmarks: bool = True,
    episodes: list[int] | None = None,
    resamples: int = 1000,
    progress: bool = True,
    write: bool = True,
    token: str | None = None,
    trust_policy_code: bool = False,
    backend: str | Backend = "local",
    ray_address: str | None = None,
    **run: Unpack[CodeRun],
) -> ReproduceReport:
    """Replay the dataset and re-run the benchmarks of ``repo_id`` at ``revision``; report what differs.

    The stages: load (checks on, fingerprint off), provenance and what it says of the dataset
    (:func:`_dataset_notes`), the fingerprint (:func:`_fingerprint`), the episodes of the replay and the
    benchmarks in one pass (:func:`_run_episodes`), the report (written unless ``write=False``).

    Args:
        repo_id: ``user/name`` (``@rev`` allowed) or a local folder of a published repo.
        revision: branch, tag or sha; pin a sha to reproduce exactly what was published.
        trust_remote_code: consent to run the repo's code (or trust the commit with ``hub-envs trust``).
        workers: processes for the episodes (default: up to 2; on Ray: actors, default the cluster's CPUs);
            the report does not depend on it.
        tolerance: largest absolute difference accepted in the replay (0: bit-exact).
        out: folder for report.json/.md/.png (default ``reproduce-out/<user>/<name>/``).
        replay: replay the dataset's episodes.
        benchmarks: re-run the declared benchmarks.
        episodes: replay only these episode indices (default: all).
        resamples: bootstrap resamples for the benchmark confidence intervals.
        progress: progress bars.
        write: write the report files.
        run: how the env's code runs (``isolation``, ``sandbox``, ``versions``, ``step_timeout``, as
            :func:`hub_envs.load_env` takes them); isolated, the replay, the benchmarks and the fingerprint all
            step the env through its worker processes.
        backend: where the replay and benchmark episodes run: ``"local"`` (this machine's processes) or ``"ray"``
            (a Ray cluster: ``ray_address``, default ``$RAY_ADDRESS``, else a local Ray for the run). The report is
            the same (timings aside). On Ray, an explicit ``out`` also keeps the finished shards in ``out/shards/``,
            so the same command started again skips them.
        trust_policy_code: consent to load the LeRobot policy checkpoints the benchmarks name (other repos than
            the env: loading one can import code its processor config names). Or trust each with ``hub-envs trust``.

    Returns:
        A :class:`ReproduceReport`; ``report.reproduced`` is the verdict, ``report.paths`` the files.

    Raises:
        hub_envs.errors.HubEnvsError: the repo cannot be loaded or replayed at all (not: it diverged).
    """
    if workers is not None and int(workers) < 0:
        raise ConfigError(f"workers={workers}: pass a positive number of processes (or 0 for the default).")
    runner = make_backend(
        backend,
        workers=int(workers) if workers else None,
        ray_address=ray_address,
        checkpoint_dir=Path(out) / "shards" if out is not None and backend == "ray" else None,
    )
    timings: dict[str, float] = {}
    t0 = t = time.perf_counter()
    with load_env(
        repo_id,
        revision=revision,
        trust_remote_code=trust_remote_code,
        check=True,
        fingerprint="off",
        token=token,
        **code_run(run, "reproduce"),
    ) as loaded:
        timings["load"] = time.perf_counter() - t
        dataset_root = loaded.dataset_root
        provenance = _provenance(loaded, dataset_root)
        notes = _dataset_notes(provenance) if dataset_root is not None else []
        timings["provenance"] = time.perf_counter() - t0 - timings["load"]
        replay_result: ReplayResult | None = None
        bench_results: list[BenchmarkResult] = []
        if replay and dataset_root is None:
            notes.append("no dataset/ in this repo: nothing to replay")
        if benchmarks and not loaded.manifest.benchmarks:
            notes.append("the manifest declares no benchmark results")
        recorded = loaded.manifest.fingerprint or {}
        ran: dict[int, Any] = {}
        task_results: list[TaskReproduction] = []
        t = time.perf_counter()
        with runner:
            if loaded.is_suite:  # each task: its episodes' replay, its benchmarks, its fingerprint
                task_results = _reproduce_tasks(
                    loaded,
                    replay=replay and dataset_root is not None,
                    benchmarks=benchmarks,
                    tolerance=tolerance,
                    backend=runner,
                    episodes=episodes,
                    resamples=resamples,
                    progress=progress,
                    token=token,
                    timings=timings,
                    trust_policy_code=trust_policy_code,
                )
            else:
                replay_result, bench_results = _run_episodes(
                    loaded,
                    replay=replay and dataset_root is not None,
                    benchmarks=benchmarks,
                    tolerance=tolerance,
                    backend=runner,
                    episodes=episodes,
                    resamples=resamples,
                    progress=progress,
                    token=token,
                    timings=timings,
                    trust_policy_code=trust_policy_code,
                    keep=(list(recorded.get("seeds") or []), int(recorded.get("steps") or 0)),
                    kept=ran,
                )
        timings["episodes"] = time.perf_counter() - t
        t = time.perf_counter()
        if task_results:
            fp = {"status": "per task", "ok": all(r.fingerprint.get("ok", True) for r in task_results)}
        else:
            fp = _fingerprint(loaded, ran)  # from the benchmark's random-policy episodes when they cover its seeds
        timings["fingerprint"] = time.perf_counter() - t
        report = ReproduceReport(
            repo_id=loaded.repo_id,
            sha=loaded.revision,
            provenance=provenance,
            replay=replay_result,
            benchmarks=bench_results,
            fingerprint=fp,
            notes=notes,
            settings={
                "tolerance": float(tolerance),
                **runner.settings(),
                "resamples": resamples,
                "episodes": episodes,
                "replay": replay,
                "benchmarks": benchmarks,
                "isolation": loaded.runs_as,
                "versions": run.get("versions", "current"),
                "source": "folder" if loaded.local_folder is not None else "hub",
            },
            tasks=task_results,
        )
        report.finish(timings, t0, out=out, default=default_out_dir(DEFAULT_OUT, loaded.repo_id), write=write)
        return report
