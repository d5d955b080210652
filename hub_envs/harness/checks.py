"""The checks that run the env's code: gymnasium's env checker, determinism (two fresh envs, the same actions), and the
golden-rollout fingerprint (recorded at push, recomputed at load).

Example:
    >>> from hub_envs.harness.checks import golden_fingerprint                          # doctest: +SKIP
    >>> golden_fingerprint(lambda: loaded.make(), seeds=[0, 1], steps=32)       # doctest: +SKIP
    {'algorithm': 'sha256', 'seeds': [0, 1], 'steps': 32, 'digest': '…', 'episodes': ['…', '…']}
"""

from __future__ import annotations

import dataclasses
import hashlib
import warnings
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from gymnasium.utils.env_checker import check_env

from hub_envs.errors import DeterminismError, EnvCheckError, EnvCodeError, FingerprintMismatchError
from hub_envs.harness.rollout import EpisodeRollout, run_episodes

#: Steps of each seed the golden-rollout fingerprint covers (fewer when episodes are shorter).
FINGERPRINT_STEPS = 32


def run_env_checker(env, *, where: str) -> list[str]:
    """Run gymnasium's ``check_env`` on the unwrapped env.

    Args:
        env: the env.
        where: names it in messages.

    Returns:
        The checker's warnings.

    Raises:
        EnvCheckError: the checker refused the env.
    """
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            check_env(env.unwrapped, skip_render_check=False)
        except (AssertionError, TypeError, ValueError, NotImplementedError) as e:
            raise EnvCheckError(
                f"{where}: gymnasium's check_env refused the env: {e}\n"
                f"Run `from gymnasium.utils.env_checker import check_env; check_env(env)` on it and fix what it reports."
            ) from e
        except ImportError as e:
            raise EnvCodeError(
                f"{where}: the env raised {type(e).__name__} inside gymnasium's check_env: {e}. Install it and list it in "
                f"the env's [project] dependencies (check_env calls render(), and publishing renders the card's GIF)."
            ) from e
        except Exception as e:
            raise EnvCodeError(f"{where}: the env raised {type(e).__name__} inside gymnasium's check_env: {e}") from e
    return sorted({str(w.message) for w in caught})


def _episode_digest(ep: EpisodeRollout) -> str:
    h = hashlib.sha256()
    for key in sorted(ep.observations):
        arr = np.ascontiguousarray(ep.observations[key])
        h.update(key.encode() + str(arr.dtype).encode() + str(arr.shape).encode())
        h.update(arr.tobytes())
    for arr in (ep.actions, ep.rewards, ep.terminated, ep.truncated):
        arr = np.ascontiguousarray(arr)
        h.update(str(arr.dtype).encode() + str(arr.shape).encode())
        h.update(arr.tobytes())
    return h.hexdigest()


def _first_difference(a: EpisodeRollout, b: EpisodeRollout) -> str:
    pairs = [(f"observation {k!r}", a.observations[k], b.observations.get(k)) for k in sorted(a.observations)]
    pairs += [
        ("reward", a.rewards, b.rewards),
        ("terminated", a.terminated, b.terminated),
        ("truncated", a.truncated, b.truncated),
    ]
    for name, x, y in pairs:
        if y is None or x.shape != y.shape:
            return f"{name}: shapes {getattr(x, 'shape', None)} vs {getattr(y, 'shape', None)}"
        diff = np.nonzero(np.any((x != y).reshape(len(x), -1), axis=1))[0] if len(x) else []
        if len(diff):
            i = int(diff[0])
            delta = np.max(np.abs(x[i].astype(np.float64) - y[i].astype(np.float64)))
            return f"{name} at step {i} (max abs difference {delta:.3g})"
    return "lengths differ"


def check_determinism(make_env: Callable[[], Any], *, seeds: Sequence[int], steps: int, where: str) -> None:
    """Per seed, two fresh envs reset with it and driven by the same seeded random actions must give bit-identical rollouts.

    Args:
        make_env: makes a fresh env.
        seeds: the seeds to try.
        steps: steps per rollout (a whole episode at push).
        where: names the env in messages.

    Raises:
        DeterminismError: naming the seed, key, step and size of the first difference.
    """
    for seed in seeds:
        first = run_episodes(make_env, [seed], max_steps=steps, progress=False)[0]
        second = run_episodes(make_env, [seed], max_steps=steps, progress=False)[0]
        if _episode_digest(first) != _episode_digest(second):
            raise DeterminismError(
                f"{where}: two rollouts with seed {seed} differ: {_first_difference(first, second)}.\n"
                f"Seed every source of randomness from reset(seed=...) (use self.np_random), reset every piece of "
                f"state in reset(), and avoid global state."
            )


def episode_prefix(ep: EpisodeRollout, steps: int) -> EpisodeRollout:
    """The first ``steps`` steps of an episode, exactly as a run cut at ``max_steps=steps`` records them (the cut step is a
    time-limit truncation), so a fingerprint can come from longer rollouts (push's dataset).

    Args:
        ep: a rollout.
        steps: how many steps.

    Returns:
        The cut rollout (``ep`` itself when it is no longer).
    """
    if ep.length <= steps:
        return ep
    cut = slice(0, steps)
    truncated = ep.truncated[cut].copy()
    if not ep.terminated[steps - 1]:
        truncated[-1] = True
    return dataclasses.replace(
        ep,
        observations={k: v[cut] for k, v in ep.observations.items()},
        actions=ep.actions[cut],
        rewards=ep.rewards[cut],
        terminated=ep.terminated[cut],
        truncated=truncated,
        is_success=ep.is_success[cut],
        states=None,
    )


def fingerprint_of(episodes: Sequence[EpisodeRollout], *, steps: int) -> dict[str, Any]:
    """The golden-rollout fingerprint of seeded random-action episodes.

    Args:
        episodes: the rollouts (each cut to its first ``steps``).
        steps: the steps hashed.

    Returns:
        ``{"algorithm", "seeds", "steps", "digest", "episodes"}``: one digest per episode and one overall.
    """
    digests = [_episode_digest(episode_prefix(ep, steps)) for ep in episodes]
    overall = hashlib.sha256("".join(digests).encode()).hexdigest()
    return {"algorithm": "sha256", "seeds": [ep.seed for ep in episodes], "steps": steps, "digest": overall, "episodes": digests}


def golden_fingerprint(make_env: Callable[[], Any], *, seeds: list[int], steps: int) -> dict[str, Any]:
    """Run seeded random-action rollouts and fingerprint their first ``steps`` steps (:func:`fingerprint_of`).

    Args:
        make_env: makes a fresh env.
        seeds: one episode per seed.
        steps: steps per episode.

    Returns:
        The fingerprint.
    """
    return fingerprint_of(run_episodes(make_env, list(seeds), max_steps=steps, progress=False), steps=steps)


def verify_fingerprint(
    make_env: Callable[[], Any],
    recorded: dict[str, Any],
    *,
    where: str,
    versions_note: str | Callable[[], str] = "",
    episodes: Sequence[EpisodeRollout] | None = None,
) -> dict[str, Any]:
    """Recompute a recorded fingerprint.

    Args:
        make_env: makes a fresh env.
        recorded: the manifest's ``fingerprint``.
        where: names the env in messages.
        versions_note: what ends a mismatch's message (or a callable returning it, called only on a mismatch).
        episodes: seeded random-action rollouts of the recorded seeds, in their order, run already with
            ``max_steps`` of at least the recorded steps (a benchmark's random-policy episodes): the fingerprint
            comes from them (:func:`fingerprint_of`) instead of running the seeds again.

    Returns:
        The fresh fingerprint.

    Raises:
        FingerprintMismatchError: naming the seeds that drifted.
    """
    steps = int(recorded["steps"])
    if episodes is not None and [ep.seed for ep in episodes] == list(recorded["seeds"]):
        fresh = fingerprint_of(episodes, steps=steps)
    else:
        fresh = golden_fingerprint(make_env, seeds=list(recorded["seeds"]), steps=steps)
    if fresh["digest"] != recorded["digest"]:
        if callable(versions_note):
            versions_note = versions_note()
        drifted = [s for s, a, b in zip(recorded["seeds"], recorded["episodes"], fresh["episodes"]) if a != b]
        raise FingerprintMismatchError(
            f"{where}: the golden-rollout fingerprint drifted: the first {recorded['steps']} steps of seeds {drifted} "
            f"no longer match what was published.{versions_note}\n"
            f"Run `hub-envs reproduce` for the step-by-step divergence, or pass fingerprint='warn' to load anyway."
        )
    return fresh
