"""``diff``: what changed between two revisions of an env repo (or two env repos), and does it behave differently? The
files and manifest fields, the spaces, the same episodes on both, the benchmarks' seed-paired deltas; a suite's, task by task.

Example:
    >>> from hub_envs import diff                                                     # doctest: +SKIP
    >>> report = diff("user/tiny@<A>", "user/tiny@<B>", trust_remote_code=True)      # doctest: +SKIP
    >>> report.behaviour_identical, report.first_divergence.describe()               # doctest: +SKIP
    (False, 'seed 0 (recorded actions of episode 0): next.reward diverged at step 0 ...')
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import json
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Unpack

import gymnasium as gym
import numpy as np

from hub_envs._text import md_code
from hub_envs._version import __version__
from hub_envs.dataset.reader import read_episode_frames, read_episode_meta
from hub_envs.errors import ConfigError
from hub_envs.harness.benchmark import METRICS, BenchmarkRun, bootstrap_ci
from hub_envs.harness.checks import FINGERPRINT_STEPS, golden_fingerprint
from hub_envs.harness.provenance import versions_run_with
from hub_envs.harness.replay import env_actions, step_errors
from hub_envs.harness.report import jsonable
from hub_envs.harness.report_files import ReportFiles, default_out_dir, save_figure
from hub_envs.harness.rollout import run_episodes
from hub_envs.loading.isolated import CodeRun, code_run
from hub_envs.loading.load import load_env
from hub_envs.repo.format import (
    CARD_FILE,
    DATASET_DIR,
    ENV_ENTRY_FILE,
    MANIFEST_FILE,
    MEDIA_DIR,
    PROJECT_FILE,
    Manifest,
    is_code_file,
)

__all__ = ["diff", "DiffReport", "SeedDiff", "TaskDiff", "classify_file", "manifest_changes", "task_pairs"]

DEFAULT_OUT = Path("diff-out")

#: fewer paired episodes than this: the report says their bootstrap interval is not a calibrated 95% one
FEW_EPISODES = 10
#: manifest fields the file lists already cover (or that only restate them)
_MANIFEST_SKIP = ("files", "content_digest", "code_digest", "repo_id", "gym_id", "env_type", "tasks")  # tasks: the task table
#: manifest fields whose change alters behaviour even when the compared episodes do not show it
_BEHAVIOUR_FIELDS = ("config", "config_overrides", "dataset.features", "dataset.fps", "env_entry_point", "processors")


# --- static part --------------------------------------------------------------------------------


def classify_file(path: str) -> str:
    """``code``, ``assets``, ``dataset`` or ``generated``.

    >>> [classify_file(p) for p in ("dynamics.py", "pyproject.toml", "meshes/arm.stl", "dataset/meta/info.json", "README.md")]
    ['code', 'code', 'assets', 'dataset', 'generated']
    """
    top = path.split("/", 1)[0]
    if top == DATASET_DIR:
        return "dataset"
    if path in (CARD_FILE, ENV_ENTRY_FILE, MANIFEST_FILE) or top == MEDIA_DIR:
        return "generated"
    if is_code_file(path) or path == PROJECT_FILE:
        return "code"
    return "assets"


def _flatten(value: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(value, dict) and value:
        out: dict[str, Any] = {}
        for k in sorted(value, key=str):
            out.update(_flatten(value[k], f"{prefix}.{k}" if prefix else str(k)))
        return out
    return {prefix: value}


def manifest_changes(old: Manifest, new: Manifest) -> list[dict[str, Any]]:
    """Every leaf field of the manifests that differs, as ``{"field": "config.fps", "old": 20, "new": 30}``.

    >>> a = Manifest(name="t", env_entry_point="m:E", config_entry_point="m:C", gym_id="g", env_type="t",
    ...              files={}, content_digest="", config={"fps": 20})
    >>> manifest_changes(a, Manifest(**{**a.__dict__, "config": {"fps": 30}}))
    [{'field': 'config.fps', 'old': 20, 'new': 30}]
    """
    a = _flatten({k: v for k, v in json.loads(old.to_json()).items() if k not in _MANIFEST_SKIP})
    b = _flatten({k: v for k, v in json.loads(new.to_json()).items() if k not in _MANIFEST_SKIP})
    return [{"field": k, "old": a.get(k), "new": b.get(k)} for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)]


def file_changes(old: Manifest, new: Manifest) -> dict[str, dict[str, list[str]]]:
    """The files added, removed and changed between two manifests, by their hashes.

    Args:
        old, new: the two revisions' manifests.

    Returns:
        ``{group: {"added": [...], "removed": [...], "changed": [...]}}``, groups as :func:`classify_file` names them.
    """
    a, b = dict(old.files), dict(new.files)
    a[MANIFEST_FILE] = old.to_json()  # the manifest is not in its own file list: compare its canonical text
    b[MANIFEST_FILE] = new.to_json()
    out: dict[str, dict[str, list[str]]] = {}
    for path in sorted(set(a) | set(b)):
        kind = "added" if path not in a else "removed" if path not in b else "changed" if a[path] != b[path] else None
        if kind is None:
            continue
        out.setdefault(classify_file(path), {"added": [], "removed": [], "changed": []})[kind].append(path)
    return out


def task_pairs(old: Manifest, new: Manifest) -> list[tuple[str | None, str | None]]:
    """How the tasks of two revisions correspond, when either is a benchmark suite: ``(old task, new task)`` pairs, the
    same name on both first, then a task removed and one added with the same (non-empty) instruction as a rename, then
    ``(task, None)`` removed and ``(None, task)`` added. A one-task side is paired with the suite's task its config
    names (its ``task`` field, when the suite has it), else with the suite's default task, and stands as ``""``.

    >>> m = Manifest(name="s", env_entry_point="m:E", config_entry_point="m:C", gym_id="g", env_type="t", files={},
    ...              content_digest="", config={"task": "a"}, tasks=({"task": "a", "instruction": "go"},
    ...              {"task": "b", "instruction": "stop"}))
    >>> task_pairs(m, Manifest(**{**m.__dict__, "tasks": ({"task": "a", "instruction": "go"}, {"task": "c", "instruction": "stop"})}))
    [('a', 'a'), ('b', 'c')]
    >>> task_pairs(m, Manifest(**{**m.__dict__, "tasks": ()}))
    [('a', ''), ('b', None)]
    """
    a, b = old.task_names, new.task_names
    if not a and not b:
        return []
    if not a or not b:
        suite, single = (new, old) if not a else (old, new)
        wanted = single.config.get("task")
        chosen = wanted if wanted in suite.task_names else suite.config.get("task", suite.task_names[0])
        rows: list[tuple[str | None, str | None]] = []
        for t in suite.task_names:
            if t == chosen:
                rows.append(("", t) if not a else (t, ""))
            else:
                rows.append((None, t) if not a else (t, None))
        return rows
    pairs: list[tuple[str | None, str | None]] = [(t, t) for t in a if t in b]
    removed, added = [t for t in a if t not in b], [t for t in b if t not in a]
    said_a = {t: old.task_record(t).get("instruction") for t in removed}
    said_b = {t: new.task_record(t).get("instruction") for t in added}
    for t in list(removed):
        twin = next((u for u in added if said_a[t] and said_b[u] == said_a[t]), None)
        if twin is not None:
            pairs.append((t, twin))
            removed.remove(t)
            added.remove(twin)
    return pairs + [(t, None) for t in removed] + [(None, t) for t in added]


# --- behavioural part ---------------------------------------------------------------------------


@dataclass
class SeedDiff:
    """One paired episode: the first step where the two revisions differ (or None), and what differs."""

    seed: int
    source: str  # "recorded actions of episode N" or "random actions"
    steps_old: int
    steps_new: int
    step: int | None = None
    feature: str | None = None
    element: list[int] = field(default_factory=list)
    old: Any = None
    new: Any = None
    max_abs_diff: float = 0.0
    #: per-step max |new - old| of each feature that diverged (over the common length)
    errors: dict[str, list[float]] = field(default_factory=dict)
    return_old: float = 0.0
    return_new: float = 0.0
    success_old: bool = False
    success_new: bool = False
    task: str | None = None  # a suite's task (its name in the new revision) the episode ran in

    @property
    def diverged(self) -> bool:
        return self.step is not None

    def describe(self) -> str:
        """One line: where this seed's episodes first diverged (step, feature, element, both values), or that they did not."""
        where = (
            f"seed {self.seed} ({self.source})" if self.task is None else f"task {self.task!r} seed {self.seed} ({self.source})"
        )
        if not self.diverged:
            return f"{where}: identical for {self.steps_old} steps"
        at = f"[{', '.join(map(str, self.element))}]" if self.element else ""
        return (
            f"{where}: {self.feature}{at} diverged at step {self.step} "
            f"(old {_short(self.old)} vs new {_short(self.new)}, |diff| {self.max_abs_diff:.6g})"
        )

    def to_dict(self) -> dict[str, Any]:
        """The comparison as JSON-ready data."""
        return {**asdict(self), "diverged": self.diverged}


def _md_cell(text: str) -> str:
    """Text as one Markdown table cell (a task name or instruction is the publisher's: no '|' or line break)."""
    return " ".join(str(text).split()).replace("|", "\\|")


def _short(value: Any, limit: int = 80) -> str:
    text = json.dumps(value) if not isinstance(value, str) else value
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _space_info(space: Any) -> dict[str, Any]:
    if isinstance(space, gym.spaces.Dict):
        return {k: _space_info(v) for k, v in space.spaces.items()}
    return {"type": type(space).__name__, "shape": list(space.shape or ()), "dtype": str(space.dtype)}


def _space_changes(old_env: Any, new_env: Any) -> list[dict[str, Any]]:
    out = []
    for name in ("observation_space", "action_space"):
        a, b = _flatten(_space_info(getattr(old_env, name))), _flatten(_space_info(getattr(new_env, name)))
        for k in sorted(set(a) | set(b)):
            if a.get(k) != b.get(k):
                out.append({"space": name, "field": k, "old": a.get(k), "new": b.get(k)})
    return out


def _compare(a: Any, b: Any, seed: int, source: str, names: dict[str, str], tolerance: float) -> SeedDiff:
    n = min(a.length, b.length)
    out = SeedDiff(
        seed=seed,
        source=source,
        steps_old=a.length,
        steps_new=b.length,
        return_old=a.episode_return,
        return_new=b.episode_return,
        success_old=a.success,
        success_new=b.success,
    )
    # (rank at equal steps: the observation at step t comes before action t, the rest after it)
    pairs = [(names.get(k, f"observation.{k}"), 0, a.observations[k], b.observations.get(k)) for k in sorted(a.observations)]
    pairs += [
        ("next.reward", 1, a.rewards, b.rewards),
        ("next.success", 1, a.is_success, b.is_success),
        ("terminated", 1, a.terminated, b.terminated),
        ("truncated", 1, a.truncated, b.truncated),
    ]
    best: tuple[int, int] | None = None
    for name, rank, x, y in pairs:
        if y is None or x.shape[1:] != y.shape[1:]:
            continue  # a space change, reported as such
        err = step_errors(y[:n], x[:n])
        bad = np.flatnonzero(err > tolerance)
        if not len(bad):
            continue
        out.errors[name] = [float(e) for e in err]
        t = int(bad[0])
        if best is None or (t, rank) < best:
            best = (t, rank)
            xa, ya = np.asarray(x[t]), np.asarray(y[t])
            d = np.abs(ya.astype(np.float64) - xa.astype(np.float64)).reshape(-1) if xa.size else np.zeros(0)
            out.step, out.feature, out.max_abs_diff = t, name, float(err[t])
            out.element = [int(i) for i in np.unravel_index(int(np.argmax(d)), xa.shape)] if xa.ndim else []
            out.old, out.new = xa.tolist(), ya.tolist()
    if best is None and a.length != b.length:
        out.step, out.feature = n, "episode length"
        out.old, out.new = a.length, b.length
    return out


def _recorded_actions(loaded: Any, episodes: int, among: list[int] | None = None) -> list[tuple[int, int, np.ndarray]]:
    """(episode index, seed, actions) of the first ``episodes`` episodes of the revision's dataset (of those ``among``
    lists: a suite task's)."""
    if episodes <= 0 or loaded.dataset_root is None:
        return []
    out = []
    metas = read_episode_meta(loaded.dataset_root)
    if among is not None:
        metas = [m for m in metas if int(m["episode_index"]) in set(among)]
    for m in metas[:episodes]:
        if m.get("seed") is None:
            continue
        frames = read_episode_frames(loaded.dataset_root, int(m["episode_index"]), keys=["action"])
        out.append((int(m["episode_index"]), int(m["seed"]), np.asarray(frames["action"])))
    return out


# --- the report ---------------------------------------------------------------------------------


@dataclass
class TaskDiff:
    """One task of a benchmark suite across the two revisions (:func:`task_pairs`): its name and instruction on each side
    (``old``/``new`` None: the task is not there; ``""``: that side is a one-task env), and, when on both, its episodes
    paired seed by seed, its fingerprints, its benchmarks' paired deltas."""

    old: str | None
    new: str | None
    instruction_old: str | None = None
    instruction_new: str | None = None
    spaces: list[dict[str, Any]] = field(default_factory=list)
    seeds: list[SeedDiff] = field(default_factory=list)
    fingerprint: dict[str, Any] = field(default_factory=dict)
    benchmarks: list[dict[str, Any]] = field(default_factory=list)
    deltas: dict[str, Any] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    @property
    def name(self) -> str:
        """The task's name: ``old -> new`` when renamed."""
        if self.renamed:
            return f"{self.old} -> {self.new}"
        return str(self.new or self.old or "(the one-task env)")

    @property
    def change(self) -> str:
        """``added``, ``removed``, ``renamed``, ``vs one-task env`` or ``kept``."""
        if self.old is None:
            return "added"
        if self.new is None:
            return "removed"
        if "" in (self.old, self.new):
            return "vs one-task env"
        return "renamed" if self.old != self.new else "kept"

    @property
    def renamed(self) -> bool:
        return bool(self.old and self.new and self.old != self.new)

    @property
    def compared(self) -> bool:
        return self.old is not None and self.new is not None

    @property
    def instruction_changed(self) -> bool:
        """Whether the language instruction a policy reads changed (a one-task side has none to compare)."""
        return self.compared and "" not in (self.old, self.new) and self.instruction_old != self.instruction_new

    @property
    def behaviour_identical(self) -> bool:
        """Whether the task behaves the same on both: on both, same spaces, no paired episode diverged, the same
        fingerprint, no benchmark episode differing."""
        return self.compared and not (
            self.spaces
            or any(s.diverged for s in self.seeds)
            or not self.fingerprint.get("same", True)
            or any(b.get("episodes_differing") for b in self.benchmarks)
        )

    @property
    def identical(self) -> bool:
        """Identical behaviour under the same name and instruction."""
        return self.behaviour_identical and self.change in ("kept", "vs one-task env") and not self.instruction_changed

    def verdict(self) -> str:
        """``identical``, ``behaviour differs``, ``added`` or ``removed`` (and ``renamed``/``instruction changed``)."""
        if not self.compared:
            return self.change
        out = "identical behaviour" if self.behaviour_identical else "behaviour differs"
        extra = [w for w, on in (("renamed", self.renamed), ("instruction changed", self.instruction_changed)) if on]
        return out + (f" ({', '.join(extra)})" if extra else "")

    def to_dict(self) -> dict[str, Any]:
        """The task's part of ``report.json``."""
        return {
            "old": self.old,
            "new": self.new,
            "change": self.change,
            "instruction_old": self.instruction_old,
            "instruction_new": self.instruction_new,
            "instruction_changed": self.instruction_changed,
            "behaviour_identical": self.behaviour_identical,
            "identical": self.identical,
            "verdict": self.verdict(),
            "spaces": self.spaces,
            "seeds": [s.to_dict() for s in self.seeds],
            "fingerprint": self.fingerprint,
            "benchmarks": self.benchmarks,
            "deltas": self.deltas,
            "notes": self.notes,
        }

    def row(self) -> tuple[str, ...]:
        """(task, change, instruction, episodes diverged, fingerprint, benchmark episodes differing, verdict) as text."""
        said = (
            f"{self.instruction_old!r} -> {self.instruction_new!r}"
            if self.instruction_changed
            else repr(self.instruction_new if self.new else self.instruction_old)
        )
        if not self.compared:
            return (self.name, self.change, said, "-", "-", "-", self.verdict())
        bench = sum(len(b.get("episodes_differing", [])) for b in self.benchmarks)
        of = sum(len(b.get("seeds", [])) for b in self.benchmarks if b.get("metrics"))
        return (
            self.name,
            self.change,
            said,
            f"{sum(s.diverged for s in self.seeds)} of {len(self.seeds)}",
            str(self.fingerprint.get("status", "-")),
            f"{bench} of {of}" if of else "-",
            self.verdict(),
        )


@dataclass
class DiffReport(ReportFiles):
    """What :func:`diff` found. ``behaviour_identical`` is the verdict; ``exit_code`` what ``hub-envs diff`` returns."""

    old: dict[str, Any]
    new: dict[str, Any]
    files: dict[str, dict[str, list[str]]]
    manifest: list[dict[str, Any]]
    spaces: list[dict[str, Any]]
    seeds: list[SeedDiff]
    fingerprint: dict[str, Any]
    deltas: dict[str, Any]
    notes: list[str]
    settings: dict[str, Any]
    provenance: dict[str, Any]
    benchmarks: list[dict[str, Any]] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    paths: dict[str, str] = field(default_factory=dict)
    #: a benchmark suite on either side: each task across the revisions (``seeds``, ``benchmarks``, ``deltas`` then pool
    #: every task's, paired by task and seed)
    tasks: list[TaskDiff] = field(default_factory=list)
    #: a suite on either side: ``{"old": n tasks, "new": m tasks, "kind": "suite vs suite" | ...}``
    suite: dict[str, Any] = field(default_factory=dict)

    @property
    def diverged(self) -> list[SeedDiff]:
        return [s for s in self.seeds if s.diverged]

    @property
    def first_divergence(self) -> SeedDiff | None:
        return self.diverged[0] if self.diverged else None

    @property
    def behaviour_fields(self) -> list[dict[str, Any]]:
        return [c for c in self.manifest if any(c["field"] == f or c["field"].startswith(f + ".") for f in _BEHAVIOUR_FIELDS)]

    @property
    def benchmarks_differing(self) -> list[dict[str, Any]]:
        """The re-run benchmarks with an episode whose result differs between the revisions."""
        return [b for b in self.benchmarks if b.get("episodes_differing")]

    @property
    def tasks_differing(self) -> list[TaskDiff]:
        """A suite's tasks that are not identical: added, removed, renamed, instruction or behaviour changed."""
        return [t for t in self.tasks if not t.identical]

    @property
    def behaviour_identical(self) -> bool:
        """The verdict; for a suite, every task identical (a task added, removed or renamed, or whose instruction
        changed, makes it differ: ``--env.task=`` and a language-conditioned policy see it)."""
        return not (
            self.spaces
            or self.diverged
            or not self.fingerprint.get("same", True)
            or self.behaviour_fields
            or self.benchmarks_differing
            or self.tasks_differing
        )

    @property
    def exit_code(self) -> int:
        return 0 if self.behaviour_identical else 1

    def to_dict(self) -> dict[str, Any]:
        """The report as JSON-ready data (``report.json``)."""
        return {
            "verdict": "identical behaviour" if self.behaviour_identical else "behaviour differs",
            "behaviour_identical": self.behaviour_identical,
            "old": self.old,
            "new": self.new,
            "files": self.files,
            "manifest": self.manifest,
            "spaces": self.spaces,
            "seeds": [s.to_dict() for s in self.seeds],
            "first_divergence": self.first_divergence.to_dict() if self.first_divergence else None,
            "fingerprint": self.fingerprint,
            "deltas": self.deltas,
            "benchmarks": self.benchmarks,
            "notes": self.notes,
            "settings": self.settings,
            "provenance": self.provenance,
            "timings": self.timings,
            **({"suite": self.suite, "tasks": [t.to_dict() for t in self.tasks]} if self.suite else {}),
        }

    def to_json(self) -> str:
        """``report.json``'s text (NaN and infinities as text)."""
        return json.dumps(jsonable(self.to_dict()), indent=2, sort_keys=True) + "\n"

    def _files_lines(self) -> list[str]:
        lines = []
        for group in ("code", "assets", "dataset", "generated"):
            g = self.files.get(group)
            if not g:
                continue
            parts = []
            for kind, sign in (("added", "+"), ("removed", "-"), ("changed", "~")):
                names = g[kind]
                if names:
                    shown = ", ".join(names[:6]) + (f", … ({len(names) - 6} more)" if len(names) > 6 else "")
                    parts.append(f"{sign}{len(names)} {kind} ({shown})")
            lines.append(f"{group}: " + "; ".join(parts))
        return lines or ["no file differs"]

    def summary(self) -> str:
        """What ``hub-envs diff`` prints: the verdict, the files, fields, spaces, seeds, fingerprints and benchmarks that changed."""
        o, n = self.old, self.new
        lines = [
            f"hub-envs diff {o['repo_id']}@{o['sha'][:12]} -> {n['repo_id']}@{n['sha'][:12]}: "
            + ("IDENTICAL BEHAVIOUR" if self.behaviour_identical else "BEHAVIOUR DIFFERS"),
            "Files:",
            *(f"  {line}" for line in self._files_lines()),
        ]
        if self.suite:
            lines.append(f"Suite: {self.suite['kind']}; {len(self.tasks_differing)} of {len(self.tasks)} task(s) differ")
            lines += [f"  {t.name}: {t.verdict()}" for t in self.tasks]
        if self.manifest:
            lines.append(f"Manifest: {len(self.manifest)} field(s) changed")
            lines += [f"  {c['field']}: {_short(c['old'], 40)} -> {_short(c['new'], 40)}" for c in self.manifest[:12]]
            if len(self.manifest) > 12:
                lines.append(f"  … {len(self.manifest) - 12} more in the report")
        for s in self.spaces:
            lines.append(f"SPACE CHANGE {s['space']} {s['field']}: {s['old']} -> {s['new']}")
        fp = self.fingerprint
        lines.append(f"Golden fingerprint: {fp.get('status')}")
        if self.seeds:
            lines.append(f"Episodes: {len(self.diverged)} of {len(self.seeds)} paired seeds diverged")
            lines += [f"  {s.describe()}" for s in self.seeds]
        d = self.deltas.get("return")
        if d:
            lines.append(
                f"Return delta (new - old, paired over {d['n']} seeds): {d['mean']:+.6g} [95% CI {d['ci'][0]:+.6g}, {d['ci'][1]:+.6g}]"
            )
        for b in self.benchmarks:
            lines.append(f"Benchmark {b['name']} ({_benchmark_what(b)}):")
            for row in _benchmark_rows(b):
                if len(row) == 1:
                    lines.append(f"  not re-run: {row[0]}")
                    continue
                m, _published, old, new, delta, ci, _differing = row
                lines.append(f"  {m}: {old} -> {new}, paired delta {delta} [95% CI {ci}]")
            if b.get("episodes_differing"):
                lines.append(f"  {len(b['episodes_differing'])} of {len(b['seeds'])} episodes differ")
        lines += [f"Note: {x}" for x in self.notes]
        return "\n".join(lines)

    def to_markdown(self) -> str:
        """The report for people (``report.md``)."""
        o, n = self.old, self.new
        out = [
            f"# hub-envs diff: `{o['repo_id']}@{o['sha'][:12]}` → `{n['repo_id']}@{n['sha'][:12]}`",
            "",
            f"**Verdict: {'identical behaviour' if self.behaviour_identical else 'behaviour differs'}**",
            "",
            "## Files",
            "",
            *(f"- {line}" for line in self._files_lines()),
            "",
        ]
        if self.suite:
            out += [
                "## Tasks",
                "",
                f"{self.suite['kind'][0].upper()}{self.suite['kind'][1:]}. Each task on both revisions, its episodes paired by "
                "seed; **the suite: "
                + ("identical behaviour" if self.behaviour_identical else f"{len(self.tasks_differing)} task(s) differ")
                + "**.",
                "",
                "| task | change | instruction | episodes diverged | golden fingerprint | benchmark episodes differing | verdict |",
                "| --- | --- | --- | --- | --- | --- | --- |",
                *("| " + " | ".join(_md_cell(c) for c in t.row()) + " |" for t in self.tasks),
                "",
            ]
        out += [
            "## Manifest fields",
            "",
        ]
        if self.manifest:
            out += ["| field | old | new |", "| --- | --- | --- |"]
            out += [
                f"| {md_code(c['field'])} | {md_code(_short(c['old'], 60))} | {md_code(_short(c['new'], 60))} |"
                for c in self.manifest
            ]
        else:
            out.append("none changed")
        out += ["", "## Spaces", ""]
        if self.spaces:
            out += ["| space | field | old | new |", "| --- | --- | --- | --- |"]
            out += [
                f"| {_md_cell(s['space'])} | {md_code(s['field'])} | {md_code(s['old'])} | {md_code(s['new'])} |"
                for s in self.spaces
            ]
        else:
            out.append("unchanged")
        out += ["", "## Behaviour", "", f"Golden fingerprint: {self.fingerprint.get('status')}", ""]
        if self.seeds:
            out += ["| seed | actions | steps old/new | first divergence |", "| --- | --- | --- | --- |"]
            for s in self.seeds:
                first = (
                    f"step {s.step}, {s.feature}{s.element or ''}: {_short(s.old, 40)} → {_short(s.new, 40)}"
                    if s.diverged
                    else "identical"
                )
                out.append(f"| {s.seed} | {s.source} | {s.steps_old}/{s.steps_new} | {first} |")
        for key, d in self.deltas.items():
            out.append(
                f"\n{key} delta (new − old, paired over {d['n']} seeds): {d['mean']:+.6g}, 95% bootstrap CI "
                f"[{d['ci'][0]:+.6g}, {d['ci'][1]:+.6g}]"
            )
        if self.benchmarks:
            out += [
                "",
                "## Benchmarks",
                "",
                "Each benchmark the old revision declares, re-run on both; the difference is paired episode by episode "
                f"(95% bootstrap CI over episodes, {self.settings.get('resamples')} resamples).",
                "",
                "| benchmark | metric | published | old | new | new − old | 95% CI | episodes differing |",
                "| --- | --- | --- | --- | --- | --- | --- | --- |",
            ]
            for b in self.benchmarks:
                for row in _benchmark_rows(b):
                    cells = (
                        ("—", "", "", "", "", "", f"not re-run: {row[0]}") if len(row) == 1 else (*row[:5], f"[{row[5]}]", row[6])
                    )
                    out.append(f"| {b['name']} ({_benchmark_what(b)}) | " + " | ".join(cells) + " |")
        if self.notes:
            out += ["", "## Notes", "", *(f"- {x}" for x in self.notes)]
        p = self.provenance
        out += [
            "",
            "## Provenance",
            "",
            f"- old: `{o['repo_id']}@{o['sha']}` (requested `{o['requested']}`)",
            f"- new: `{n['repo_id']}@{n['sha']}` (requested `{n['requested']}`)",
            f"- seeds: {[s.seed for s in self.seeds]}; settings: `{json.dumps(self.settings, sort_keys=True)}`",
            f"- hub-envs {p['hub_envs_version']}; " + ", ".join(f"{k} {v}" for k, v in sorted(p["versions_here"].items())),
            f"- generated at {p['generated_at']}",
        ]
        if self.paths.get("png"):
            out += ["", f"![per-step error]({Path(self.paths['png']).name})"]
        return "\n".join(out) + "\n"

    def plot(self, path: Path) -> Path | None:
        """The per-step errors of up to three diverged seeds.

        Args:
            path: the PNG to write.

        Returns:
            ``path``; None when nothing diverged, or without matplotlib.
        """
        shown = self.diverged[:3]
        if not shown:  # nothing to plot: no matplotlib import either
            return None
        try:
            import matplotlib  # heavy: matplotlib

            matplotlib.use("Agg")
            import matplotlib.pyplot as plt  # heavy: matplotlib
        except ImportError:
            return None
        fig, axes = plt.subplots(len(shown), 1, figsize=(7, 2.4 * len(shown)), squeeze=False)
        for ax, s in zip(axes[:, 0], shown, strict=True):
            for name, curve in s.errors.items():
                ax.plot(np.maximum(np.asarray(curve), 1e-12), label=name)
            ax.set_yscale("log")
            ax.set_title(f"seed {s.seed} ({s.source}): first divergence step {s.step}", fontsize=9)
            ax.set_xlabel("step")
            ax.set_ylabel("|new - old|")
            ax.legend(fontsize=7)
        return save_figure(fig, path, dpi=90)


# --- the operation ------------------------------------------------------------------------------


def _fingerprints(
    old: Any, new: Any, live_old: dict | None, live_new: dict | None, recorded: tuple[dict, dict] | None = None
) -> dict[str, Any]:
    a, b = recorded if recorded is not None else (old.manifest.fingerprint, new.manifest.fingerprint)
    recorded_same = (a.get("digest") == b.get("digest")) if a and b else None
    comparable = bool(a and b and a.get("seeds") == b.get("seeds") and a.get("steps") == b.get("steps"))
    live_same = live_old["digest"] == live_new["digest"] if live_old and live_new else None
    # the live recomputation is the measurement; the recorded digests decide only when it could not run
    same = live_same if live_same is not None else (recorded_same if comparable else True)
    if live_same is not None:
        status = "same" if live_same else "DIFFERENT"
        status += f" (recomputed here on seeds {live_old['seeds']} x {live_old['steps']} steps"
        status += f"; recorded digests {'equal' if recorded_same else 'differ'})" if recorded_same is not None else ")"
    elif recorded_same is not None:
        status = ("same" if recorded_same else "DIFFERENT") + " (recorded digests)"
    else:
        status = "none recorded"
    return {
        "same": bool(same),
        "status": status,
        "recorded_old": a.get("digest"),
        "recorded_new": b.get("digest"),
        "live_old": live_old and live_old["digest"],
        "live_new": live_new and live_new["digest"],
    }


def _paired_delta(x: list[float], y: list[float], resamples: int) -> dict[str, Any]:
    d = np.asarray(y, dtype=np.float64) - np.asarray(x, dtype=np.float64)
    lo, hi = bootstrap_ci(d, resamples=resamples, seed=0)
    return {
        "n": int(d.size),
        "mean": float(d.mean()),
        "ci": [lo, hi],
        "old_mean": float(np.mean(x)),
        "new_mean": float(np.mean(y)),
    }


def _benchmark_what(b: dict[str, Any]) -> str:
    policy = b.get("policy") or {}
    name = policy.get("checkpoint") or policy.get("type") or "?"
    return f"policy {name}, {len(b.get('seeds', []))} episodes"


def _benchmark_rows(b: dict[str, Any]) -> list[tuple[str, ...]]:
    """One benchmark's metrics as text: (metric, published, old, new, new − old, 95% CI, episodes differing) each,
    or ``(error,)`` when it was not re-run."""
    if b.get("error"):
        return [(b["error"],)]
    differing = f"{len(b.get('episodes_differing', []))} of {len(b['seeds'])}"
    return [
        (
            m,
            f"{v['published']:.6g}",
            f"{v['old_mean']:.6g}",
            f"{v['new_mean']:.6g}",
            f"{v['mean']:+.6g}",
            f"{v['ci'][0]:+.6g}, {v['ci'][1]:+.6g}",
            differing,
        )
        for m, v in b.get("metrics", {}).items()
    ]


def _benchmark_deltas(
    old: Any,
    new: Any,
    *,
    workers: int,
    resamples: int,
    tolerance: float,
    progress: bool,
    token: str | None,
    trust_policy_code: bool,
    declared: tuple[list[dict[str, Any]], list[dict[str, Any]]] | None = None,
) -> list[dict[str, Any]]:
    """Each benchmark ``old`` declares (``declared``: the old and new declarations to use, a suite task's), re-run on ``old`` and ``new`` (same policy, seeds and steps: the old
    declaration's, or the old config's episode length), and per metric the paired per-episode difference with its
    bootstrap CI; a benchmark that cannot run says why (``error``).

    An episode differs when a per-episode value differs by more than ``tolerance`` per step: a return, a sum of
    up to ``max_steps`` rewards each within ``tolerance`` of the other, by more than ``tolerance * max_steps``;
    a success (0 or 1) when it flips (any ``tolerance`` below 1)."""
    old_declared, new_declared = declared if declared is not None else (old.manifest.benchmarks, new.manifest.benchmarks)
    declared_new = {str(b.get("name")) for b in new_declared}
    out = []
    for bench in old_declared:
        max_steps = int(bench.get("max_steps") or old.config.episode_length)
        bench = {**bench, "max_steps": max_steps}
        runs = [
            BenchmarkRun(side, bench, resamples=resamples, token=token, trust_policy_code=trust_policy_code)
            for side in (old, new)
        ]
        entry: dict[str, Any] = {
            "name": runs[0].name,
            "policy": dict(bench.get("policy") or {}),
            "seeds": list(runs[0].seeds),
            "max_steps": max_steps,
            "declared_in_new": runs[0].name in declared_new,
            **({"task": new.task or old.task} if (new.task or old.task) else {}),
        }
        out.append(entry)
        error = runs[0].result.error or runs[1].result.error
        if error:
            entry["error"] = error
            continue
        for run, side in zip(runs, (old, new), strict=True):
            run.run(side, workers=workers, progress=progress)
        differing: set[int] = set()
        metrics = {}
        for m, published in runs[0].metrics.items():
            key = METRICS[m][0]
            x, y = runs[0].per_episode[key], runs[1].per_episode[key]
            allowed = tolerance * max_steps if key == "return" else tolerance
            differing |= {i for i, (p, q) in enumerate(zip(x, y, strict=True)) if abs(q - p) > allowed}
            metrics[m] = {
                **_paired_delta(x, y, resamples),
                "published": float(published),
                "per_episode_old": [float(v) for v in x],
                "per_episode_new": [float(v) for v in y],
            }
        entry["metrics"] = metrics
        entry["episodes_differing"] = sorted(differing)
    return out


def _ref(loaded: Any) -> dict[str, Any]:
    return {
        "repo_id": loaded.repo_id,
        "requested": loaded.requested_revision,
        "sha": loaded.revision,
        "content_digest": loaded.manifest.content_digest,
        "gym_id": loaded.gym_id,
    }


def diff(
    old: str,
    new: str,
    *,
    episodes: int = 2,
    random_episodes: int = 2,
    trust_remote_code: bool = False,
    tolerance: float = 0.0,
    out: str | Path | None = None,
    write: bool = True,
    workers: int = 1,
    benchmarks: bool = True,
    resamples: int = 1000,
    progress: bool = False,
    token: str | None = None,
    trust_policy_code: bool = False,
    **run: Unpack[CodeRun],
) -> DiffReport:
    """Compare two revisions of an env repo (``"user/name@A"``, ``"user/name@B"``), or two env repos.

    Args:
        old: ``user/name@rev`` (a branch, tag or sha; pin shas for a reproducible diff) or a local folder.
        new: the other revision, as ``old``.
        episodes: replay the old revision's recorded actions of its first ``episodes`` dataset episodes on both.
        random_episodes: also run this many seeded random-action episodes on both (seeds 0, 1, ... other than the
            replayed episodes' seeds).
        trust_remote_code: consent to run both revisions' code (or trust each commit with ``hub-envs trust``).
        tolerance: largest absolute difference that still counts as identical (0: bit-exact).
        out: folder for report.json/.md/.png (default ``diff-out/<user>/<name>/``); ``write=False``: none.
        workers: processes for the episodes (the result does not depend on it).
        benchmarks: re-run the old revision's declared benchmarks on both and report the paired metric deltas.
        resamples: bootstrap resamples of the paired deltas' confidence intervals.
        trust_policy_code: consent to load the LeRobot policy checkpoints those benchmarks name (other repos).
        run: how both revisions' code runs (``isolation``, ``sandbox``, ``versions``, ``step_timeout``; see
            :func:`hub_envs.load_env`): isolated, each revision steps in its own worker processes and this
            process imports neither.

    Returns:
        A :class:`DiffReport`; ``report.behaviour_identical`` is the verdict, ``report.exit_code`` 0 or 1. When either
        revision is a benchmark suite, ``report.tasks`` compares it task by task (:func:`task_pairs`; each task's own
        episodes, seeds, fingerprint and benchmarks) and the verdict is the suite's: every task identical.

    Raises:
        hub_envs.errors.HubEnvsError: a revision cannot be loaded or run (``hub-envs diff`` exits 2).
    """
    for name, v in (("episodes", episodes), ("random_episodes", random_episodes)):
        if isinstance(v, bool) or not isinstance(v, int) or v < 0:
            raise ConfigError(f"{name}={v!r}: pass a number of episodes >= 0.")
    run = code_run(run, "diff")
    timings: dict[str, float] = {}
    t0 = t = time.perf_counter()
    with contextlib.ExitStack() as loaded:  # both unregistered at the end
        # fingerprint off: a drifted fingerprint is what a diff reports, not a reason to stop
        a, b = (
            loaded.enter_context(
                load_env(ref, trust_remote_code=trust_remote_code, check=False, fingerprint="off", token=token, **run)
            )
            for ref in (old, new)
        )
        timings["load"] = time.perf_counter() - t
        t = time.perf_counter()
        files, fields = file_changes(a.manifest, b.manifest), manifest_changes(a.manifest, b.manifest)  # 1. static
        timings["static"] = time.perf_counter() - t
        pair = {
            "episodes": episodes,
            "random_episodes": random_episodes,
            "tolerance": tolerance,
            "workers": workers,
            "progress": progress,
            "benchmarks": benchmarks,
            "resamples": resamples,
            "token": token,
            "trust_policy_code": trust_policy_code,
        }
        suite, tasks = _suite_kind(a, b), []
        if suite:  # 2-3. each task on both revisions, then pooled by task and seed
            tasks = [_task_diff(a, b, o, n, timings=timings, **pair) for o, n in task_pairs(a.manifest, b.manifest)]
            behaviour, bench_out, fp = _pooled(tasks, suite)
        else:  # 2-3. the behaviour, the benchmarks
            behaviour, bench_out, fp = _compare_sides(a, b, timings=timings, **pair)
        deltas = _seed_deltas(behaviour.seeds, resamples)
        report = DiffReport(  # 4. the report
            old=_ref(a),
            new=_ref(b),
            files=files,
            manifest=fields,
            spaces=behaviour.spaces,
            seeds=behaviour.seeds,
            fingerprint=fp,
            deltas=deltas,
            benchmarks=bench_out,
            notes=behaviour.notes + _closing_notes(deltas, bench_out, behaviour),
            tasks=tasks,
            suite=suite,
            settings={
                "episodes": episodes,
                "random_episodes": random_episodes,
                "tolerance": float(tolerance),
                "workers": workers,
                "benchmarks": benchmarks,
                "resamples": resamples,
                "isolation": a.runs_as,
                "versions": run.get("versions", "current"),
            },
            provenance={
                "hub_envs_version": __version__,
                # each revision's code ran with these (a venv worker's own, when isolated in one)
                "versions_here": {**versions_run_with(a), **versions_run_with(b)},
                "versions_old": dict(a.manifest.versions),
                "versions_new": dict(b.manifest.versions),
                "python": sys.version.split()[0],
                "generated_at": _dt.datetime.now(_dt.UTC).replace(microsecond=0).isoformat(),
            },
        )
        report.finish(timings, t0, out=out, default=default_out_dir(DEFAULT_OUT, b.repo_id), write=write)
        return report


def _compare_sides(
    a: Any,
    b: Any,
    *,
    timings: dict[str, float],
    benchmarks: bool,
    resamples: int,
    token: str | None,
    trust_policy_code: bool,
    among: list[int] | None = None,
    recorded: tuple[dict, dict] | None = None,
    declared: tuple[list, list] | None = None,
    **episodes_run: Any,
) -> tuple[_Behaviour, list[dict[str, Any]], dict[str, Any]]:
    """The behaviour of two sides (two revisions, or one task of each: ``among`` its old dataset episodes, ``recorded``
    its old and new fingerprints, ``declared`` its old and new benchmarks), the benchmarks' paired deltas, the fingerprints."""
    t = time.perf_counter()
    behaviour = _behaviour(a, b, among=among, fingerprint=None if recorded is None else recorded[0], **episodes_run)
    timings["behaviour"] = timings.get("behaviour", 0.0) + time.perf_counter() - t
    t = time.perf_counter()
    bench_out: list[dict[str, Any]] = []
    old_declared = a.manifest.benchmarks if declared is None else declared[0]
    if benchmarks and not behaviour.action_changed:
        bench_out = _benchmark_deltas(
            a,
            b,
            workers=episodes_run["workers"],
            resamples=resamples,
            tolerance=episodes_run["tolerance"],
            progress=episodes_run["progress"],
            token=token,
            trust_policy_code=trust_policy_code,
            declared=declared,
        )
        timings["benchmarks"] = timings.get("benchmarks", 0.0) + time.perf_counter() - t
    elif benchmarks and old_declared:
        behaviour.notes.append("the action space changed: the benchmarks were not re-run")
    for bm in bench_out:
        if bm.get("error"):
            behaviour.notes.append(f"benchmark {bm['name']} was not re-run: {bm['error']}")
    return behaviour, bench_out, _fingerprints(a, b, behaviour.live_old, behaviour.live_new, recorded)


def _suite_kind(a: Any, b: Any) -> dict[str, Any]:
    """``{"old": tasks, "new": tasks, "kind": ...}`` when either revision is a benchmark suite, else ``{}``; the kind
    says plainly what is compared with what."""
    if not (a.is_suite or b.is_suite):
        return {}
    n_a, n_b = len(a.tasks), len(b.tasks)
    if a.is_suite and b.is_suite:
        kind = f"suite vs suite ({n_a} tasks -> {n_b} tasks)"
    else:
        suite, single = ("old", "new") if a.is_suite else ("new", "old")
        pair = next(p for p in task_pairs(a.manifest, b.manifest) if "" in p)
        kind = (
            f"the {suite} revision is a suite of {max(n_a, n_b)} tasks, the {single} one a one-task env: it is compared "
            f"with the suite's task {pair[0] or pair[1]!r} only, the suite's other tasks have no counterpart"
        )
    return {"old": n_a, "new": n_b, "kind": kind}


def _task_diff(a: Any, b: Any, old_task: str | None, new_task: str | None, *, timings: dict[str, float], **pair: Any) -> TaskDiff:
    """One task across the revisions (:func:`task_pairs`): its instruction on each side, and when it is on both, its
    episodes (the old task's dataset episodes, then seeded random ones), fingerprint and benchmarks, each side making
    that task (``""``: a one-task side, making its own env)."""
    rec_a = a.manifest.task_record(old_task) if old_task else {}
    rec_b = b.manifest.task_record(new_task) if new_task else {}
    out = TaskDiff(old_task, new_task, rec_a.get("instruction"), rec_b.get("instruction"))
    if old_task is None or new_task is None:
        return out
    side_a = a.for_task(old_task) if old_task else a
    side_b = b.for_task(new_task) if new_task else b
    behaviour, bench_out, fp = _compare_sides(
        side_a,
        side_b,
        timings=timings,
        among=list(rec_a["episodes"]) if old_task else None,
        recorded=(
            rec_a.get("fingerprint") or {} if old_task else a.manifest.fingerprint,
            rec_b.get("fingerprint") or {} if new_task else b.manifest.fingerprint,
        ),
        declared=(
            [x for x in a.manifest.benchmarks if not old_task or x.get("task") == old_task],
            [x for x in b.manifest.benchmarks if not new_task or x.get("task") == new_task],
        ),
        **pair,
    )
    for s in behaviour.seeds:
        s.task = new_task or old_task
    out.spaces, out.seeds, out.benchmarks, out.fingerprint = behaviour.spaces, behaviour.seeds, bench_out, fp
    out.deltas = _seed_deltas(behaviour.seeds, pair["resamples"])
    out.notes = behaviour.notes
    return out


def _pooled(tasks: list[TaskDiff], suite: dict[str, Any]) -> tuple[_Behaviour, list[dict[str, Any]], dict[str, Any]]:
    """A suite's tasks pooled: every task's space changes, paired episodes (matched by task and seed) and benchmarks;
    the fingerprint the same when every compared task's is."""
    compared = [t for t in tasks if t.compared]
    spaces = [{**sp, "task": t.name} for t in compared for sp in t.spaces]
    pooled = _Behaviour(spaces=spaces, action_changed=any(sp["space"] == "action_space" for sp in spaces))
    pooled.seeds = [s for t in compared for s in t.seeds]
    pooled.notes = [f"task {t.name}: {n}" for t in compared for n in t.notes]
    same = sum(bool(t.fingerprint.get("same", True)) for t in compared)
    fp = {"same": same == len(compared), "status": f"per task: {same} of {len(compared)} compared task(s) the same"}
    return pooled, [b for t in compared for b in t.benchmarks], fp


@dataclass
class _Behaviour:
    """What running both revisions found: their space changes, each seed's comparison, the golden fingerprints
    recomputed on both (None: not run), and what the report notes."""

    spaces: list[dict[str, Any]]
    action_changed: bool
    seeds: list[SeedDiff] = field(default_factory=list)
    live_old: dict | None = None
    live_new: dict | None = None
    notes: list[str] = field(default_factory=list)


def _behaviour(
    a: Any,
    b: Any,
    *,
    episodes: int,
    random_episodes: int,
    tolerance: float,
    workers: int,
    progress: bool,
    among: list[int] | None = None,
    fingerprint: dict[str, Any] | None = None,
) -> _Behaviour:
    """Both revisions' spaces compared, then the same episodes on both (the old revision's recorded actions, of its
    dataset episodes ``among`` when given, then seeded random actions), and the golden fingerprint recomputed on both
    (``fingerprint``: the recorded one whose seeds and steps to use, default the old manifest's)."""
    env_a, env_b = a.make(), b.make()
    try:
        spaces = _space_changes(env_a, env_b)
        action_space = env_a.action_space
    finally:
        env_a.close()
        env_b.close()
    found = _Behaviour(spaces=spaces, action_changed=any(s["space"] == "action_space" for s in spaces))
    if found.action_changed:
        found.notes.append("the action space changed: the same actions cannot drive both revisions, so no episodes were compared")
        return found
    recorded = _recorded_actions(a, episodes, among)
    if episodes and not recorded:
        found.notes.append(f"{a.repo_id}@{a.revision[:12]} has no dataset with seeds: no recorded actions to replay")
    # random-action seeds other than the replayed episodes' (push_env records seeded random actions: the same seed
    # would repeat a recorded episode)
    used = {s for _, s, _ in recorded}
    random_seeds = [s for s in range(len(used) + random_episodes + 1) if s not in used][:random_episodes]
    seeds = [s for _, s, _ in recorded] + random_seeds
    policy = [env_actions(acts, action_space, f"{a.repo_id}@{a.revision[:12]}") for _, _, acts in recorded]
    policy += [None] * len(random_seeds)
    max_steps = max(int(a.config.episode_length), int(b.config.episode_length))
    runs = [
        run_episodes(
            side.make,
            seeds,
            max_steps=max_steps,
            policy=policy if recorded else None,
            workers=workers,
            progress=progress,
            desc=f"{side.repo_id}@{side.revision[:12]}",
        )
        if seeds
        else []
        for side in (a, b)
    ]
    names = dict(a.config.features_map)
    sources = [f"recorded actions of episode {i}" for i, _, _ in recorded] + ["random actions"] * len(random_seeds)
    found.seeds = [
        _compare(ra, rb, ra.seed, src, names, tolerance) for ra, rb, src in zip(runs[0], runs[1], sources, strict=True)
    ]
    # the golden fingerprint of both, recomputed here on the old manifest's seeds and steps (a few short episodes)
    fp = a.manifest.fingerprint if fingerprint is None else fingerprint
    if fp and fp.get("seeds"):
        fp_seeds, steps = [int(s) for s in fp["seeds"]], int(fp.get("steps", FINGERPRINT_STEPS))
        found.live_old = golden_fingerprint(a.make, seeds=fp_seeds, steps=steps)
        found.live_new = golden_fingerprint(b.make, seeds=fp_seeds, steps=steps)
    return found


def _seed_deltas(seeds: list[SeedDiff], resamples: int) -> dict[str, Any]:
    """The paired per-seed return and success deltas (new - old) with their bootstrap intervals."""
    if not seeds:
        return {}
    return {
        "return": _paired_delta([s.return_old for s in seeds], [s.return_new for s in seeds], resamples),
        "success": _paired_delta([float(s.success_old) for s in seeds], [float(s.success_new) for s in seeds], resamples),
    }


def _closing_notes(deltas: dict[str, Any], bench_out: list[dict[str, Any]], behaviour: _Behaviour) -> list[str]:
    """What the report says last: intervals over too few episodes to be calibrated, observations not compared."""
    notes = []
    few = sorted({d["n"] for d in deltas.values()} | {len(bm["seeds"]) for bm in bench_out if bm.get("metrics")})
    if few and few[0] < FEW_EPISODES:
        notes.append(
            f"a paired interval over {few[0]} episodes is little more than the range of the differences, not a calibrated "
            f"95% interval: use {FEW_EPISODES} or more (--episodes/--random_episodes; push_env --episodes for the benchmark)"
        )
    if any(s["space"] == "observation_space" for s in behaviour.spaces) and behaviour.seeds:
        notes.append("the observation space changed: the observations whose shape changed were not compared step by step")
    return notes
