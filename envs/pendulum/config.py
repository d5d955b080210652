"""LeRobot EnvConfig of the pendulum env (hub-envs registers it; it is not registered here)."""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig
from lerobot.utils.constants import ACTION, OBS_IMAGE, OBS_STATE

from .pendulum_env import OBS_TYPES


@dataclass
class PendulumEnvConfig(EnvConfig):
    """Pendulum-v1 swing-up.

    ``obs_type="state"`` observes ``agent_pos`` (cos theta, sin theta, theta_dot);
    ``obs_type="pixels_agent_pos"`` adds the rendered frame as ``pixels`` (``observation.image``).
    """

    task: str | None = "Pendulum-v1"
    fps: int = 30
    episode_length: int = 200
    obs_type: str = "state"
    observation_height: int = 64
    observation_width: int = 64
    g: float = 10.0  # gravity, m/s^2 (Pendulum-v1's parameter)
    features: dict[str, PolicyFeature] = field(
        default_factory=lambda: {
            ACTION: PolicyFeature(type=FeatureType.ACTION, shape=(1,)),
            "agent_pos": PolicyFeature(type=FeatureType.STATE, shape=(3,)),
        }
    )
    features_map: dict[str, str] = field(
        default_factory=lambda: {
            ACTION: ACTION,
            "agent_pos": OBS_STATE,
            "pixels": OBS_IMAGE,
        }
    )

    def __post_init__(self):
        if self.obs_type not in OBS_TYPES:
            raise ValueError(f"obs_type={self.obs_type!r} is not supported; use one of {list(OBS_TYPES)}.")
        if self.obs_type == "pixels_agent_pos":
            self.features["pixels"] = PolicyFeature(
                type=FeatureType.VISUAL, shape=(self.observation_height, self.observation_width, 3)
            )
        else:
            self.features.pop("pixels", None)

    @property
    def gym_kwargs(self) -> dict:
        return {
            "obs_type": self.obs_type,
            "observation_height": self.observation_height,
            "observation_width": self.observation_width,
            "g": self.g,
            "fps": self.fps,
        }
