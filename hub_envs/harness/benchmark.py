"""Re-run a repo's declared benchmarks (``hub_env.json`` ``benchmarks``: a policy, its episodes' reset seeds, the
published per-episode results and metrics, a tolerance per metric) and compare each metric with what was published.

Example:
    >>> from hub_envs.harness.benchmark import bootstrap_ci
    >>> bootstrap_ci([1.0, 2.0, 3.0, 4.0], resamples=1000, seed=0)
    (1.5, 3.5)
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from hub_envs.errors import ReproductionError, UntrustedCodeError
from hub_envs.harness.policy import policy_for, remote_policy_spec
from hub_envs.harness.rollout import iter_episodes

__all__ = ["MetricResult", "BenchmarkResult", "BenchmarkRun", "bootstrap_ci", "reproduce_benchmark", "METRICS"]

#: metric name -> (per-episode key in ``per_episode``, how to get it from a rollout)
METRICS: dict[str, tuple[str, Callable[[Any], float]]] = {
    "mean_return": ("return", lambda r: r.episode_return),
    "success_rate": ("success", lambda r: float(r.success)),
}


def bootstrap_ci(
    values: Sequence[float],
    *,
    resamples: int = 1000,
    confidence: float = 0.95,
    seed: int = 0,
    statistic: Callable[[np.ndarray], np.ndarray] | None = None,
) -> tuple[float, float]:
    """Percentile bootstrap confidence interval of the mean (or of ``statistic``), seeded.

    Args:
        values: the per-episode values.
        resamples: bootstrap resamples.
        confidence: the interval's level.
        seed: the resampling's seed (the same values give the same interval).
        statistic: computed over axis 1 of the ``(resamples, n)`` samples (default: the mean).

    Returns:
        ``(low, high)``; NaNs for no values.
    """
    x = np.asarray(values, dtype=np.float64)
    if x.size == 0:
        return (float("nan"), float("nan"))
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, x.size, size=(int(resamples), x.size))
    samples = x[idx]
    stats = statistic(samples) if statistic is not None else samples.mean(axis=1)
    alpha = (1.0 - confidence) / 2.0
    lo, hi = np.quantile(stats, [alpha, 1.0 - alpha])
    return (float(lo), float(hi))


@dataclass
class MetricResult:
    name: str
    published: float
    reproduced: float
    ci_low: float
    ci_high: float
    tolerance: float | None
    passed: bool

    @property
    def difference(self) -> float:
        return self.reproduced - self.published

    def to_dict(self) -> dict[str, Any]:
        """The metric as JSON-ready data, its difference included."""
        d = asdict(self)
        d["difference"] = self.difference
        return d


@dataclass
class BenchmarkResult:
    name: str
    policy: dict[str, Any]
    seeds: list[int]
    metrics: list[MetricResult] = field(default_factory=list)
    published_per_episode: dict[str, list] = field(default_factory=dict)
    reproduced_per_episode: dict[str, list] = field(default_factory=dict)
    confidence: float = 0.95
    resamples: int = 1000
    seconds: float = 0.0
    error: str | None = None  # set when the benchmark could not be run (e.g. an unsupported policy)

    @property
    def passed(self) -> bool:
        return self.error is None and all(m.passed for m in self.metrics)

    @property
    def episodes_differing(self) -> list[int]:
        """Episodes whose published and reproduced per-episode values differ (any metric)."""
        out = set()
        for key, pub in self.published_per_episode.items():
            rep = self.reproduced_per_episode.get(key, [])
            out |= {i for i, (a, b) in enumerate(zip(pub, rep)) if a != b}
        return sorted(out)

    def summary(self) -> str:
        """One line: each metric published -> reproduced, its interval and PASS/FAIL (or why it was not reproduced)."""
        if self.error:
            return f"benchmark {self.name}: not reproduced: {self.error}"
        parts = [
            f"{m.name} {m.published:.6g} -> {m.reproduced:.6g} [{m.ci_low:.6g}, {m.ci_high:.6g}] {'PASS' if m.passed else 'FAIL'}"
            for m in self.metrics
        ]
        return f"benchmark {self.name} ({self.policy.get('type')} policy, {len(self.seeds)} episodes): " + "; ".join(parts)

    def to_dict(self) -> dict[str, Any]:
        """The result as JSON-ready data (``report.json``)."""
        return {
            "name": self.name,
            "policy": self.policy,
            "seeds": self.seeds,
            "passed": self.passed,
            "error": self.error,
            "confidence": self.confidence,
            "resamples": self.resamples,
            "seconds": self.seconds,
            "metrics": [m.to_dict() for m in self.metrics],
            "episodes_differing": self.episodes_differing,
            "published_per_episode": self.published_per_episode,
            "reproduced_per_episode": self.reproduced_per_episode,
        }


def _torch_threads() -> int | None:
    torch = sys.modules.get("torch")  # only if imported already: a random policy never imports torch
    return torch.get_num_threads() if torch is not None else None


def _restore_torch_threads(n: int | None) -> None:
    torch = sys.modules.get("torch")
    if n is not None and torch is not None and torch.get_num_threads() != n:
        torch.set_num_threads(n)


# --- reproduction -----------------------------------------------------------------------------


class BenchmarkRun:
    """One benchmark reproduction, in three steps, so its episodes can share a worker pool.

    ``BenchmarkRun(loaded, benchmark)`` checks the declaration and builds the policy; when
    :attr:`runnable`, :attr:`seeds`, :attr:`policy` (``None``: the seeded random policy) and
    :attr:`max_steps` are what to run through the rollout engine; :meth:`consume` takes the rollouts
    in order and :meth:`finish` computes the metrics. :func:`reproduce_benchmark` does all three.
    """

    def __init__(
        self,
        loaded: Any,
        benchmark: dict[str, Any],
        *,
        resamples: int = 1000,
        confidence: float = 0.95,
        seed: int = 0,
        token: str | None = None,
        trust_policy_code: bool = False,
    ):
        t0 = time.perf_counter()
        self.benchmark = benchmark
        self.name = str(benchmark.get("name", "benchmark"))
        policy_spec = dict(benchmark.get("policy") or {})
        self.seeds = [int(s) for s in benchmark.get("seeds", [])]
        self.result = BenchmarkResult(
            name=self.name, policy=policy_spec, seeds=self.seeds, confidence=confidence, resamples=resamples
        )
        self.bootstrap_seed = seed
        self.metrics = dict(benchmark.get("metrics") or {})
        self.max_steps = int(benchmark.get("max_steps") or loaded.config.episode_length)
        self.policy: Any = None
        self.per_episode: dict[str, list[float]] = {METRICS[m][0]: [] for m in self.metrics if m in METRICS}
        self._threads = _torch_threads()
        unknown = sorted(set(self.metrics) - set(METRICS))
        if not self.seeds:
            self.result.error = "the benchmark declares no seeds"
        elif unknown:
            self.result.error = f"metric(s) {unknown} cannot be recomputed (hub-envs knows {sorted(METRICS)})"
        else:
            try:
                self.policy = policy_for(policy_spec, loaded, token, trust_policy_code)
            except (ReproductionError, UntrustedCodeError) as exc:
                self.result.error = str(exc)
        self._seconds = time.perf_counter() - t0

    @property
    def runnable(self) -> bool:
        return self.result.error is None

    @property
    def random_policy(self) -> bool:
        """True when the episodes use the engine's seeded random actions (``policy`` is None)."""
        return self.runnable and self.policy is None

    def consume(self, rollout: Any) -> None:
        """Take one rollout of this benchmark's episodes, in order.

        Args:
            rollout: an :class:`~hub_envs.harness.rollout.EpisodeRollout`.
        """
        for m in self.metrics:
            key, get = METRICS[m]
            self.per_episode[key].append(get(rollout))

    def run(self, loaded: Any, *, workers: int = 1, progress: bool = True, backend: Any = None) -> BenchmarkResult:
        """Run this benchmark's episodes of ``loaded``'s env in a pass of its own, and :meth:`finish`.

        Args:
            loaded: the env (a :class:`~hub_envs.loading.loaded.LoadedEnv`).
            workers: local processes, when no ``backend`` is given.
            progress: show a progress bar.
            backend: where the episodes run (a :class:`hub_envs.backends.Backend`); None: ``workers`` processes of
                this machine (the rollout engine's pool).

        Returns:
            The :class:`BenchmarkResult`.
        """
        t = time.perf_counter()
        try:
            if self.runnable:
                policy = self.policy
                desc = f"Benchmark {self.name}"
                if backend is None:
                    rollouts = iter_episodes(
                        loaded.make,
                        self.seeds,
                        max_steps=self.max_steps,
                        policy=policy,
                        workers=workers,
                        progress=progress,
                        desc=desc,
                    )
                else:
                    if policy is not None and backend.name != "local" and isinstance(self.benchmark.get("policy"), dict):
                        policy = remote_policy_spec(self.benchmark["policy"], policy)  # a remote worker builds its own, once
                    rollouts = backend.episodes(
                        loaded, self.seeds, max_steps=self.max_steps, policy=policy, progress=progress, desc=desc
                    )
                for rollout in rollouts:
                    self.consume(rollout)
        finally:
            seconds = time.perf_counter() - t
        return self.finish(episodes_seconds=seconds)

    def finish(self, *, episodes_seconds: float = 0.0) -> BenchmarkResult:
        """Compute the metrics of the rollouts consumed.

        Args:
            episodes_seconds: the time the episodes took (when they ran in a shared pass).

        Returns:
            The :class:`BenchmarkResult`.
        """
        _restore_torch_threads(self._threads)
        result = self.result
        if result.error is not None:
            result.seconds = self._seconds
            return result
        published = dict(self.benchmark.get("per_episode") or {})
        tolerance = dict(self.benchmark.get("tolerance") or {})
        for m, value in self.metrics.items():
            key = METRICS[m][0]
            values = np.asarray(self.per_episode[key], dtype=np.float64)
            reproduced = float(np.mean(values))
            lo, hi = bootstrap_ci(values, resamples=result.resamples, confidence=result.confidence, seed=self.bootstrap_seed)
            tol = tolerance.get(m)
            if tol is None:
                passed = lo <= float(value) <= hi
            else:
                passed = abs(reproduced - float(value)) <= float(tol)
            result.metrics.append(
                MetricResult(m, float(value), reproduced, lo, hi, None if tol is None else float(tol), bool(passed))
            )
        for key, values in self.per_episode.items():
            result.reproduced_per_episode[key] = [bool(v) for v in values] if key == "success" else [float(v) for v in values]
            if key in published:
                result.published_per_episode[key] = list(published[key])
        result.seconds = self._seconds + episodes_seconds
        return result


def reproduce_benchmark(
    loaded: Any,
    benchmark: dict[str, Any],
    *,
    workers: int = 1,
    resamples: int = 1000,
    confidence: float = 0.95,
    seed: int = 0,
    progress: bool = True,
    token: str | None = None,
    trust_policy_code: bool = False,
) -> BenchmarkResult:
    """Re-run one declared benchmark and compare its metrics with the published ones: per metric, the reproduced value,
    a seeded bootstrap confidence interval over episodes, and pass/fail (``|reproduced - published| <= tolerance``; a
    metric without a tolerance passes when the published value lies inside the interval).

    Args:
        loaded: the env (a :class:`~hub_envs.loading.loaded.LoadedEnv`).
        benchmark: the declaration (an entry of ``manifest.benchmarks``).
        workers: processes for the episodes (the result does not depend on it).
        resamples, confidence, seed: the bootstrap's.
        progress: show a progress bar.
        token: the Hub token to download a checkpoint policy with.
        trust_policy_code: consent to load a checkpoint policy (another repo than the env).

    Returns:
        The :class:`BenchmarkResult`; an unsupported policy or metric gives one with ``error`` set (and ``passed``
        False) rather than raising, so the other parts of a reproduction still report.
    """
    run = BenchmarkRun(
        loaded, benchmark, resamples=resamples, confidence=confidence, seed=seed, token=token, trust_policy_code=trust_policy_code
    )
    return run.run(loaded, workers=workers, progress=progress)
