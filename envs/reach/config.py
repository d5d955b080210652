"""LeRobot EnvConfig of the reach env (hub-envs registers it; it is not registered here)."""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig
from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_IMAGE, OBS_STATE

from .arm import NUM_JOINTS
from .reach_env import check_fps, check_obs_type


@dataclass
class ReachEnvConfig(EnvConfig):
    """KUKA iiwa reach.

    ``obs_type="pixels_agent_pos"`` (default) observes ``agent_pos`` (7 joint positions and 7
    joint velocities, ``observation.state``) and ``pixels`` (the camera image,
    ``observation.image``); ``obs_type="environment_state_agent_pos"`` replaces the image by the
    target's position ``environment_state`` (``observation.environment_state``).
    """

    task: str | None = "Reach-v0"
    fps: int = 20
    episode_length: int = 100
    obs_type: str = "pixels_agent_pos"
    observation_height: int = 96
    observation_width: int = 96
    render_height: int = 96  # env.render() (the card's media): the same camera, at this size
    render_width: int = 96
    features: dict[str, PolicyFeature] = field(
        default_factory=lambda: {
            ACTION: PolicyFeature(type=FeatureType.ACTION, shape=(NUM_JOINTS,)),
            "agent_pos": PolicyFeature(type=FeatureType.STATE, shape=(2 * NUM_JOINTS,)),
        }
    )
    features_map: dict[str, str] = field(
        default_factory=lambda: {
            ACTION: ACTION,
            "agent_pos": OBS_STATE,
            "pixels": OBS_IMAGE,
            "environment_state": OBS_ENV_STATE,
        }
    )

    def __post_init__(self):
        check_obs_type(self.obs_type)
        check_fps(self.fps)
        self.features.pop("pixels", None)
        self.features.pop("environment_state", None)
        if self.obs_type == "pixels_agent_pos":
            self.features["pixels"] = PolicyFeature(
                type=FeatureType.VISUAL, shape=(self.observation_height, self.observation_width, 3)
            )
        else:
            self.features["environment_state"] = PolicyFeature(type=FeatureType.ENV, shape=(3,))

    @property
    def gym_kwargs(self) -> dict:
        return {
            "obs_type": self.obs_type,
            "observation_height": self.observation_height,
            "observation_width": self.observation_width,
            "render_height": self.render_height,
            "render_width": self.render_width,
            "fps": self.fps,
        }
