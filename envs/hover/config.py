"""LeRobot EnvConfig of the hover env (hub-envs registers it; it is not registered here)."""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig
from lerobot.utils.constants import ACTION, OBS_STATE

from .hover_env import check_act_type, check_fps, observation_size


@dataclass
class HoverEnvConfig(EnvConfig):
    """Quadrotor hover at (0, 0, 1).

    ``act_type`` is ``"one_d_rpm"`` (one command for all motors, action (1,)) or ``"rpm"`` (one per
    motor, action (4,)); ``agent_pos`` is 12 kinematic values plus the last ``fps // 2`` actions,
    so both feature shapes follow from ``act_type`` and ``fps`` (a divisor of 240).
    The default ``episode_length`` is HoverAviary's 8 s at the default 30 fps.
    """

    task: str | None = "Hover-v0"
    fps: int = 30
    episode_length: int = 240
    act_type: str = "one_d_rpm"
    render_height: int = 128
    render_width: int = 128
    features: dict[str, PolicyFeature] = field(default_factory=dict)
    features_map: dict[str, str] = field(
        default_factory=lambda: {
            ACTION: ACTION,
            "agent_pos": OBS_STATE,
        }
    )

    def __post_init__(self):
        act_dim = check_act_type(self.act_type)
        check_fps(self.fps)
        self.features[ACTION] = PolicyFeature(type=FeatureType.ACTION, shape=(act_dim,))
        self.features["agent_pos"] = PolicyFeature(type=FeatureType.STATE, shape=(observation_size(self.act_type, self.fps),))

    @property
    def gym_kwargs(self) -> dict:
        return {
            "act_type": self.act_type,
            "fps": self.fps,
            "render_height": self.render_height,
            "render_width": self.render_width,
        }
