"""The reproduction report (:class:`ReproduceReport`): the replay, the benchmarks, the fingerprint and the provenance,
written as ``report.json``, ``report.md`` and ``report.png`` (returns, divergence, each frame's video error).

Example:
    >>> from hub_envs.harness.report import ReproduceReport
    >>> report = ReproduceReport(repo_id="user/env", sha="0" * 40, provenance={}, replay=None,
    ...                          benchmarks=[], fingerprint={"status": "matches", "ok": True})
    >>> report.reproduced, report.verdict()
    (True, 'REPRODUCED')
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hub_envs._text import md_code
from hub_envs.harness.benchmark import BenchmarkResult
from hub_envs.harness.provenance import DRIFT_KINDS, difference_text
from hub_envs.harness.replay import ReplayResult
from hub_envs.harness.report_files import REPORT_JSON, REPORT_MD, REPORT_PNG, ReportFiles, save_figure, seeds_text

__all__ = ["ReproduceReport", "TaskReproduction", "REPORT_JSON", "REPORT_MD", "REPORT_PNG"]


def _fmt(x: Any, digits: int = 6) -> str:
    if isinstance(x, bool) or x is None:
        return str(x)
    if isinstance(x, float):
        if math.isnan(x) or math.isinf(x):
            return str(x)
        return f"{x:.{digits}g}"
    return str(x)


def jsonable(value: Any) -> Any:
    """A value as JSON can hold it.

    Args:
        value: nested dicts, lists, numbers...

    Returns:
        The same, with NaN and infinities as text, keys as text, tuples as lists.
    """
    if isinstance(value, float) and (math.isnan(value) or math.isinf(value)):
        return str(value)
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    return value


@dataclass
class TaskReproduction:
    """What the reproduction of one task of a benchmark suite found: its episodes' replay, its benchmarks, its
    golden-rollout fingerprint. ``reproduced`` is True when every part that ran passed."""

    task: str
    task_index: int
    replay: ReplayResult | None
    benchmarks: list[BenchmarkResult]
    fingerprint: dict[str, Any]

    @property
    def checks(self) -> dict[str, bool]:
        """``{part: passed}`` of the parts that ran."""
        out: dict[str, bool] = {}
        if self.replay is not None:
            out["replay"] = self.replay.ok
        for b in self.benchmarks:
            out[f"benchmark {b.name}"] = b.passed
        if self.fingerprint.get("status") not in (None, "off", "none recorded"):
            out["fingerprint"] = bool(self.fingerprint.get("ok"))
        return out

    @property
    def reproduced(self) -> bool:
        return all(self.checks.values())

    def verdict(self) -> str:
        """``REPRODUCED`` or ``NOT REPRODUCED``."""
        return "REPRODUCED" if self.reproduced else "NOT REPRODUCED"

    def to_dict(self) -> dict[str, Any]:
        """The task's part of ``report.json``."""
        return {
            "task": self.task,
            "task_index": self.task_index,
            "reproduced": self.reproduced,
            "verdict": self.verdict(),
            "checks": self.checks,
            "replay": self.replay.to_dict() if self.replay is not None else None,
            "benchmarks": [b.to_dict() for b in self.benchmarks],
            "fingerprint": self.fingerprint,
        }


@dataclass
class ReproduceReport(ReportFiles):
    """What a reproduction found. ``reproduced`` is True when every part that ran passed; for a benchmark suite, every
    part of every task (``tasks``: one :class:`TaskReproduction` each)."""

    repo_id: str
    sha: str
    provenance: dict[str, Any]
    replay: ReplayResult | None
    benchmarks: list[BenchmarkResult]
    fingerprint: dict[str, Any]
    notes: list[str] = field(default_factory=list)  # warnings that do not fail the reproduction
    settings: dict[str, Any] = field(default_factory=dict)
    paths: dict[str, str] = field(default_factory=dict)  # where write() put the files
    timings: dict[str, float] = field(default_factory=dict)  # seconds per stage (load, replay, benchmarks, ...)
    tasks: list[TaskReproduction] = field(default_factory=list)  # a suite's tasks, each reproduced on its own

    # -- verdict --

    @property
    def checks(self) -> dict[str, bool]:
        out: dict[str, bool] = {f"task {t.task}: {part}": ok for t in self.tasks for part, ok in t.checks.items()}
        if self.replay is not None:
            out["replay"] = self.replay.ok
        for b in self.benchmarks:
            out[f"benchmark {b.name}"] = b.passed
        if self.fingerprint.get("status") not in (None, "off", "none recorded", "per task"):
            out["fingerprint"] = bool(self.fingerprint.get("ok"))
        return out

    @property
    def reproduced(self) -> bool:
        return all(self.checks.values())

    def verdict(self) -> str:
        """``REPRODUCED`` or ``NOT REPRODUCED``."""
        return "REPRODUCED" if self.reproduced else "NOT REPRODUCED"

    @property
    def version_differences(self) -> dict[str, list[str]]:
        """``{package: [published, here]}`` for every recorded version that differs, the most suspect first."""
        drift = self.provenance.get("version_drift")
        if drift is not None:
            return {d["package"]: [d["published"], d["here"]] for d in drift}
        return dict(self.provenance.get("version_differences") or {})

    @property
    def version_kinds(self) -> dict[str, str]:
        """What each differing package is to the env (a key of :data:`hub_envs.harness.provenance.DRIFT_KINDS`)."""
        return {d["package"]: d["kind"] for d in self.provenance.get("version_drift") or []}

    def versions_note(self) -> str:
        """Which recorded versions differ from those the env ran with here, the most suspect first (the env's
        requirements and their dependencies, the simulator, numpy and gymnasium, then the rest of the stack)."""
        diffs = self.version_differences
        if not diffs:
            return "no package version differs from the publisher's"
        return "versions differ from the publisher's: " + difference_text(diffs, self.version_kinds)

    def publisher_versions_command(self) -> str | None:
        """When the reproduction failed while versions the env runs on differ (not only the stack around it, such as
        lerobot or torch) and it did not already run with the publisher's: the command that runs it again in a venv
        of the versions the publisher recorded (``--isolation=venv --versions=publisher``), else None."""
        diffs, kinds = self.version_differences, self.version_kinds
        env_side = [k for k in diffs if kinds.get(k, "stack") != "stack" or k == "python"]
        if self.reproduced or not env_side or self.settings.get("versions") == "publisher":
            return None
        flags = ["--trust_remote_code=true", "--isolation=venv", "--versions=publisher"]
        if "sandbox" in str(self.settings.get("isolation", "")):
            flags.append("--sandbox=true")
        if self.settings.get("tolerance"):
            flags.append(f"--tolerance={self.settings['tolerance']:g}")
        flags += [f"--{part}=false" for part in ("replay", "benchmarks") if self.settings.get(part) is False]
        if self.settings.get("source") == "folder":
            return "hub-envs reproduce --repo_id=<the folder> " + " ".join(flags)
        return f"hub-envs reproduce --repo_id={self.repo_id} --revision={self.sha} " + " ".join(flags)

    # -- text --

    def summary(self) -> str:
        """A few lines for the terminal."""
        lines = [f"{self.verdict()}: {self.repo_id}@{self.sha}"]
        if self.tasks:
            done = sum(t.reproduced for t in self.tasks)
            lines[0] += f" (a suite of {len(self.tasks)} tasks: {done} of {len(self.tasks)} reproduced)"
        for t in self.tasks:
            lines.append(f"  task {t.task_index} {t.task!r}: {t.verdict()}")
            if t.replay is not None:
                lines.append("    " + t.replay.summary())
                for ep in t.replay.diverged[:1]:
                    lines += ["      " + d.describe() for d in ep.divergences[:3]]
            for b in t.benchmarks:
                lines.append("    " + b.summary())
            lines.append(f"    golden-rollout fingerprint: {t.fingerprint.get('status')}")
        if self.replay is not None:
            lines.append("  " + self.replay.summary())
            shown = self.replay.diverged[:2]
            for ep in shown:
                for d in ep.divergences[:3]:
                    lines.append("    " + d.describe())
                if ep.localization:
                    lines.append(f"    localized: {ep.localization.get('message')}")
            if len(self.replay.diverged) > len(shown):
                lines.append(
                    f"    ... and {len(self.replay.diverged) - len(shown)} more diverged episodes (see the Markdown report)"
                )
            if not self.replay.ok:
                lines.append(f"    {self.versions_note()}")
        for b in self.benchmarks:
            lines.append("  " + b.summary())
            if not b.passed and not b.error:
                lines.append(f"    episodes whose result differs: {b.episodes_differing}; {self.versions_note()}")
        fp = self.fingerprint
        if not self.tasks:
            lines.append(
                f"  golden-rollout fingerprint: {fp.get('status')}"
                + (f" ({fp['message']})" if fp.get("message") and not fp.get("ok") else "")
            )
        lines.append(f"  stack: {self.versions_note()}")
        command = self.publisher_versions_command()
        if command:
            lines.append(f"  with the publisher's versions, run: {command}")
        for note in self.notes:
            lines.append(f"  note: {note}")
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        """The report as JSON-ready data (``report.json``)."""
        return jsonable(
            {
                "repo_id": self.repo_id,
                "sha": self.sha,
                "reproduced": self.reproduced,
                "verdict": self.verdict(),
                "checks": self.checks,
                "settings": self.settings,
                "replay": self.replay.to_dict() if self.replay is not None else None,
                "benchmarks": [b.to_dict() for b in self.benchmarks],
                "fingerprint": self.fingerprint,
                "notes": self.notes,
                "provenance": self.provenance,
                "timings": self.timings,
                **(
                    {
                        "tasks": [t.to_dict() for t in self.tasks],
                        "suite": {"tasks": len(self.tasks), "reproduced": sum(t.reproduced for t in self.tasks)},
                    }
                    if self.tasks
                    else {}
                ),
            }
        )

    def to_markdown(self) -> str:
        """The report for people (``report.md``): the verdict, the checks, the replay, the benchmarks, the provenance."""
        p = self.provenance
        out = [
            f"# Reproduction of `{self.repo_id}`",
            "",
            f"**{self.verdict()}** at commit `{self.sha}` — "
            + ", ".join(f"{k} {'✓' if v else '✗'}" for k, v in self.checks.items()),
            "",
        ]
        if self.tasks:
            out += [
                "## Tasks",
                "",
                "| task id | task | verdict | replay | benchmarks | golden-rollout fingerprint |",
                "|---|---|---|---|---|---|",
            ]
            for t in self.tasks:
                replay = t.replay.summary() if t.replay is not None else "not run"
                benches = "; ".join(b.summary() for b in t.benchmarks) or "none"
                out.append(
                    f"| {t.task_index} | {md_code(t.task)} | **{t.verdict()}** | {replay} | {benches} | {t.fingerprint.get('status')} |"
                )
            out.append("")
        if self.replay is not None:
            r = self.replay
            how = "exactly" if r.tolerance == 0 else f"within an absolute tolerance of {r.tolerance:g}"
            out += [
                "## Replay of the dataset",
                "",
                f"Every episode reset with its recorded seed, the recorded actions applied, and compared {how}: "
                f"{', '.join(f'`{k}`' for k in r.features)}. States: {r.states}.",
                "",
            ]
            if r.skipped:
                out += ["Not compared: " + "; ".join(f"`{k}` ({why})" for k, why in r.skipped.items()), ""]
            if r.video:
                limit = max(r.tolerance, float(r.video["tolerance"]["max_mean_abs_error"]))
                out += [
                    f"Video {', '.join(f'`{k}`' for k in r.video['keys'])} (lossy): a frame matches when its mean absolute "
                    f"error from the decoded video is at most {limit:g} (0-255); worst frame {_fmt(r.video['worst'], 3)}, "
                    f"mean {_fmt(r.video.get('mean'), 3)}, over the {r.video.get('frames_checked')} of "
                    f"{r.video.get('frames')} frames decoded"
                    + {
                        "frames_sha256": "; the replayed frames are the rendered ones bit for bit (their recorded sha256)",
                        "reencode": "; the replayed frames, re-encoded, give the dataset's video bit for bit",
                    }.get((r.video.get("bit_exact_by") or "") if r.video.get("bit_exact") else "", "")
                    + ".",
                    "",
                ]
            out += ["| episode | seed | frames | result | first divergence |", "|---|---|---|---|---|"]
            for e in r.episodes:
                first = e.first
                out.append(
                    f"| {e.episode} | {e.seed} | {e.length} | {'ok' if e.ok else 'DIVERGED'} | "
                    f"{'' if first is None else f'step {first.step}, `{first.feature}`, by {_fmt(first.max_abs_diff)}'} |"
                )
            out.append("")
            if not r.ok:
                out += ["### Divergences", "", f"*Provenance: {self.versions_note()}.*", ""]
                for e in r.diverged:
                    for d in e.divergences:
                        out.append(f"- {d.describe()}")
                    if e.localization:
                        out.append(f"  - localized ({e.localization.get('method')}): {e.localization.get('message')}")
                out.append("")
        if self.benchmarks:
            out += [
                "## Benchmarks",
                "",
                "| benchmark | policy | metric | published | reproduced | 95% CI (bootstrap) | tolerance | result |",
                "|---|---|---|---|---|---|---|---|",
            ]
            for b in self.benchmarks:
                pol = b.policy.get("type", "?") + (f" `{b.policy.get('checkpoint')}`" if b.policy.get("checkpoint") else "")
                if b.error:
                    out.append(f"| {b.name} | {pol} | – | – | – | – | – | NOT RUN: {b.error} |")
                for m in b.metrics:
                    ci = f"[{_fmt(m.ci_low)}, {_fmt(m.ci_high)}]"
                    out.append(
                        f"| {b.name} | {pol} | {m.name} | {_fmt(m.published)} | {_fmt(m.reproduced)} | {ci} | "
                        f"{'CI' if m.tolerance is None else _fmt(m.tolerance)} | {'pass' if m.passed else 'FAIL'} |"
                    )
            out.append("")
            for b in self.benchmarks:
                if not b.passed and not b.error:
                    out.append(
                        f"- {b.name}: episodes whose per-episode result differs: {b.episodes_differing}. *{self.versions_note()}.*"
                    )
            out += [
                f"Confidence intervals: {self.benchmarks[0].resamples} bootstrap resamples of the reproduced episodes (seeded).",
                "",
            ]
        fp = self.fingerprint
        if not self.tasks:
            out += [
                "## Golden-rollout fingerprint",
                "",
                f"{fp.get('status')}" + (f": {fp.get('message')}" if fp.get("message") else ""),
                "",
            ]
        if self.version_differences:
            out += [
                "## Versions that differ",
                "",
                "The most suspect first: the env's requirements and their dependencies, the simulator, numpy and gymnasium, "
                "then the rest of the stack.",
                "",
                "| package | published with | here | what it is |",
                "|---|---|---|---|",
            ]
            for name, (a, b) in self.version_differences.items():
                out.append(f"| {name} | {a} | {b} | {DRIFT_KINDS.get(self.version_kinds.get(name, ''), '')} |")
            out.append("")
            command = self.publisher_versions_command()
            if command:
                out += [
                    "Run it again with the publisher's versions (a venv of what the manifest records):",
                    "",
                    f"    {command}",
                    "",
                ]
        if self.notes:
            out += ["## Notes", ""] + [f"- {n}" for n in self.notes] + [""]
        out += [
            "## Provenance",
            "",
            "| | |",
            "|---|---|",
            f"| repo | `{self.repo_id}` |",
            f"| commit | `{self.sha}` |",
            f"| content digest | `{p.get('content_digest', '-')}` |",
            f"| code digest (this commit / the dataset's env_meta) | `{p.get('code_digest', '-')}` / `{p.get('dataset_code_digest', '-')}` |",
            f"| dataset fingerprint (computed / published) | `{p.get('dataset_fingerprint', '-')}` / `{p.get('published_dataset_fingerprint', '-')}` |",
            f"| dataset seeds | {seeds_text(p.get('seeds', {}).get('dataset', []))} |",
            f"| fingerprint seeds | {seeds_text(p.get('seeds', {}).get('fingerprint', []))} |",
            f"| generated | {p.get('generated_at', '-')} with hub-envs {p.get('hub_envs_version', '-')} |",
            "",
            "| package | published with | here | |",
            "|---|---|---|---|",
        ]
        published = {**(p.get("versions_published") or {}), **(p.get("closure_published") or {})}
        here = {**(p.get("versions_here") or {}), **(p.get("closure_here") or {})}
        for name in sorted(set(published) | set(here)):
            a, b = published.get(name, "-"), here.get(name, "-")
            out.append(f"| {name} | {a} | {b} | {'**differs**' if name in self.version_differences else ''} |")
        out.append("")
        if self.paths.get("png"):
            out += [f"![per-episode returns, divergence and video error]({Path(self.paths['png']).name})", ""]
        return "\n".join(out)

    # -- files --

    def plot(self, path: str | Path) -> Path | None:
        """Write :meth:`figure` as a PNG.

        Args:
            path: the PNG to write.

        Returns:
            ``path``; None (and no file) when there is nothing to plot or without matplotlib: it is the ``plots``
            extra (``pip install 'hub-envs[plots]'``).
        """
        fig = self.figure()
        return None if fig is None else save_figure(fig, path)

    def figure(self):
        """The report's plot as a matplotlib ``Figure``, one panel each (None when there is none, or no matplotlib):

        * per benchmark: the per-episode returns, published vs reproduced;
        * when the replay diverged: the divergence over steps of the first diverged episode;
        * when the dataset has video features: each frame's mean absolute error (replay vs decoded video) over the
          whole replay, with the tolerance it is held to: the one figure of a reproduction that is not exact.
        """
        try:
            import matplotlib  # heavy: matplotlib
        except ModuleNotFoundError:
            return None

        matplotlib.use("Agg", force=False)
        import matplotlib.pyplot as plt  # heavy: matplotlib

        panels: list[tuple[str, Any]] = []
        for b in self.benchmarks + [b for t in self.tasks for b in t.benchmarks]:
            if b.reproduced_per_episode.get("return"):
                panels.append(("returns", b))
        diverged = self.replay.diverged if self.replay is not None else []
        if diverged and diverged[0].error_curve:
            panels.append(("divergence", diverged[0]))
        if self.replay is not None and self.replay.video:
            panels += [("video", key) for key in self.replay.video["keys"]]
        if not panels:
            return None
        fig, axes = plt.subplots(len(panels), 1, figsize=(8, 3.2 * len(panels)), squeeze=False)
        draw = {"returns": _returns_panel, "divergence": _divergence_panel, "video": self._video_panel}
        for ax, (kind, item) in zip(axes[:, 0], panels):
            draw[kind](ax, item)
        fig.suptitle(f"{self.repo_id}@{self.sha[:12]}: {self.verdict()}", fontsize=10)
        return fig

    def _video_panel(self, ax, key: str) -> None:
        """Per-frame mean |replay - decoded video| of ``key`` over the replay (episodes in order), and the tolerance."""

        replay = self.replay
        episodes = [e for e in replay.episodes if key in e.video_errors]
        errors = np.concatenate([e.video_errors[key] for e in episodes]) if episodes else np.zeros(0)
        limit = max(replay.tolerance, float(replay.video["tolerance"]["max_mean_abs_error"]))
        decoded = errors[~np.isnan(errors)]
        sparse = len(decoded) < len(errors)  # keyframes only (rendered bit for bit): points, not a line through gaps
        ax.plot(
            np.arange(len(errors)),
            errors,
            ".-" if sparse else "-",
            ms=3,
            lw=0.8,
            color="tab:blue",
            label="replay vs dataset video, per frame" + (" (keyframes decoded)" if sparse else ""),
        )
        ax.axhline(limit, color="red", ls="--", lw=1, label=f"tolerance: {limit:g}")
        if len(episodes) <= 50:  # episode boundaries, while they can be told apart
            for start in np.cumsum([len(e.video_errors[key]) for e in episodes])[:-1]:
                ax.axvline(start - 0.5, color="grey", lw=0.5, ls=":")
        worst = float(decoded.max()) if len(decoded) else 0.0
        ax.set_ylim(0, 1.15 * max(limit, worst))
        ax.set_xlim(-0.5, max(len(errors) - 0.5, 0.5))
        ax.set_xlabel(f"frame of the replay ({len(episodes)} episodes in order)")
        ax.set_ylabel("mean |replay - decoded| (0-255)")
        how = replay.video.get("bit_exact_by") if replay.video.get("bit_exact") else None
        exact = {"frames_sha256": ", rendered bit for bit", "reencode": ", re-encoded: bit for bit"}.get(how or "", "")
        ax.set_title(
            f"video {key}: worst decoded frame {worst:.3g}, mean {float(decoded.mean()) if len(decoded) else 0.0:.3g}{exact}",
            fontsize=10,
        )
        ax.legend(loc="lower right", fontsize=8)


def _returns_panel(ax, item: BenchmarkResult) -> None:

    rep = np.asarray(item.reproduced_per_episode["return"], dtype=float)
    pub = np.asarray(item.published_per_episode.get("return", []), dtype=float)
    x = np.arange(len(rep))
    if len(pub):
        ax.plot(np.arange(len(pub)), pub, "o", mfc="none", ms=9, label="published")
    ax.plot(x, rep, "x", ms=7, label="reproduced")
    ax.set_xlabel("episode")
    ax.set_ylabel("return")
    ax.set_title(f"benchmark {item.name}: per-episode returns ({'pass' if item.passed else 'FAIL'})")
    ax.legend(loc="best")


def _divergence_panel(ax, item) -> None:

    for feature, curve in item.error_curve.items():
        c = np.asarray(curve, dtype=float)
        if np.any(c > 0):
            ax.plot(np.arange(len(c)), c, label=feature)
    loc = item.localization or {}
    if loc.get("one_step_error"):
        ax.plot(loc["one_step_error"], "--", color="black", lw=1, label="one step from recorded state")
    first = item.first
    if first is not None:
        ax.axvline(first.step, color="red", lw=0.8, ls=":")
    ax.set_yscale("symlog", linthresh=1e-9)
    ax.set_ylim(bottom=0)
    ax.set_xlabel("step")
    ax.set_ylabel("max |replay - dataset|")
    ax.set_title(f"replay divergence, episode {item.episode} (first at step {first.step if first else '-'})")
    ax.legend(loc="best", fontsize=8)
