"""The local backend: episodes in worker processes of this machine (the rollout engine's pool)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

from hub_envs.backends.base import Backend
from hub_envs.errors import ConfigError
from hub_envs.harness.rollout import iter_episodes


def default_local_workers() -> int:
    """Processes a local run uses when not told: up to 2 (the episodes' results do not depend on it)."""
    return max(1, min(2, os.cpu_count() or 1))


@dataclass(frozen=True)
class LocalBackend(Backend):
    """Episodes in ``workers`` processes of this machine (:func:`hub_envs.harness.rollout.iter_episodes`)."""

    workers: int = 1
    name = "local"

    def __post_init__(self) -> None:
        if isinstance(self.workers, bool) or not isinstance(self.workers, int) or self.workers < 1:
            raise ConfigError(f"workers={self.workers!r}: pass a positive number of processes.")

    def episodes(self, loaded, seeds, *, max_steps, policy=None, record_states=False, progress=True, desc="rollouts"):
        """As :meth:`Backend.episodes`, in this machine's worker processes (:func:`~hub_envs.harness.rollout.iter_episodes`).

        Args:
            loaded, seeds, max_steps, policy, record_states, progress, desc: as :meth:`Backend.episodes`.

        Returns:
            The rollouts, in episode order.
        """
        return iter_episodes(
            loaded.make,
            seeds,
            max_steps=max_steps,
            policy=policy,
            record_states=record_states,
            workers=self.workers,
            progress=progress,
            desc=desc,
        )

    def settings(self) -> dict[str, Any]:
        """``{"backend": "local", "workers": n}``."""
        return {"backend": self.name, "workers": self.workers}
