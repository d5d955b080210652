"""One seeded episode stepped by hand (:class:`SeededEpisode`): the convention every rollout in hub-envs follows.

Example:
    >>> import gymnasium as gym
    >>> episode = SeededEpisode(gym.make("CartPole-v1"), seed=0)
    >>> while not episode.done:
    ...     _ = episode.step(episode.sample())
    >>> again = SeededEpisode(gym.make("CartPole-v1"), seed=0)
    >>> while not again.done:
    ...     _ = again.step(again.sample())
    >>> episode.t == again.t, episode.terminated
    (True, True)
"""

from __future__ import annotations

import traceback
from typing import Any

from hub_envs.errors import EnvCodeError

__all__ = ["SeededEpisode", "exception_text"]


def _raised_at(exc: BaseException) -> str:
    frames = traceback.extract_tb(exc.__traceback__)
    if not frames:
        return ""
    f = frames[-1]
    return f" (raised at {f.filename}:{f.lineno} in {f.name})"


def exception_text(exc: BaseException) -> str:
    """What an error message quotes of an exception raised by env code.

    Args:
        exc: the exception.

    Returns:
        ``"TypeName: message (raised at file:line in function)"``.
    """
    return f"{type(exc).__name__}: {exc}{_raised_at(exc)}"


class SeededEpisode:
    """An episode of ``env`` reset with ``seed``; ``env.action_space`` is seeded with the same seed.

    Attributes after each :meth:`step`: ``obs`` and ``info`` (the latest; the reset ones before the
    first step), ``t`` (steps taken), ``terminated``/``truncated`` (of the last step) and ``done``.
    ``where`` names the episode in error messages (e.g. ``"episode 3 (seed 7)"``).
    """

    __slots__ = ("env", "seed", "where", "space", "obs", "info", "t", "terminated", "truncated", "_step")

    def __init__(self, env: Any, seed: int, *, where: str | None = None):
        self.env = env
        self.seed = seed
        self.where = where or f"seed {seed}"
        try:
            self.obs, self.info = env.reset(seed=seed)
        except Exception as exc:
            raise EnvCodeError(
                f"{self.where}: env.reset(seed={seed}) raised {exception_text(exc)}. Fix the env's reset "
                f"(reproduce with env.reset(seed={seed})) and publish it again with push_env."
            ) from exc
        self.space = env.action_space
        self.space.seed(seed)
        self.t = 0
        self.terminated = self.truncated = False
        self._step = env.step

    @property
    def done(self) -> bool:
        """The env ended the episode (terminated or truncated) at the last step."""
        return self.terminated or self.truncated

    def sample(self) -> Any:
        """A seeded random action (the next sample of the seeded action space)."""
        return self.space.sample()

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict]:
        """Step the env.

        Args:
            action: the action.

        Returns:
            ``env.step(action)``'s ``(obs, reward, terminated, truncated, info)``.

        Raises:
            EnvCodeError: the env's step raised (naming the episode, seed and step).
        """
        try:
            result = obs, _reward, terminated, truncated, info = self._step(action)
        except Exception as exc:
            raise self.step_error(exc, self.t) from exc
        self.obs, self.info, self.terminated, self.truncated = obs, info, terminated, truncated
        self.t += 1
        return result

    def step_error(self, exc: BaseException, t: int) -> EnvCodeError:
        """The error for ``exc`` raised by ``env.step`` at step ``t`` (for a loop that calls ``env.step`` itself)."""
        return EnvCodeError(
            f"{self.where}, step {t}: env.step(action) raised {exception_text(exc)}. Fix the env's step "
            f"(reproduce with env.reset(seed={self.seed}) and the same actions) and publish it again with push_env."
        )
