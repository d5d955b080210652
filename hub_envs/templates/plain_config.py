"""The LeRobot EnvConfig of a plain LeRobot EnvHub repo's env (see plain_env.py), written by hub-envs. Do not edit."""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig

#: What the env observes and takes, found from its spaces and a live rollout: name -> (FeatureType name, shape).
FEATURES = {{FEATURES}}
#: LeRobot's names for them (``agent_pos`` -> ``observation.state``, ``pixels`` -> ``observation.image``, ...).
FEATURES_MAP = {{FEATURES_MAP}}


@dataclass
class PlainEnvConfig(EnvConfig):
    """The env's settings: none of its own (``make_env`` takes none), its task (a suite's: the one to make), its time
    limit and LeRobot's features."""

    task: str | None = {{TASK}}
    fps: int = {{FPS}}
    episode_length: int = {{EPISODE_LENGTH}}
    features: dict[str, PolicyFeature] = field(
        default_factory=lambda: {k: PolicyFeature(type=FeatureType[t], shape=tuple(s)) for k, (t, s) in FEATURES.items()}
    )
    features_map: dict[str, str] = field(default_factory=lambda: dict(FEATURES_MAP))

    @property
    def gym_kwargs(self) -> dict:
        return {"task": self.task} if self.task is not None else {}  # a suite's task picks its env (one env: ignored)
