"""``audit``: every check a plain LeRobot EnvHub repo can be put through without publishing anything (gymnasium's checker,
LeRobot's observation names, ``is_success``, the ``final_info`` autoreset ``lerobot-eval`` reads success from, seeding
and whole-episode determinism, spaces vs rollouts, requirements), as a report and a JSON file.

Example:
    >>> from hub_envs import audit                                                    # doctest: +SKIP
    >>> report = audit("user/name@<sha>", trust_remote_code=True)                     # doctest: +SKIP
    >>> report.passed                                                                 # doctest: +SKIP
"""

from __future__ import annotations

import json
import sys
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from hub_envs._text import safe_text
from hub_envs.errors import DeterminismError, EnvCheckError, HubEnvsError, PlainRepoWarning, UnpinnedRevisionWarning
from hub_envs.harness.checks import check_determinism, run_env_checker
from hub_envs.loading.load import load_env
from hub_envs.loading.loaded import LoadedEnv
from hub_envs.loading.plain import DEFAULT_EPISODE_LENGTH, fetch_plain, parse_hub_path
from hub_envs.repo.requirements import requirement_status

__all__ = ["AuditCheck", "AuditReport", "AuditTask", "audit", "infer_features"]

#: LeRobot's observation keys for an EnvHub env, and the dataset names its ``features_map`` gives them.
OBSERVATION_NAMES = {
    "agent_pos": "observation.state",
    "environment_state": "observation.environment_state",
    "pixels": "observation.image",
}


@dataclass
class AuditCheck:
    """One check: its name, whether it passed (None: not run, ``detail`` says why) and what it found."""

    name: str
    passed: bool | None
    detail: str


@dataclass
class AuditTask:
    """One task of a suite (``make_env`` returned ``{suite: {task_id: VectorEnv}}``): its checks and what they found.

    Attributes:
        task: its name (its env's ``task``, else ``<suite>/<task_id>``), what ``LoadedEnv.for_task`` takes.
        suite, task_id: where the source's ``make_env`` puts it.
        instruction: its env's ``task_description`` (else its name), what ``lerobot-eval`` gives a policy.
        checks: one :class:`AuditCheck` per check, in order.
        features, features_map, episode_length: as :class:`AuditReport`'s, for this task.
    """

    task: str
    suite: Any
    task_id: Any
    instruction: str
    checks: list[AuditCheck] = field(default_factory=list)
    features: dict[str, list] = field(default_factory=dict)
    features_map: dict[str, str] = field(default_factory=dict)
    episode_length: int | None = None

    @property
    def passed(self) -> bool:
        """Whether every check of the task ran and passed."""
        return all(c.passed for c in self.checks)

    def add(self, name: str, passed: bool | None, detail: str) -> None:
        self.checks.append(AuditCheck(name, passed, safe_text(detail)))


@dataclass
class AuditReport:
    """What :func:`audit` found.

    Attributes:
        source: ``user/name@<sha>[:path]``, the audited commit.
        checks: one :class:`AuditCheck` per check, in order.
        features: the LeRobot features inferred from the env's spaces (``{name: [FeatureType name, shape]}``).
        features_map: their LeRobot names.
        episode_length: the env's own time limit (None: it has none).
        task: the env's ``task`` / ``task_description``, if it has one.
        requirements: the requirements of its ``requirements.txt``.
        tasks: a suite's tasks, each with its own checks (:class:`AuditTask`); empty for one env. The report's own
            ``checks`` then hold what concerns the whole (requirements, contract, the same features for every task),
            and ``features`` / ``episode_length`` / ``task`` are the first task's.
        content_digest: the digest of the files the audit ran, which its consent covered (None: nothing ran); what
            ``adopt`` publishes must have it.
    """

    source: str
    checks: list[AuditCheck] = field(default_factory=list)
    features: dict[str, list] = field(default_factory=dict)
    features_map: dict[str, str] = field(default_factory=dict)
    episode_length: int | None = None
    task: str | None = None
    requirements: list[str] = field(default_factory=list)
    tasks: list[AuditTask] = field(default_factory=list)
    content_digest: str | None = None

    @property
    def passed(self) -> bool:
        """Whether every check ran and passed (a suite: every task's too)."""
        return all(c.passed for c in self.checks) and all(t.passed for t in self.tasks)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready data (what ``audit.json`` holds)."""
        return {**asdict(self), "passed": self.passed}

    def render(self) -> str:
        """The report as text, a line per check."""
        marks = {True: "PASS", False: "FAIL", None: "SKIP"}
        lines = [f"Audit of {self.source}: {'PASSED' if self.passed else 'FAILED'}"]
        lines += [f"  [{marks[c.passed]}] {c.name}: {c.detail}" for c in self.checks]
        for i, t in enumerate(self.tasks):
            lines.append(
                f"  task {i} {safe_text(t.task)!r} ({safe_text(str(t.suite))}/{safe_text(str(t.task_id))}: "
                f"{safe_text(t.instruction)!r}): {'PASSED' if t.passed else 'FAILED'}"
            )
            lines += [f"    [{marks[c.passed]}] {c.name}: {c.detail}" for c in t.checks]
        if self.features:
            lines.append("  features: " + ", ".join(f"{k} {t} {tuple(s)}" for k, (t, s) in self.features.items()))
        return "\n".join(lines)

    def add(self, name: str, passed: bool | None, detail: str) -> None:
        self.checks.append(AuditCheck(name, passed, safe_text(detail)))


def infer_features(observation_space: gym.Space, action_space: gym.Space) -> tuple[dict[str, list], dict[str, str], list[str]]:
    """LeRobot's features of an env from its spaces, by LeRobot's EnvHub observation names.

    Args:
        observation_space: a ``Dict`` of ``agent_pos`` / ``environment_state`` (1-D) and ``pixels`` (HWC uint8, or a
            ``Dict`` of cameras).
        action_space: a ``Box`` (or ``Discrete``, stored as shape ``(1,)``).

    Returns:
        ``(features, features_map, problems)``: ``{name: [FeatureType name, shape]}``, LeRobot's name for each, and
        what does not follow the conventions.
    """
    features: dict[str, list] = {}
    names: dict[str, str] = {"action": "action"}
    problems: list[str] = []
    if isinstance(action_space, gym.spaces.Box):
        features["action"] = ["ACTION", list(action_space.shape)]
    elif isinstance(action_space, gym.spaces.Discrete):
        features["action"] = ["ACTION", [1]]
    else:
        problems.append(f"action_space is a {type(action_space).__name__}; LeRobot policies act in a Box (or Discrete)")
    if not isinstance(observation_space, gym.spaces.Dict):
        problems.append(
            f"observation_space is a {type(observation_space).__name__}, not a Dict of agent_pos / environment_state / pixels"
        )
        return features, names, problems
    for key, space in observation_space.spaces.items():
        if key in ("agent_pos", "environment_state"):
            if isinstance(space, gym.spaces.Box) and len(space.shape) == 1:
                features[key] = ["STATE" if key == "agent_pos" else "ENV", list(space.shape)]
                names[key] = OBSERVATION_NAMES[key]
            else:
                problems.append(f"observation {key!r} must be a 1-D Box, not {space}")
        elif key == "pixels":
            cameras = space.spaces.items() if isinstance(space, gym.spaces.Dict) else [(None, space)]
            for camera, cam_space in cameras:
                name = "pixels" if camera is None else f"pixels/{camera}"
                shape = getattr(cam_space, "shape", None)
                if isinstance(cam_space, gym.spaces.Box) and cam_space.dtype == np.uint8 and shape and len(shape) == 3:
                    features[name] = ["VISUAL", list(shape)]
                    names[name] = "observation.image" if camera is None else f"observation.images.{camera}"
                else:
                    problems.append(f"observation {name!r} must be an (H, W, 3) uint8 Box, not {cam_space}")
        else:
            problems.append(f"observation key {key!r} is not one of LeRobot's: agent_pos, environment_state, pixels")
    return features, names, problems


def _time_limit(env: gym.Env) -> int | None:
    """The env's own time limit (its spec's, or a ``TimeLimit`` wrapper's), if any."""
    limits = []
    while isinstance(env, gym.Wrapper):  # hub-envs' registration adds one of its own: the smallest ends episodes
        if isinstance(env, gym.wrappers.TimeLimit):
            limits.append(int(env._max_episode_steps))
        env = env.env
    return min(limits) if limits else None


def _attr(env: gym.Env, *names: str) -> Any:
    for name in names:
        try:
            value = env.get_wrapper_attr(name)
        except AttributeError:
            continue
        if isinstance(value, str):
            return value
    return None


def _make_vector(loaded: LoadedEnv, n_envs: int) -> Any:
    """What the entry file's ``make_env(n_envs, use_async_envs=False)`` returns, as LeRobot's ``make_env`` calls it."""
    adapter = sys.modules[loaded.env_class.__module__]
    return adapter.call_make_env(n_envs=n_envs, use_async_envs=False)


def audit(
    repo_id: str,
    *,
    revision: str | None = None,
    trust_remote_code: bool = False,
    seeds: tuple[int, ...] = (0, 1),
    steps: int = 0,
    token: str | None = None,
    cache_dir: str | Path | None = None,
    output: str | Path | None = None,
) -> AuditReport:
    """Audit a plain LeRobot EnvHub repo (``user/name[@rev][:path]``) against LeRobot's EnvHub conventions, publishing
    nothing. The stages: requirements, load (with consent: the repo's code runs), the ``make_env`` contract, gymnasium's
    checker, LeRobot's observation names and the features they give, ``is_success``, the ``final_info`` autoreset
    (lerobot-eval reads per-episode success there: without it every episode scores as a failure), seeding and
    whole-episode determinism, and spaces vs rollouts. A ``make_env`` returning a suite of several tasks has these
    checks run task by task (``report.tasks``), and its tasks' features compared.

    Args:
        repo_id: ``user/name[@rev][:path]``.
        revision: overrides ``@rev``.
        trust_remote_code: consent to run the repo's code for this call (else the trust list must hold repo@sha).
        seeds: the seeds of the determinism and rollout checks.
        steps: steps per rollout (0: the env's own time limit, at most 1000).
        token: as for :func:`hub_envs.load_env`.
        cache_dir: as for :func:`hub_envs.load_env`.
        output: a file to write the JSON report to (None: none).

    Returns:
        The :class:`AuditReport` (``passed``: every check passed).

    Raises:
        UntrustedCodeError: no consent to run the repo's code.
        EnvRepoNotFoundError, RevisionNotFoundError, ConfigError: no such repo or revision, or not a reference.
    """
    ref = parse_hub_path(repo_id)
    if revision is not None:
        ref = type(ref)(ref.repo, revision, ref.entry, ref.explicit_entry)
    src = fetch_plain(ref, token=token, cache_dir=cache_dir)
    if ref.revision != src.sha:  # audited (and adopted) is that commit, not whatever the branch names later
        warnings.warn(
            f"{ref.repo}: revision {ref.revision or 'main'!r} resolved to {src.sha}; that commit is the one audited. Pin it "
            f"for reproducible results: {ref.text(src.sha)}",
            UnpinnedRevisionWarning,
            stacklevel=2,
        )
    report = AuditReport(source=ref.text(src.sha), requirements=list(src.requirements))
    unmet, _ = requirement_status(src.requirements)
    if unmet:
        report.add("requirements", False, "not installed here: " + ", ".join(f"{r} ({why})" for r, why in unmet))
    else:
        report.add("requirements", True, f"{len(src.requirements)} met" + "".join(f"; {n}" for n in src.requirement_notes))
    if unmet:
        report.add("contract", None, "not run: install the requirements first")
        return _finish(report, output)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PlainRepoWarning)  # the audit is about what it cannot guarantee
        try:
            loaded = load_env(ref.text(src.sha), trust_remote_code=trust_remote_code)
        except HubEnvsError as e:
            if type(e).__name__ in ("UntrustedCodeError", "EnvRepoNotFoundError", "RevisionNotFoundError"):
                raise
            report.add("contract", False, str(e))
            return _finish(report, output)
    report.content_digest = loaded.manifest.content_digest  # what consent covered: adopt publishes exactly these files
    try:
        _audit_loaded(loaded, report, seeds, steps)
    finally:
        loaded.unregister()
    return _finish(report, output)


def _audit_loaded(loaded: LoadedEnv, report: AuditReport, seeds: tuple[int, ...], steps: int) -> None:
    vec = _make_vector(loaded, 2)
    form = "dict (suite form)" if isinstance(vec, dict) else type(vec).__name__
    if not loaded.is_suite:
        report.add("contract", True, f"make_env(n_envs=2, use_async_envs=False) returns a {form}")
        _check_final_info(vec, report, seeds[0])
        _audit_env(loaded, report, report.source, seeds, steps)
        report.task = _task_of(loaded)
        return
    by_task = {(s, t): v for s, tasks in vec.items() for t, v in tasks.items()}
    report.add(
        "contract",
        True,
        f"make_env(n_envs=2, use_async_envs=False) returns a suite of {len(loaded.tasks)} tasks "
        f"({', '.join(sorted({str(r['suite']) for r in loaded.manifest.tasks}))})",
    )
    for record in loaded.manifest.tasks:  # each task through the checks of one env, in its own env
        part = AuditTask(record["task"], record["suite"], record["task_id"], record["instruction"])
        report.tasks.append(part)
        _check_final_info(by_task.pop((record["suite"], record["task_id"])), part, seeds[0])
        _audit_env(loaded.for_task(record["task"]), part, f"{report.source} task {record['task']!r}", seeds, steps)
    for rest in by_task.values():
        rest.close()
    first = report.tasks[0]
    report.features, report.features_map, report.episode_length = first.features, first.features_map, first.episode_length
    report.task = first.task
    differ = [t.task for t in report.tasks if (t.features, t.features_map) != (first.features, first.features_map)]
    report.add(
        "the same features for every task",
        not differ,
        f"{len(report.tasks)} tasks: " + ", ".join(f"{k} {t} {tuple(s)}" for k, (t, s) in first.features.items())
        if not differ
        else f"{', '.join(map(repr, differ))} differ from {first.task!r}: one dataset holds every task of a suite",
    )


def _task_of(loaded: LoadedEnv) -> str | None:
    env = loaded.make()
    try:
        return _attr(env, "task_description", "task")
    finally:
        env.close()


def _audit_env(loaded: LoadedEnv, report: AuditReport | AuditTask, where: str, seeds: tuple[int, ...], steps: int) -> None:
    """gymnasium's checker, LeRobot's observation names, ``is_success``, spaces vs rollouts and determinism, on the env
    ``loaded.make`` gives (a suite task's: ``loaded`` is its ``for_task`` view)."""
    env = loaded.make()
    try:
        report.episode_length = _time_limit(env)
        try:
            notes = run_env_checker(env, where=where)
            report.add("gymnasium check_env", True, "; ".join(notes[:3]) or "no warnings")
        except (EnvCheckError, HubEnvsError) as e:
            report.add("gymnasium check_env", False, str(e))
        features, names, problems = infer_features(env.observation_space, env.action_space)
        report.features, report.features_map = features, names
        report.add(
            "LeRobot observation names",
            not problems,
            "; ".join(problems) or ", ".join(f"{k} -> {names[k]}" for k in features),
        )
        n = steps or min(report.episode_length or DEFAULT_EPISODE_LENGTH, DEFAULT_EPISODE_LENGTH)
        _check_rollouts(env, report, seeds, n)
    finally:
        env.close()
    n = steps or min(report.episode_length or DEFAULT_EPISODE_LENGTH, DEFAULT_EPISODE_LENGTH)
    try:
        check_determinism(loaded.make, seeds=seeds, steps=n, where=where)
        report.add(
            "seeding and whole-episode determinism", True, f"seeds {list(seeds)}: bit-identical episodes of up to {n} steps"
        )
    except (DeterminismError, HubEnvsError) as e:
        report.add("seeding and whole-episode determinism", False, str(e))


def _check_final_info(vec: Any, report: AuditReport | AuditTask, seed: int) -> None:
    """lerobot-eval reads per-episode success from ``info["final_info"]["is_success"]``, which a vector env with
    ``AutoresetMode.SAME_STEP`` gives when an episode ends."""
    if isinstance(vec, dict):  # the suite form of one task (a suite of several is checked task by task)
        tasks = [v for by_task in vec.values() if isinstance(by_task, dict) for v in by_task.values()]
        for other in tasks[1:]:
            other.close()
        vec = tasks[0] if tasks else vec
    if isinstance(vec, dict) or not isinstance(vec, gym.vector.VectorEnv):
        what = (
            "a bare gym.Env: LeRobot wraps it in a SyncVectorEnv with NEXT_STEP autoreset"
            if isinstance(vec, gym.Env)
            else "not one VectorEnv"
        )
        report.add(
            "final_info autoreset",
            False,
            f"make_env returns {what}; lerobot-eval then finds no final_info and scores every episode as a failure. Return gym.vector.SyncVectorEnv(fns, autoreset_mode=gym.vector.AutoresetMode.SAME_STEP).",
        )
        (vec.close() if hasattr(vec, "close") else None)
        return
    try:
        mode = vec.metadata.get("autoreset_mode")
        vec.reset(seed=seed)
        vec.action_space.seed(seed)
        found = None
        for _ in range(DEFAULT_EPISODE_LENGTH):
            _, _, term, trunc, info = vec.step(vec.action_space.sample())
            if np.any(term) or np.any(trunc):
                final = info.get("final_info")
                found = isinstance(final, dict) and "is_success" in final
                break
        if found:
            report.add(
                "final_info autoreset",
                True,
                f"{getattr(mode, 'name', mode)}: info['final_info']['is_success'] when an episode ends",
            )
        elif found is None:
            report.add(
                "final_info autoreset",
                False,
                f"no episode ended within {DEFAULT_EPISODE_LENGTH} steps: give the env a time limit",
            )
        else:
            report.add(
                "final_info autoreset",
                False,
                f"autoreset mode {getattr(mode, 'name', mode)}: an episode ended without info['final_info']['is_success'], so "
                f"lerobot-eval scores every episode as a failure. Vectorize with autoreset_mode=gym.vector.AutoresetMode.SAME_STEP.",
            )
    finally:
        vec.close()


def _check_rollouts(env: gym.Env, report: AuditReport | AuditTask, seeds: tuple[int, ...], steps: int) -> None:
    """``is_success`` in every info, and every observation inside the observation space, over seeded random rollouts."""
    bad_success, outside, count = [], [], 0
    for seed in seeds:
        obs, info = env.reset(seed=seed)
        env.action_space.seed(seed)
        for t in range(steps + 1):
            count += 1
            if not isinstance(info.get("is_success"), (bool, np.bool_)) and len(bad_success) < 3:
                bad_success.append(f"seed {seed} step {t}: {info.get('is_success', 'missing')!r}")
            if not env.observation_space.contains(obs) and len(outside) < 3:
                outside.append(f"seed {seed} step {t}")
            if t == steps:
                break
            obs, _, term, trunc, info = env.step(env.action_space.sample())
            if term or trunc:
                count += 1
                if not isinstance(info.get("is_success"), (bool, np.bool_)) and len(bad_success) < 3:
                    bad_success.append(f"seed {seed} final step: {info.get('is_success', 'missing')!r}")
                if not env.observation_space.contains(obs) and len(outside) < 3:
                    outside.append(f"seed {seed} final step")
                break
    report.add(
        "is_success in info",
        not bad_success,
        f"a bool in all {count} reset/step infos"
        if not bad_success
        else "info['is_success'] must be a bool in every reset/step info; got " + ", ".join(bad_success),
    )
    report.add(
        "spaces vs rollouts",
        not outside,
        f"all {count} observations inside observation_space"
        if not outside
        else "observations outside observation_space at " + ", ".join(outside),
    )


def _finish(report: AuditReport, output: str | Path | None) -> AuditReport:
    if output is not None:
        path = Path(output)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(report.to_dict(), indent=2) + "\n")
    return report
