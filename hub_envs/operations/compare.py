"""``compare``: policies evaluated on the same seeds of one env commit (or of two revisions, ``against``), their success
rates and returns with bootstrap intervals, and their seed-paired differences.

Example:
    >>> from hub_envs.operations.compare import episodes_for_half_width
    >>> episodes_for_half_width([0.0, 1.0] * 10, half_width=0.05)  # a 50 % success rate: ~400 episodes for ±5 points
    405
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import statistics
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Unpack

import numpy as np

from hub_envs._text import md_code
from hub_envs.backends import make_backend
from hub_envs.errors import ConfigError, ReproductionError
from hub_envs.harness.benchmark import BenchmarkRun, bootstrap_ci
from hub_envs.harness.provenance import run_provenance
from hub_envs.harness.report_files import ReportFiles, default_out_dir, save_figure, seeds_text
from hub_envs.loading.isolated import CodeRun, code_run
from hub_envs.loading.load import load_env
from hub_envs.repo import hub_io
from hub_envs.repo.refs import local_path, parse_repo_ref

__all__ = [
    "compare",
    "CompareReport",
    "Estimate",
    "PolicyResult",
    "PairedDifference",
    "TaskComparison",
    "episodes_for_half_width",
]

DEFAULT_OUT = Path("compare-out")
HALF_WIDTH = 0.05  # ±5 points of a rate


def episodes_for_half_width(values, half_width: float = HALF_WIDTH, confidence: float = 0.95) -> int | None:
    """Episodes whose mean would have a ``confidence`` interval of ± ``half_width`` (normal approximation).

    Args:
        values: per-episode values (their sample standard deviation is used).
        half_width: the interval's half-width (0.05: ±5 points of a rate).
        confidence: the interval's level.

    Returns:
        The number of episodes; None when the values do not vary (no estimate from them).
    """
    values = [float(v) for v in values]
    if len(values) < 2:
        return None
    sd = statistics.stdev(values)
    if sd == 0:
        return None
    z = statistics.NormalDist().inv_cdf(0.5 + confidence / 2)
    return math.ceil((z * sd / half_width) ** 2)


@dataclass(frozen=True)
class Estimate:
    """Per-episode values in seed order, their mean and its seeded bootstrap interval (which resamples seeds).

    >>> e = Estimate.of([1.0, 0.0, 1.0, 1.0], resamples=1000, confidence=0.95, seed=0)
    >>> e.mean, e.ci, e.text(scale=100, sign="+", fmt=".1f")
    (0.75, (0.25, 1.0), '+75.0 [+25.0, +100.0]')
    """

    values: tuple[float, ...]
    mean: float
    ci: tuple[float, float]

    @classmethod
    def of(cls, values: Sequence[float], *, resamples: int, confidence: float, seed: int) -> Estimate:
        """The estimate of per-episode values.

        Args:
            values: in seed order.
            resamples, confidence, seed: the bootstrap's.

        Returns:
            Their mean and its seeded percentile bootstrap interval.
        """
        v = tuple(float(x) for x in values)
        return cls(v, float(statistics.fmean(v)), bootstrap_ci(v, resamples=resamples, confidence=confidence, seed=seed))

    def text(self, *, scale: float = 1.0, sign: str = "", fmt: str = ".4g") -> str:
        """The estimate as text.

        Args:
            scale: multiplies the numbers (100: percent).
            sign: ``"+"`` to sign them.
            fmt: their format.

        Returns:
            ``mean [low, high]``.
        """
        f = f"{sign}{fmt}"
        return f"{scale * self.mean:{f}} [{scale * self.ci[0]:{f}}, {scale * self.ci[1]:{f}}]"


@dataclass(frozen=True)
class PolicyResult:
    """One policy over the compared seeds: its returns and successes (1.0 / 0.0; the mean is the success rate)."""

    label: str
    spec: dict[str, Any]
    returns: Estimate
    successes: Estimate
    episodes_for_5_points: int | None  # on the success rate
    seconds: float

    def summary(self) -> str:
        """One line: the success rate and mean return with their intervals."""
        success = self.successes.text(scale=100, fmt=".1f").replace(" [", " % [")
        return f"{self.label}: success {success}, mean return {self.returns.text()}"


@dataclass(frozen=True)
class PairedDifference:
    """``a - b`` seed by seed (returns and successes), with seed-paired bootstrap intervals."""

    a: str
    b: str
    returns: Estimate
    successes: Estimate
    episodes_for_5_points: int | None  # on the success-rate difference

    def summary(self) -> str:
        """One line: the paired differences with their intervals."""
        success = self.successes.text(scale=100, sign="+", fmt=".1f").replace(" [", " points [")
        return f"{self.a} - {self.b} (paired over seeds): success {success}, mean return {self.returns.text(sign='+')}"


@dataclass(frozen=True)
class TaskComparison:
    """One task of a benchmark suite: each policy on it, and their seed-paired differences on it."""

    task: str
    policies: list[PolicyResult]
    differences: list[PairedDifference]


@dataclass
class CompareReport(ReportFiles):
    """What ``hub-envs compare`` found. On a benchmark suite, ``tasks`` holds each task's comparison and ``policies`` /
    ``differences`` pool every task's episodes (pairs matched by task and seed; the bootstrap resamples those)."""

    policies: list[PolicyResult]
    differences: list[PairedDifference]
    provenance: dict[str, Any]  # the repo, the resolved sha, the seeds, versions (harness.provenance.run_provenance)
    settings: dict[str, Any]
    paths: dict[str, str] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    tasks: list[TaskComparison] = field(default_factory=list)

    @property
    def repo_id(self) -> str:
        return self.provenance["repo_id"]

    @property
    def sha(self) -> str:
        return self.provenance["sha"]

    @property
    def seeds(self) -> list[int]:
        return self.provenance["seeds"]

    def _needed(self, n: int | None) -> str:
        return f"~{n}" if n is not None else f"no estimate (no variation in {len(self.seeds)} episodes)"

    @property
    def envs(self) -> str:
        """The env commit(s) compared: ``user/name@<sha>`` (and ``user/name@<sha>`` of ``against``)."""
        other = self.provenance.get("against")
        return f"{self.repo_id}@{self.sha}" + (f" and {other['repo_id']}@{other['sha']}" if other else "")

    def summary(self) -> str:
        """What ``hub-envs compare`` prints: the envs, each policy, each pair, the episodes a ±5-point estimate needs."""
        conf = int(100 * self.settings["confidence"])
        lines = [f"Compared on {self.envs}: {len(self.seeds)} episodes, seeds {seeds_text(self.seeds)}"]
        if self.tasks:
            lines[0] += f", on each of {len(self.tasks)} tasks"
            for t in self.tasks:
                lines.append(f"  task {t.task!r}:")
                lines += [f"    {p.summary()}" for p in t.policies]
                lines += [f"    {d.summary()}" for d in t.differences]
            lines.append(f"  the suite (every task's episodes pooled, {len(self.tasks) * len(self.seeds)} per policy):")
        lines += [f"  {p.summary()}" for p in self.policies]
        lines += [f"  {d.summary()}" for d in self.differences]
        lines.append(f"  ({conf}% bootstrap intervals, {self.settings['resamples']} resamples)")
        for p in self.policies:
            lines.append(f"  episodes for ±5 points on {p.label}'s success rate: {self._needed(p.episodes_for_5_points)}")
        for d in self.differences:
            lines.append(f"  episodes for ±5 points on {d.a} - {d.b}: {self._needed(d.episodes_for_5_points)}")
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        """The report as JSON-ready data (``report.json``)."""
        return {
            "repo_id": self.repo_id,
            "sha": self.sha,
            "seeds": self.seeds,
            "policies": [asdict(p) for p in self.policies],
            "differences": [asdict(d) for d in self.differences],
            "provenance": self.provenance,
            "settings": self.settings,
            "timings": self.timings,
            **({"tasks": [asdict(t) for t in self.tasks]} if self.tasks else {}),
        }

    def to_markdown(self) -> str:
        """The report for people (``report.md``): the tables, the provenance, the plot."""
        conf = int(100 * self.settings["confidence"])
        out = [
            f"# Policy comparison on `{self.repo_id}`",
            "",
            f"`{self.envs}`, {len(self.seeds)} episodes per policy on the same reset seeds ({seeds_text(self.seeds)}), "
            f"{conf}% bootstrap intervals ({self.settings['resamples']} resamples, seeded).",
            "",
            "| policy | success rate | CI | mean return | CI | episodes for ±5 points |",
            "|---|---|---|---|---|---|",
        ]
        for p in self.policies:
            out.append(
                f"| {p.label} | {p.successes.text(scale=100, fmt='.1f').replace(' [', ' % | [')} | "
                f"{p.returns.text().replace(' [', ' | [')} | {self._needed(p.episodes_for_5_points)} |"
            )
        out += [
            "",
            "## Paired differences",
            "",
            "Seed by seed (the same reset seed on both sides), resampling seeds in the bootstrap.",
            "",
            "| A - B | success rate (points) | CI | mean return | CI | episodes for ±5 points |",
            "|---|---|---|---|---|---|",
        ]
        for d in self.differences:
            out.append(
                f"| {d.a} - {d.b} | {d.successes.text(scale=100, sign='+', fmt='.1f').replace(' [', ' | [')} | "
                f"{d.returns.text(sign='+').replace(' [', ' | [')} | {self._needed(d.episodes_for_5_points)} |"
            )
        for t in self.tasks:
            out += [
                "",
                f"## Task {md_code(t.task, table_cell=False)}",
                "",
                "| policy or A - B | success rate | mean return |",
                "|---|---|---|",
            ]
            out += [f"| {q.label} | {q.successes.text(scale=100, fmt='.1f')} | {q.returns.text()} |" for q in t.policies]
            out += [
                f"| {d.a} - {d.b} | {d.successes.text(scale=100, sign='+', fmt='.1f')} | {d.returns.text(sign='+')} |"
                for d in t.differences
            ]
        p = self.provenance
        out += [
            "",
            "## Provenance",
            "",
            f"- env: `{self.repo_id}@{self.sha}` (content digest `{p.get('content_digest')}`)",
            *(
                [
                    f"- against: `{p['against']['repo_id']}@{p['against']['sha']}` (content digest `{p['against']['content_digest']}`)"
                ]
                if p.get("against")
                else []
            ),
            *[f"- policy {q.label}: `{json.dumps(q.spec, sort_keys=True)}`" for q in self.policies],
            f"- versions: {', '.join(f'{k} {v}' for k, v in sorted(p.get('versions_here', {}).items()))}",
            f"- generated {p.get('generated_at')} with hub-envs {p.get('hub_envs_version')}",
            "",
        ]
        if self.paths.get("png"):
            out += [f"![success rates, returns and paired differences]({Path(self.paths['png']).name})", ""]
        return "\n".join(out)

    def plot(self, path: str | Path) -> Path | None:
        """Write :meth:`figure` as a PNG.

        Args:
            path: the PNG to write.

        Returns:
            ``path``; None (no file) without matplotlib (the ``plots`` extra).
        """
        fig = self.figure()
        return None if fig is None else save_figure(fig, path)

    def figure(self):
        """The plot as a matplotlib ``Figure`` (None without matplotlib): success rates (axis 0-100 %) and mean
        returns with their intervals, and the first pair's per-seed return differences. Policies are labelled by
        :func:`short_labels` (what tells their names apart), with a legend giving each shortened label's full name."""
        try:
            import matplotlib  # heavy: matplotlib
        except ModuleNotFoundError:
            return None
        matplotlib.use("Agg", force=False)
        import matplotlib.pyplot as plt  # heavy: matplotlib
        from matplotlib.lines import Line2D  # heavy: matplotlib

        fig, axes = plt.subplots(1, 3, figsize=(13, 3.6), layout="constrained")  # constrained: room for the legend below
        names = [p.label for p in self.policies]
        labels = short_labels(names)
        x = np.arange(len(self.policies))
        for ax, (value, ci, title) in zip(
            axes[:2],
            [
                ([100 * p.successes.mean for p in self.policies], [(100 * p.successes.ci[0], 100 * p.successes.ci[1]) for p in self.policies], "success rate (%)"),
                ([p.returns.mean for p in self.policies], [p.returns.ci for p in self.policies], "mean return"),
            ],
        ):  # fmt: skip
            v = np.asarray(value, dtype=float)
            lo = v - np.asarray([c[0] for c in ci]), np.asarray([c[1] for c in ci]) - v
            ax.bar(x, v, yerr=np.abs(np.asarray(lo)), capsize=6, color="tab:blue", alpha=0.7, error_kw={"clip_on": False})
            ax.set_xticks(x, labels, rotation=15, fontsize=8)
            ax.set_title(title)
        axes[0].set_ylim(0, 100)  # a rate: 0-100 % whatever the values (all 0 would otherwise draw negative percentages)
        for xi, p in zip(x, self.policies):  # the rate, written at the bar's foot beside its interval (0 % shows no bar)
            axes[0].text(xi + 0.08, 1.5, f"{100 * p.successes.mean:.0f} %", ha="left", va="bottom", fontsize=8)
        renamed = [(short, full) for short, full in zip(labels, names) if short != full]
        if renamed:
            fig.legend(
                [Line2D([], [], linestyle="none")] * len(renamed),
                [f"{short}  =  {full}" for short, full in renamed],
                loc="outside lower center",
                ncols=1 if max(len(f) for _, f in renamed) > 60 else min(2, len(renamed)),
                fontsize=7,
                handlelength=0,
                frameon=False,
                title="policies",
                title_fontsize=7,
            )
        ax = axes[2]
        if self.differences:
            d = self.differences[0]
            diffs = np.asarray(d.returns.values, dtype=float)
            ax.plot(np.arange(len(diffs)), diffs, "o", ms=4)
            ax.axhline(d.returns.mean, color="black", lw=1)
            ax.axhspan(d.returns.ci[0], d.returns.ci[1], color="tab:orange", alpha=0.3, label="paired 95% CI of the mean")
            ax.axhline(0, color="grey", lw=0.8, ls=":")
            ax.set_xlabel("episode (seed order)")
            short = dict(zip(names, labels))
            ax.set_title(f"return: {short[d.a]} - {short[d.b]}", fontsize=9)
            ax.legend(fontsize=7, loc="best")
        fig.suptitle(f"{self.repo_id}@{self.sha[:12]}: {len(self.seeds)} paired episodes", fontsize=10)
        return fig


def policy_spec(text: str | os.PathLike, *, token: str | None = None) -> dict[str, Any]:
    """The spec of a policy named on the command line.

    A folder is told from a repo id as ``load_env`` tells an env folder from one (:func:`hub_envs.repo.refs.local_path`):
    ``user/name`` always means the Hub, even when a folder of that name exists here (a local checkpoint's code runs as
    the caller's own, without consent); write ``./user/name`` for the folder.

    Args:
        text: ``random``, a local ``pretrained_model`` folder, or a Hub repo id (``user/policy[@rev]``).
        token: the Hub token (to resolve a revision).

    Returns:
        ``{"type": "random"}``, ``{"type": "lerobot", "path": ...}`` or ``{"type": "lerobot", "checkpoint": "user/policy@<sha>"}``
        (the revision resolved to its commit).

    Raises:
        ConfigError: a path that is no folder, or text that is no repo id.
        EnvRepoNotFoundError, RevisionNotFoundError: the Hub has no such repo or revision.
    """
    if isinstance(text, str):
        text = text.strip(" ")  # around the commas of --policies=a, b (a newline or other character is refused below)
        if text.lower() == "random":
            return {"type": "random"}
    path = local_path(text, stacklevel=3)
    if path is not None:
        if not path.is_dir():
            raise ConfigError(
                f"--policies: {text!r} is neither 'random', an existing folder (a LeRobot pretrained_model), nor a Hub "
                "repo id user/name[@revision]."
            )
        return {"type": "lerobot", "path": str(path.resolve())}
    repo_id, rev = parse_repo_ref(text, what="--policies: policy")
    with hub_io.translate_hub_errors(repo_id, rev or "main"):
        sha = hub_io.api(token).repo_info(repo_id, revision=rev).sha
    return {"type": "lerobot", "checkpoint": f"{repo_id}@{sha}"}


_SHA_RE = re.compile(r"\b([0-9a-f]{8})[0-9a-f]{32}\b")


def short_labels(names: Sequence[str], max_len: int = 32) -> list[str]:
    """Labels for a plot that tell ``names`` (distinct) apart: the path components all names share at the start and
    at the end become ``…``; a label still longer than ``max_len`` is cut to what is left's shortest tail of whole
    components that no other label has, else its shortest such head, else as many of its last (or first)
    characters as fit. Distinct names always give distinct labels (else the names themselves are returned).

    >>> short_labels(["a/last/pretrained_model", "b/last/pretrained_model"])
    ['a/…', 'b/…']
    >>> short_labels(["outputs/train/act_1/checkpoints/last/pretrained_model", "outputs/train/act_2/checkpoints/005000/pretrained_model"])
    ['…/act_1/checkpoints/last/…', '…/act_2/checkpoints/005000/…']
    >>> short_labels(["random", "outputs/train/act/checkpoints/last/pretrained_model"])
    ['random', '…/pretrained_model']
    >>> short_labels(["random", "random (2)"]), short_labels(["user/act-reach", "user/act-pusht"])
    (['random', 'random (2)'], ['…/act-reach', '…/act-pusht'])
    >>> short_labels(["out/act_1/checkpoints/last/pretrained_model", "out/act_2/checkpoints/last/pretrained_model", "random"])
    ['out/act_1/…', 'out/act_2/…', 'random']
    """
    names = [str(n) for n in names]
    if not names or len(set(names)) != len(names):
        return names
    parts = [_SHA_RE.sub(r"\1…", n).split("/") for n in names]  # a pinned user/policy@<40-hex sha>: 8 hex tell it
    shortest = min((len(p) for p in parts), default=0)
    pre = suf = 0
    if len(names) > 1:
        while pre < shortest - 1 and len({p[pre] for p in parts}) == 1:
            pre += 1
        while pre + suf < shortest - 1 and len({p[len(p) - 1 - suf] for p in parts}) == 1:
            suf += 1
    mids = [p[pre : len(p) - suf] for p in parts]
    head = "…/" if any(c not in ("", ".") for c in parts[0][:pre]) else ""  # a leading "./" or "/" alone is not worth a "…"
    tail = "/…" if suf else ""

    def wrapped(middle: str) -> str:  # one "…" where the dropped part and the cut meet
        return ("" if middle.startswith("…") else head) + middle + ("" if middle.endswith("…") else tail)

    labels = [wrapped("/".join(m)) for m in mids]
    for i, mid in enumerate(mids):
        if len(labels[i]) <= max_len:
            continue
        text = "/".join(mid)
        others = ["/".join(m) for j, m in enumerate(mids) if j != i]
        n = len(mid)
        # (label, distinguishing): a tail no other name ends with, a head no other name starts with
        cuts = [
            (f"…/{t}", not any(o.endswith("/" + t) or o == t for o in others)) for t in ("/".join(mid[-k:]) for k in range(1, n))
        ]
        cuts += [
            (f"{h}/…", not any(o.startswith(h + "/") or o == h for o in others)) for h in ("/".join(mid[:k]) for k in range(1, n))
        ]
        cuts += [(f"…{text[-k:]}", not any(o.endswith(text[-k:]) for o in others)) for k in range(len(text) - 1, 0, -1)]
        cuts += [(f"{text[:k]}…", not any(o.startswith(text[:k]) for o in others)) for k in range(len(text) - 1, 0, -1)]
        labels[i] = next((wrapped(c) for c, ok in cuts if ok and len(wrapped(c)) <= max_len), labels[i])
    return labels if len(set(labels)) == len(labels) else names


def _labels(names: list[str]) -> list[str]:
    out: list[str] = []
    for name in names:
        label, n = name, 2
        while label in out:
            label, n = f"{name} ({n})", n + 1
        out.append(label)
    return out


def _run_policy(loaded: Any, label: str, spec: dict, seeds: list[int], **kw: Any) -> PolicyResult:
    bench = {"name": label, "policy": spec, "seeds": seeds, "metrics": {"mean_return": 0.0, "success_rate": 0.0}}
    run = BenchmarkRun(
        loaded,
        bench,
        resamples=kw["resamples"],
        confidence=kw["confidence"],
        seed=kw["bootstrap_seed"],
        token=kw["token"],
        trust_policy_code=kw["trust_policy_code"],
    )
    if not run.runnable:
        raise ReproductionError(f"policy {label}: {run.result.error}")
    result = run.run(loaded, progress=kw["progress"], backend=kw["backend"])
    stats = dict(resamples=kw["resamples"], confidence=kw["confidence"], seed=kw["bootstrap_seed"])
    successes = [float(s) for s in result.reproduced_per_episode["success"]]
    return PolicyResult(
        label=label,
        spec=spec,
        returns=Estimate.of(result.reproduced_per_episode["return"], **stats),
        successes=Estimate.of(successes, **stats),
        episodes_for_5_points=episodes_for_half_width(successes, confidence=kw["confidence"]),
        seconds=round(result.seconds, 4),
    )


def _paired(a: PolicyResult, b: PolicyResult, *, resamples: int, confidence: float, seed: int) -> PairedDifference:
    # resampling the differences resamples seeds: each draw keeps both policies' episodes of one seed
    stats = dict(resamples=resamples, confidence=confidence, seed=seed)
    ds = [x - y for x, y in zip(a.successes.values, b.successes.values, strict=True)]
    return PairedDifference(
        a=a.label,
        b=b.label,
        returns=Estimate.of([x - y for x, y in zip(a.returns.values, b.returns.values, strict=True)], **stats),
        successes=Estimate.of(ds, **stats),
        episodes_for_5_points=episodes_for_half_width(ds, confidence=confidence),
    )


def _compared_tasks(envs: list[Any], task: str | None) -> list[str]:
    """The suite tasks a comparison runs (``[]``: a one-task env): ``task`` comma-separated, or all the first env's."""
    if not envs[0].is_suite:
        if task is not None:
            raise ConfigError(f"--task={task!r}: {envs[0].repo_id} is a one-task env (no [tool.hub-envs] tasks); leave it out.")
        return []
    names = envs[0].tasks if task is None else [t.strip() for t in str(task).split(",") if t.strip()]
    for env in envs:
        for name in names:
            env.manifest.task_record(name)  # ConfigError naming the env's tasks, before any episode runs
    return list(names)


def _differences(results: list[list[PolicyResult]], resamples: int, confidence: float, seed: int) -> list[PairedDifference]:
    """The seed-paired differences of a comparison's arms (:func:`_pairs`)."""
    return [_paired(a, b, resamples=resamples, confidence=confidence, seed=seed) for a, b in _pairs(results)]


def _pooled(arms: list[PolicyResult], resamples: int, confidence: float, seed: int) -> PolicyResult:
    """One arm over several tasks: their episodes in task order, as one estimate (the bootstrap resamples episodes)."""
    stats = dict(resamples=resamples, confidence=confidence, seed=seed)
    successes = [v for a in arms for v in a.successes.values]
    return PolicyResult(
        label=arms[0].label,
        spec=arms[0].spec,
        returns=Estimate.of([v for a in arms for v in a.returns.values], **stats),
        successes=Estimate.of(successes, **stats),
        episodes_for_5_points=episodes_for_half_width(successes, confidence=confidence),
        seconds=round(sum(a.seconds for a in arms), 4),
    )


def _env_label(env: Any, first: Any) -> str:
    """``@<sha12>`` for a revision of the first env's repo, ``user/name@<sha12>`` for another repo."""
    return ("" if env.repo_id == first.repo_id else env.repo_id) + f"@{env.revision[:12]}"


def _pairs(results: list[list[PolicyResult]]) -> list[tuple[PolicyResult, PolicyResult]]:
    """What a comparison pairs, seed by seed (``(a, b)``: ``a - b``): with two envs, each policy on the second against
    itself on the first (what the revision changed); then, in each env, every two policies."""
    pairs = []
    if len(results) == 2:
        pairs += list(zip(results[1], results[0]))
    for per_env in results:
        pairs += [(per_env[i], per_env[j]) for i in range(len(per_env)) for j in range(i + 1, len(per_env))]
    return pairs


def compare(
    repo_id: str,
    policies: Sequence[str | os.PathLike],
    *,
    against: str | None = None,
    episodes: int = 20,
    seed: int = 0,
    revision: str | None = None,
    trust_remote_code: bool = False,
    trust_policy_code: bool = False,
    workers: int | None = None,
    resamples: int = 1000,
    confidence: float = 0.95,
    out: str | Path | None = None,
    write: bool = True,
    progress: bool = True,
    token: str | None = None,
    backend: str = "local",
    ray_address: str | None = None,
    task: str | None = None,
    **run: Unpack[CodeRun],
) -> CompareReport:
    """Evaluate ``policies`` on the episodes ``seed .. seed + episodes - 1`` of ``repo_id`` and compare them, seed-paired;
    with ``against``, also on those episodes of another revision (or env), and compare each policy across the two.

    The stages: resolve the policies, load the env (and ``against``), run every (env, policy) arm on the same seeds
    (:func:`_run_policy`), pair them (:func:`_pairs`), report.

    Args:
        repo_id: ``user/name@<sha>`` (pin it: the comparison names the commit), or a local folder.
        policies: at least two of ``"random"``, a local LeRobot ``pretrained_model`` folder written as a path
            (``./x``, ``/abs``, a ``Path``; as for envs, ``user/name`` always means the Hub), a Hub repo id (one is
            enough with ``against``).
        against: another revision of the env (``user/name@<sha>``, or a local folder; another env with the same
            spaces works too): each policy also runs its episodes there, and the report pairs them seed by seed
            (``against`` minus ``repo_id``, e.g. new minus old): how the revision changed what the policy gets.
        episodes: episodes per policy (and per env); episode ``i`` resets with seed ``seed + i``.
        seed: the first episode's seed, and the bootstrap's.
        revision: the revision of ``repo_id`` (overrides its ``@rev``).
        trust_remote_code: consent to run the env's code (or ``hub-envs trust`` its commit).
        trust_policy_code: consent to load the Hub checkpoints (they can run code; or ``hub-envs trust`` each).
        workers: processes (local; default up to 2) or Ray actors.
        resamples: the bootstrap's resamples.
        confidence: the bootstrap's confidence level.
        out: the reports' folder (default ``compare-out/<user>/<name>/``); ``write=False``: no files.
        progress: progress bars.
        token: the Hub token.
        run: how the env's code runs (``isolation``, ``sandbox``, ``versions``, ``step_timeout``; see
            :func:`hub_envs.load_env`).
        backend: where the episodes run (:func:`hub_envs.make_backend`: ``"local"`` processes, or
            ``"ray"``, where each worker builds the policies from their specs once; a local checkpoint folder
            must then exist at the same path on every node).
        ray_address: the Ray cluster with ``backend="ray"`` (default ``$RAY_ADDRESS``, else a local Ray for the run).
        task: a benchmark suite: the task(s) to compare on, comma-separated (default: every task; ``against`` must
            have them too). Each task is compared on its own (``report.tasks``, the paired statistics per task) and
            the suite pooled (``report.policies`` / ``differences``).

    Returns:
        The :class:`CompareReport` (written as ``report.json``, ``report.md`` and ``report.png`` unless ``write=False``).

    Raises:
        ConfigError: fewer than two policies (one with ``against``), fewer than 2 episodes, a confidence outside
            (0, 1), a misspelt ``run`` keyword, or a policy that is neither ``random``, a folder nor a repo id.
        ReproductionError: a policy that cannot be run.
        hub_envs.errors.HubEnvsError: an env or a policy cannot be loaded.
    """
    if len(policies) < (1 if against else 2):
        raise ConfigError(
            f"--policies needs at least two policies, comma-separated (got {policies!r}); e.g. random,PATH. "
            f"(One is enough with --against=user/name@<other sha>, to compare two revisions.)"
        )
    run = code_run(run, "compare")  # before anything starts: a misspelt keyword is named at once
    if episodes < 2:
        raise ConfigError(f"--episodes={episodes}: a confidence interval needs at least 2 episodes (20 or more is sensible).")
    if not 0 < confidence < 1:
        raise ConfigError(f"confidence={confidence}: pass a level between 0 and 1, e.g. 0.95.")
    workers = int(workers) if workers else max(1, min(2, os.cpu_count() or 1))
    runner = make_backend(backend, workers=workers, ray_address=ray_address)
    t0 = time.perf_counter()
    specs = [policy_spec(p, token=token) for p in policies]
    labels = _labels([os.fspath(p).strip() for p in policies])
    with contextlib.ExitStack() as stack:
        envs = [
            stack.enter_context(  # the feature check on, no fingerprint run: the compared episodes run the env anyway
                load_env(ref, revision=rev, trust_remote_code=trust_remote_code, fingerprint="off", token=token, **run)
            )
            for ref, rev in ([(repo_id, revision), (against, None)] if against else [(repo_id, revision)])
        ]
        loaded = envs[0]
        timings = {"load": time.perf_counter() - t0}
        seeds = [seed + i for i in range(episodes)]
        kw = dict(
            resamples=resamples,
            confidence=confidence,
            bootstrap_seed=seed,
            token=token,
            trust_policy_code=trust_policy_code,
            progress=progress,
            backend=runner,
        )
        arm_labels = _labels([f"{label} on {_env_label(env, loaded)}" if against else label for env in envs for label in labels])
        tasks = _compared_tasks(envs, task)
        per_task: list[TaskComparison] = []
        with runner:
            for name in tasks or [None]:  # a suite: each task in its own env (for_task), on the same seeds
                arms = iter(arm_labels)
                results: list[list[PolicyResult]] = []  # per env, per policy
                for env in envs:
                    results.append([])
                    for spec in specs:
                        arm = next(arms)
                        t = time.perf_counter()
                        on = env if name is None else env.for_task(name)
                        results[-1].append(_run_policy(on, arm, spec, seeds, **kw))
                        timings[f"policy {arm}" + (f" task {name}" if name else "")] = time.perf_counter() - t
                if name is not None:
                    per_task.append(
                        TaskComparison(name, [r for e in results for r in e], _differences(results, resamples, confidence, seed))
                    )
        if per_task:  # the suite: every task's episodes of an arm pooled, in task order (so pairs match by task and seed)
            n = len(per_task[0].policies)
            pooled = [_pooled([t.policies[i] for t in per_task], resamples, confidence, seed) for i in range(n)]
            results = [pooled[i : i + len(specs)] for i in range(0, n, len(specs))]
        diffs = _differences(results, resamples, confidence, seed)
        provenance = {**run_provenance(loaded), "episode_length": int(loaded.config.episode_length), "seeds": seeds}
        if against:
            other = run_provenance(envs[1])
            provenance["against"] = {
                **{k: other[k] for k in ("repo_id", "requested_revision", "sha", "content_digest", "versions_here")},
                "episode_length": int(envs[1].config.episode_length),
            }
        report = CompareReport(
            policies=[r for per_env in results for r in per_env],
            differences=diffs,
            provenance=provenance,
            settings={
                "episodes": episodes,
                "seed": seed,
                "resamples": resamples,
                "confidence": confidence,
                "workers": workers,
                "backend": runner.settings(),
                "isolation": loaded.runs_as,
                "half_width": HALF_WIDTH,
                **({"tasks": tasks} if tasks else {}),
            },
            tasks=per_task,
        )
        # in the files: load and each policy
        report.finish(timings, t0, out=out, default=default_out_dir(DEFAULT_OUT, loaded.repo_id), write=write)
        return report
