"""``evaluate``: a policy over N seeded episodes of an env commit, on this machine or on a Ray cluster (the metrics do
not depend on where the episodes ran).

Example:
    >>> from hub_envs import evaluate                                                  # doctest: +SKIP
    >>> evaluate("user/hover@<sha>", episodes=100, backend="ray").mean_return          # doctest: +SKIP
    -12.3
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Unpack

import numpy as np

from hub_envs.backends import Backend, make_backend
from hub_envs.errors import ConfigError
from hub_envs.harness.policy import policy_for, remote_policy_spec
from hub_envs.harness.provenance import versions_run_with
from hub_envs.loading.isolated import CodeRun, code_run
from hub_envs.loading.load import load_env

__all__ = ["EvalResult", "evaluate"]


@dataclass(frozen=True)
class EvalResult:
    """What an evaluation measured (and everything it depended on). A suite's evaluation of several tasks holds each
    task's own result in ``per_task`` and, here, every episode of them pooled (LeRobot's ``overall``)."""

    repo_id: str
    sha: str
    policy: str
    seeds: tuple[int, ...]
    max_steps: int
    returns: tuple[float, ...]
    successes: tuple[bool, ...]
    lengths: tuple[int, ...]
    versions: dict[str, str]
    backend: dict[str, Any]
    isolation: str = "none"  # how the env's code ran: none, process, venv (+sandbox)
    task: str | None = None  # the suite task evaluated (None: a one-task env, or several tasks: per_task)
    per_task: tuple[EvalResult, ...] = field(default=())  # a suite: each task's result, in task-id order

    @property
    def metrics(self) -> dict[str, float]:
        """``mean_return``, ``success_rate`` and ``mean_length`` over the episodes."""
        return {
            "mean_return": float(np.mean(self.returns)),
            "success_rate": float(np.mean(self.successes)),
            "mean_length": float(np.mean(self.lengths)),
        }

    @property
    def mean_return(self) -> float:
        return self.metrics["mean_return"]

    def to_dict(self) -> dict[str, Any]:
        """The result as JSON-ready data (``eval.json``), its metrics included."""
        d = asdict(self)
        d["metrics"] = self.metrics
        d["per_task"] = [r.to_dict() for r in self.per_task]  # each task's metrics too
        return d

    def summary(self) -> str:
        """One line: the env commit (and task), the policy, the seeds and the metrics; a line more per task of a suite."""
        m = self.metrics
        what = f" task {self.task!r}" if self.task else f" ({len(self.per_task)} tasks)" if self.per_task else ""
        line = (
            f"{self.repo_id}@{self.sha}{what}: {len(self.returns)} episodes of policy {self.policy} "
            f"(seeds {self.seeds[0]}..{self.seeds[-1]}{' per task' if self.per_task else ''}): mean return "
            f"{m['mean_return']:.6g}, success rate {m['success_rate']:.3g}, mean length {m['mean_length']:.4g}"
        )
        for r in self.per_task:
            t = r.metrics
            line += (
                f"\n  task {r.task!r}: mean return {t['mean_return']:.6g}, success rate {t['success_rate']:.3g}, "
                f"mean length {t['mean_length']:.4g}"
            )
        return line


def _policy(policy: Any, loaded: Any, backend: Backend, token: str | None, trust_policy_code: bool) -> tuple[Any, str]:
    """(what the backend runs, a name for the result)."""
    if policy is None or policy == "random":
        return None, "random"
    if callable(policy):
        return policy, getattr(policy, "__qualname__", type(policy).__name__)
    if isinstance(policy, str):
        spec = {"type": "lerobot", "checkpoint": policy}
        built = policy_for(spec, loaded, token, trust_policy_code)  # consent and loading errors surface here
        # on a local backend the built policy runs here; a remote worker builds its own from the spec, once
        return (built if backend.name == "local" else remote_policy_spec(spec, built)), policy
    raise ConfigError(
        f"policy={policy!r}: pass None or 'random', a LeRobot checkpoint 'user/policy@<sha>', or a callable (obs, t) -> action."
    )


def load_for_evaluation(
    repo_id: str, revision: str | None, *, trust_remote_code: bool, token: str | None, run: dict[str, Any], where: str
) -> Any:
    """How an evaluation loads the env: :func:`hub_envs.load_env` with the feature check on and no fingerprint run (the
    evaluated episodes run the env anyway). Use it in a ``with`` block: the env is unregistered at the end.

    Args:
        repo_id: the env (``user/name@<sha>`` or a folder).
        revision: its revision (overrides ``@rev``).
        trust_remote_code: consent to run its code.
        token: the Hub token.
        run: :class:`~hub_envs.loading.isolated.CodeRun` keywords.
        where: the operation's name, for messages.

    Returns:
        The :class:`~hub_envs.loading.loaded.LoadedEnv`.

    Raises:
        hub_envs.errors.HubEnvsError: as :func:`hub_envs.load_env`.
    """
    return load_env(
        repo_id,
        revision=revision,
        trust_remote_code=trust_remote_code,
        fingerprint="off",
        token=token,
        **code_run(run, where),
    )


def evaluate(
    repo_id: str,
    *,
    policy: Any = None,
    episodes: int = 10,
    seed: int = 0,
    max_steps: int | None = None,
    revision: str | None = None,
    trust_remote_code: bool = False,
    trust_policy_code: bool = False,
    token: str | None = None,
    backend: str | Backend = "local",
    workers: int | None = None,
    ray_address: str | None = None,
    out: str | Path | None = None,
    progress: bool = True,
    task: str | None = None,
    **run: Unpack[CodeRun],
) -> EvalResult:
    """Run ``policy`` for ``episodes`` seeded episodes of ``repo_id`` and return the metrics.

    Args:
        repo_id: ``user/name`` (``@rev`` allowed) or a local env folder. Pin a sha for a reproducible result.
        policy: see the module docstring.
        episodes: how many episodes; episode ``i`` resets with seed ``seed + i``.
        seed: the first episode's reset seed.
        max_steps: at most this many steps per episode (default: the env config's ``episode_length``).
        backend: ``"local"`` (``workers`` processes) or ``"ray"`` (``ray_address``, default ``$RAY_ADDRESS``, else
            a local Ray for the run); the result does not depend on it.
        out: Ray: keep finished shards here (the same evaluation started again skips them), and write
            ``eval.json``; local: write ``eval.json`` only.
        task: a benchmark suite's task to evaluate, or several comma-separated (default: all its tasks, each over the same
            seeds, as ``lerobot-eval`` runs a suite: ``per_task``, and the episodes pooled). A one-task env takes none.
        run: how the env's code runs (``isolation``, ``sandbox``, ``versions``, ``step_timeout``; see
            :func:`hub_envs.load_env`): isolated, the policy runs in this process, the env in worker processes.

    Returns:
        The :class:`EvalResult`: per-episode returns, successes and lengths, their means, and what they depended on.

    Raises:
        ConfigError: ``episodes`` or ``seed`` not a count, a misspelt ``run`` keyword, a policy that is none of the
            above, or a ``task`` that is not one of the suite's (or given for a one-task env).
        hub_envs.errors.HubEnvsError: the env or the policy cannot be loaded, or a backend is unavailable.
    """
    run = code_run(run, "evaluate")  # before anything starts: a misspelt keyword is named at once
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise ConfigError(f"episodes={episodes!r}: pass a positive number of episodes.")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ConfigError(f"seed={seed!r}: pass a non-negative integer (episode i resets with seed + i).")
    runner = make_backend(
        backend,
        workers=workers,
        ray_address=ray_address,
        checkpoint_dir=Path(out) / "shards" if out is not None and backend == "ray" else None,
    )
    with load_for_evaluation(
        repo_id, revision, trust_remote_code=trust_remote_code, token=token, run=run, where="evaluate"
    ) as loaded:
        targets = _task_handles(loaded, task)
        run_policy, name = _policy(policy, targets[0], runner, token, trust_policy_code)
        steps = int(max_steps) if max_steps is not None else int(loaded.config.episode_length)
        seeds = [seed + i for i in range(episodes)]
        results = []
        with runner:
            for target in targets:
                returns, successes, lengths = [], [], []
                of = f" on task {target.task!r}" if target.task is not None else ""
                for rollout in runner.episodes(
                    target, seeds, max_steps=steps, policy=run_policy, progress=progress, desc=f"Evaluating {name}{of}"
                ):
                    returns.append(rollout.episode_return)
                    successes.append(rollout.success)
                    lengths.append(rollout.length)
                results.append(
                    EvalResult(
                        repo_id=loaded.repo_id,
                        sha=loaded.revision,
                        policy=name,
                        seeds=tuple(seeds),
                        max_steps=steps,
                        returns=tuple(returns),
                        successes=tuple(successes),
                        lengths=tuple(lengths),
                        versions=versions_run_with(loaded),
                        backend=runner.settings(),
                        isolation=loaded.runs_as,
                        task=target.task,
                    )
                )
        result = results[0] if len(results) == 1 else _pooled(results)
    if out is not None:
        Path(out).mkdir(parents=True, exist_ok=True)
        (Path(out) / "eval.json").write_text(json.dumps(result.to_dict(), indent=2) + "\n", encoding="utf-8")
    return result


def _task_handles(loaded: Any, task: str | None) -> list[Any]:
    """What an evaluation runs: the env (a one-task env), or the suite tasks ``task`` names (comma-separated; default
    all), each :meth:`~hub_envs.loading.loaded.LoadedEnv.for_task`."""
    if not loaded.is_suite:
        if task is not None:
            raise ConfigError(
                f"task={task!r}: {loaded.repo_id}@{loaded.revision} is a one-task env (no [tool.hub-envs] tasks); leave task out."
            )
        return [loaded]
    names = loaded.tasks if task is None else [t.strip() for t in str(task).split(",") if t.strip()]
    return [loaded.for_task(t) for t in names]  # ConfigError naming the suite's tasks


def _pooled(results: list[EvalResult]) -> EvalResult:
    """Several tasks' results as one: every episode pooled (LeRobot's ``overall``), each task's own in ``per_task``."""
    first = results[0]
    return EvalResult(
        repo_id=first.repo_id,
        sha=first.sha,
        policy=first.policy,
        seeds=first.seeds,
        max_steps=first.max_steps,
        returns=tuple(x for r in results for x in r.returns),
        successes=tuple(x for r in results for x in r.successes),
        lengths=tuple(x for r in results for x in r.lengths),
        versions=first.versions,
        backend=first.backend,
        isolation=first.isolation,
        per_task=tuple(results),
    )
