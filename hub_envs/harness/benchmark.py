"""Re-run a repo's declared benchmark results and compare each metric with what was published.

One concept: a *benchmark* in the manifest (``hub_env.json`` ``benchmarks``) declares a policy, the
reset seeds of its episodes, per-episode results and metrics, and a tolerance per metric::

    {"name": "random-policy",
     "policy": {"type": "random"},                                 # or {"type": "lerobot", "checkpoint": "user/policy@<sha>"}
     "episodes": 10, "seeds": [0, 1, ...],
     "metrics": {"mean_return": -1234.5, "success_rate": 0.1},
     "per_episode": {"return": [...], "success": [...]},
     "tolerance": {"mean_return": 1e-6, "success_rate": 0.0}}

:func:`reproduce_benchmark` runs the same episodes again (the rollout engine: same seeds, same
``max_steps``, any number of worker processes, identical results) and reports, per metric, the
published value, the reproduced value, a seeded bootstrap confidence interval of the reproduced
value over episodes, and pass/fail: ``|reproduced - published| <= tolerance`` (a metric without a
declared tolerance passes when the published value lies inside the interval).

Policies:

* ``random``: ``env.action_space.sample()`` with the action space seeded by each episode's reset
  seed (what push_env ran and recorded as the repo's first benchmark);
* ``lerobot`` (alias ``checkpoint``): a LeRobot pretrained policy, ``"checkpoint": "user/policy@<40-hex sha>"``
  (pinned; a branch is refused), loaded with ``PreTrainedPolicy.from_pretrained`` and its saved
  pre/post-processors. Observations are renamed with the env config's ``features_map``; the
  policy is reset and torch is seeded (0) at the start of every episode, so results do not depend
  on which worker ran which episode.

Example:
    >>> from hub_envs.harness.benchmark import bootstrap_ci
    >>> bootstrap_ci([1.0, 2.0, 3.0, 4.0], resamples=1000, seed=0)
    (1.5, 3.5)
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hub_envs._text import safe_text
from hub_envs.errors import ReproductionError, UntrustedCodeError

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
    """Percentile bootstrap confidence interval of the mean (or ``statistic`` over axis 1), seeded."""
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
        if self.error:
            return f"benchmark {self.name}: not reproduced: {self.error}"
        parts = [
            f"{m.name} {m.published:.6g} -> {m.reproduced:.6g} [{m.ci_low:.6g}, {m.ci_high:.6g}] {'PASS' if m.passed else 'FAIL'}"
            for m in self.metrics
        ]
        return f"benchmark {self.name} ({self.policy.get('type')} policy, {len(self.seeds)} episodes): " + "; ".join(parts)

    def to_dict(self) -> dict[str, Any]:
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


# --- policies ---------------------------------------------------------------------------------


def _processor_classes(path: str) -> list[str]:
    """The ``"class"`` entries of a checkpoint's ``policy_*processor.json``: what LeRobot's factory would import."""
    import glob
    import json

    out = []
    for file in sorted(glob.glob(os.path.join(path, "*processor*.json"))):
        try:
            steps = json.loads(Path(file).read_text(encoding="utf-8")).get("steps", [])
        except (OSError, ValueError, AttributeError, RecursionError):
            continue
        out += [str(s["class"]) for s in steps if isinstance(s, dict) and isinstance(s.get("class"), str)]
    return out


def _check_policy_consent(
    repo_id: str, revision: str, path: str, trusted: Any, trust_policy_code: bool, digest: str, bound_to: str | None = None
) -> None:
    """A policy checkpoint is a second repo whose loading runs code (LeRobot's processor factory imports the
    classes its JSON names): the same gate as the env's, with its own consent. ``digest``: the downloaded files'
    (:func:`~hub_envs.repo.trust_list.snapshot_digest`); ``bound_to``: the digest consent was given for elsewhere (a Ray
    worker gets the driver's), other files are refused whatever ``trust_policy_code`` says."""
    if bound_to is not None and digest != bound_to:
        raise UntrustedCodeError(
            f"policy {repo_id}@{revision} holds files of content {digest[:16]}…, not the content {bound_to[:16]}… its consent "
            f"was given for; nothing of it was loaded. The endpoint (or the network path to it) serves other files under "
            f"this commit id than the ones that were consented to: do not run it."
        )
    if trust_policy_code or trusted.covers(repo_id, revision, digest):
        return
    classes = _processor_classes(path)
    raise UntrustedCodeError(
        f"benchmark policy {repo_id}@{revision} is another repo than the env, and loading it can run code"
        + (f" (LeRobot's processor factory would import {', '.join(safe_text(c) for c in classes)})" if classes else "")
        + f"; nothing of it was loaded. Consent to the env does not cover it. Read it in {path}, then pass "
        f"trust_policy_code=True (hub-envs reproduce --trust_policy_code=true) or trust this exact commit once:\n"
        f"  hub-envs trust {repo_id}@{revision}"
    )


def _checkpoint_policy(
    spec: dict[str, Any], loaded: Any, *, token: str | None = None, trust_policy_code: bool = False
) -> Callable[[Any, int], np.ndarray]:
    """A LeRobot pretrained policy at a pinned commit (``"checkpoint": "user/policy@<sha>"``), or in a local
    ``pretrained_model`` folder (``"path": ...``: the caller's own files, loaded without a consent check), as
    the rollout engine's ``(obs, t) -> action``."""
    from hub_envs.repo import hub_io
    from hub_envs.repo.format import is_commit_sha

    local = spec.get("path")
    ref = spec.get("checkpoint") or spec.get("repo_id")
    if isinstance(local, str):
        ref = local
        if not (Path(local) / "config.json").is_file():
            raise ReproductionError(
                f"policy folder {local}: no config.json in it. Pass a LeRobot `pretrained_model` folder "
                "(e.g. outputs/train/checkpoints/last/pretrained_model) or a Hub repo id."
            )
    elif not isinstance(ref, str):
        raise ReproductionError(f'benchmark policy {spec!r}: a checkpoint policy needs "checkpoint": "user/policy@<sha>".')
    else:
        repo_id, revision = hub_io.parse_repo_ref(ref)
        revision = spec.get("revision") or revision
        if not is_commit_sha(revision):
            raise ReproductionError(
                f"benchmark policy {ref!r} is not pinned to a commit: a benchmark result is only reproducible against the "
                f'exact weights. Declare it as "{repo_id}@<40-hex sha>".'
            )
    try:
        import torch
        from huggingface_hub import snapshot_download
        from lerobot.configs.policies import PreTrainedConfig
        from lerobot.policies.factory import get_policy_class, make_pre_post_processors
    except ImportError as exc:  # pragma: no cover - lerobot is a dependency
        raise ReproductionError(f"benchmark policy {ref!r} needs lerobot and torch: {exc}") from exc
    from hub_envs.repo.trust_list import read_trust_list, snapshot_digest

    digest = None
    if isinstance(local, str):
        path, repo_id, revision = str(local), str(local), "local"
    else:
        trusted = read_trust_list()  # before the download, as load_env does
        with hub_io.translate_hub_errors(repo_id, revision):
            path = snapshot_download(repo_id, revision=revision, token=token)
        digest = snapshot_digest(Path(path))
        _check_policy_consent(repo_id, revision, path, trusted, trust_policy_code, digest, spec.get("content_digest"))
    torch.set_num_threads(1)  # see act(): identical results in every worker, no OpenMP pool across fork
    try:
        cfg = PreTrainedConfig.from_pretrained(path)
        cfg.device = "cpu"
        policy = get_policy_class(cfg.type).from_pretrained(path, config=cfg)
        policy.eval()
        if os.path.isfile(os.path.join(path, "policy_preprocessor.json")):
            pre, post = make_pre_post_processors(
                cfg, pretrained_path=path, preprocessor_overrides={"device_processor": {"device": "cpu"}}
            )
        else:
            pre, post = make_pre_post_processors(cfg)
    except Exception as exc:
        raise ReproductionError(
            f"benchmark policy {repo_id}@{revision}: cannot load it as a LeRobot policy: {type(exc).__name__}: {exc}"
        ) from exc

    task = str(getattr(loaded.config, "task", "") or "")

    def act(obs: Any, t: int) -> np.ndarray:
        if t == 0:
            # one thread: the same arithmetic in every process (and no OpenMP pool inherited across fork)
            torch.set_num_threads(1)
            policy.reset()
            torch.manual_seed(0)
        batch = policy_observation(obs, task)
        with torch.inference_mode():
            action = post(policy.select_action(pre(batch)))
        return action.detach().cpu().numpy()[0]

    act.content_digest = digest  # what a remote worker's copy must hold (remote_policy_spec)
    return act


def remote_policy_spec(spec: dict[str, Any], built: Any) -> dict[str, Any]:
    """The spec a remote (Ray) worker builds its own copy of the policy ``built`` (built here from ``spec``) from: bound
    to the checkpoint content consent was given for here, so a worker whose Hub serves other files refuses them."""
    digest = getattr(built, "content_digest", None)
    return {**spec, "content_digest": digest} if digest is not None else dict(spec)


def policy_observation(env_observation: dict, task: str | None = "") -> dict:
    """What LeRobot's eval loop gives the policy for one (unbatched) env observation: LeRobot's own
    ``preprocess_observation`` (images HWC uint8 -> CHW float in [0, 1], states float32, a batch axis) and
    the task, the one conversion hub-envs uses (benchmarks here, env processors' dry run)."""
    from lerobot.envs.utils import preprocess_observation

    batched = {k: (np.asarray(v)[None] if not isinstance(v, dict) else v) for k, v in env_observation.items()}
    obs = preprocess_observation(batched)
    obs["task"] = [task or ""]
    return obs


def _policy_for(spec: dict[str, Any], loaded: Any, token: str | None, trust_policy_code: bool = False) -> Any:
    kind = str(spec.get("type", "")).lower()
    if kind == "random":
        return None
    if kind in ("lerobot", "checkpoint", "pretrained"):
        return _checkpoint_policy(spec, loaded, token=token, trust_policy_code=trust_policy_code)
    raise ReproductionError(
        f'benchmark policy type {spec.get("type")!r} is not supported; hub-envs reproduces "random" and '
        f'"lerobot" (a LeRobot pretrained policy pinned as "checkpoint": "user/policy@<sha>").'
    )


def _torch_threads() -> int | None:
    import sys

    torch = sys.modules.get("torch")  # only if imported already: a random policy never imports torch
    return torch.get_num_threads() if torch is not None else None


def _restore_torch_threads(n: int | None) -> None:
    import sys

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
                self.policy = _policy_for(policy_spec, loaded, token, trust_policy_code)
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
        for m in self.metrics:
            key, get = METRICS[m]
            self.per_episode[key].append(get(rollout))

    def run(self, loaded: Any, *, workers: int = 1, progress: bool = True, backend: Any = None) -> BenchmarkResult:
        """Run this benchmark's episodes of ``loaded``'s env in a pass of its own, and :meth:`finish`.

        ``backend`` (:mod:`hub_envs.backends`): where the episodes run (default: ``workers`` local processes)."""
        from hub_envs.backends import LocalBackend

        backend = backend if backend is not None else LocalBackend(workers=workers)
        t = time.perf_counter()
        try:
            if self.runnable:
                policy = self.policy
                if policy is not None and backend.name != "local" and isinstance(self.benchmark.get("policy"), dict):
                    policy = remote_policy_spec(self.benchmark["policy"], policy)  # a remote worker builds its own, once
                for rollout in backend.episodes(
                    loaded,
                    self.seeds,
                    max_steps=self.max_steps,
                    policy=policy,
                    progress=progress,
                    desc=f"Benchmark {self.name}",
                ):
                    self.consume(rollout)
        finally:
            seconds = time.perf_counter() - t
        return self.finish(episodes_seconds=seconds)

    def finish(self, *, episodes_seconds: float = 0.0) -> BenchmarkResult:
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
    """Re-run one declared benchmark of ``loaded`` (a :class:`hub_envs.loading.loaded.LoadedEnv`) and compare its metrics.

    An unsupported policy or metric gives a result with ``error`` set (and ``passed`` False) rather
    than raising, so the other parts of a reproduction still report.
    """
    run = BenchmarkRun(
        loaded, benchmark, resamples=resamples, confidence=confidence, seed=seed, token=token, trust_policy_code=trust_policy_code
    )
    return run.run(loaded, workers=workers, progress=progress)
