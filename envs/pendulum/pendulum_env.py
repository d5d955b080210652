"""Pendulum swing-up: gymnasium's Pendulum-v1 in LeRobot's format.

The dynamics, reward and initial-state distribution are gymnasium's own ``PendulumEnv`` (this env
drives one internally), so a trajectory here is bit-for-bit the Pendulum-v1 trajectory for the same
initial state and torques. What changes is the interface:

* **Action** ``(1,)`` float32 in ``[-1, 1]``, scaled to a torque ``2 * a`` N m (Pendulum-v1's range
  ``[-2, 2]``; values outside ``[-1, 1]`` are clipped).
* **Observation** a dict. ``agent_pos`` ``(3,)`` float32 = ``(cos theta, sin theta, theta_dot)``,
  ``theta = 0`` upright, ``theta_dot`` in ``[-8, 8]`` rad/s. With ``obs_type="pixels_agent_pos"``
  also ``pixels``: the rendered frame, ``(observation_height, observation_width, 3)`` uint8.
* **Reward** Pendulum-v1's ``-(theta^2 + 0.1 * theta_dot^2 + 0.001 * torque^2)`` with theta
  normalised to ``[-pi, pi]``; between about -16.27 and 0.
* **Start** theta uniform in ``[-pi, pi]``, theta_dot uniform in ``[-1, 1]`` (Pendulum-v1's; the
  reset options ``x_init`` / ``y_init`` change those bounds as in gymnasium).
* **Termination** never (as in Pendulum-v1); episodes end by the time limit (200 steps).
* **Success** ``info["is_success"]`` is True when the pendulum is *upright and nearly still*:
  ``|theta| < 0.1`` rad (about 5.7 degrees, theta normalised to ``[-pi, pi]``) **and**
  ``|theta_dot| < 0.5`` rad/s, evaluated on the state after the step (and after reset).
* **Time** one step is 0.05 s of simulated time (Pendulum-v1's ``dt``); frames are played back at
  ``fps`` (30 by default, as Pendulum-v1's ``render_fps``), i.e. 1.5x real time.
* **Rendering** ``render()`` returns an ``(observation_height, observation_width, 3)`` uint8 frame
  drawn with numpy (white background, red rod, upright is up); no window, no pygame.
* **State** ``get_state()`` is ``[theta, theta_dot]`` (float64); ``reset_to(state)`` restores it
  exactly, so continuing from a restored state is bit-identical to the original continuation.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.envs.classic_control import utils as classic_utils
from gymnasium.envs.classic_control.pendulum import DEFAULT_X, DEFAULT_Y, angle_normalize
from gymnasium.envs.classic_control.pendulum import PendulumEnv as GymPendulumEnv

from .drawing import PendulumPainter

OBS_TYPES = ("state", "pixels_agent_pos")
MAX_TORQUE = 2.0  # N m, torque for action +1
MAX_SPEED = 8.0  # rad/s, Pendulum-v1 clips theta_dot to this
SUCCESS_MAX_ANGLE = 0.1  # rad
SUCCESS_MAX_SPEED = 0.5  # rad/s
STATE_SIZE = 2  # get_state(): theta, theta_dot


def is_upright(theta: float, theta_dot: float) -> bool:
    """The success criterion: ``|theta| < 0.1`` rad (normalised) and ``|theta_dot| < 0.5`` rad/s."""
    return bool(abs(angle_normalize(theta)) < SUCCESS_MAX_ANGLE and abs(theta_dot) < SUCCESS_MAX_SPEED)


class PendulumEnv(gym.Env):
    """Pendulum-v1 with dict observations, a ``[-1, 1]`` action and ``info["is_success"]``."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(
        self,
        obs_type: str = "state",
        observation_height: int = 64,
        observation_width: int = 64,
        g: float = 10.0,
        fps: int = 30,
        render_mode: str | None = "rgb_array",
    ):
        if obs_type not in OBS_TYPES:
            raise ValueError(f"obs_type={obs_type!r} is not supported; use one of {list(OBS_TYPES)}.")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode={render_mode!r} is not supported; use 'rgb_array' (or None).")
        self.obs_type = obs_type
        self.render_mode = render_mode
        self.metadata = {**type(self).metadata, "render_fps": int(fps)}
        self._dynamics = GymPendulumEnv(render_mode=None, g=g)  # gymnasium's own equations of motion
        self._dynamics.state = np.array([np.pi, 0.0])  # hanging down until reset
        self._painter = PendulumPainter(observation_height, observation_width)

        obs_spaces = {
            "agent_pos": spaces.Box(
                low=np.array([-1.0, -1.0, -MAX_SPEED], dtype=np.float32),
                high=np.array([1.0, 1.0, MAX_SPEED], dtype=np.float32),
                dtype=np.float32,
            )
        }
        if obs_type == "pixels_agent_pos":
            obs_spaces["pixels"] = spaces.Box(low=0, high=255, shape=(observation_height, observation_width, 3), dtype=np.uint8)
        self.observation_space = spaces.Dict(obs_spaces)
        self.action_space = spaces.Box(low=-1.0, high=1.0, shape=(1,), dtype=np.float32)

    # --- gymnasium API ---------------------------------------------------------------------------

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        # Pendulum-v1's initial-state distribution, drawn the same way from the same generator
        options = options or {}
        x = classic_utils.verify_number_and_cast(options.get("x_init", DEFAULT_X))
        y = classic_utils.verify_number_and_cast(options.get("y_init", DEFAULT_Y))
        high = np.array([x, y])
        self._dynamics.state = self.np_random.uniform(low=-high, high=high)
        self._dynamics.last_u = None
        return self._get_obs(), self._get_info()

    def step(self, action):
        a = np.clip(np.asarray(action, dtype=np.float32).reshape(1), -1.0, 1.0)
        torque = (a * np.float32(MAX_TORQUE)).astype(np.float32)  # exact: scaling by 2
        _, reward, _, _, _ = self._dynamics.step(torque)
        return self._get_obs(), float(reward), False, False, self._get_info()

    def render(self) -> np.ndarray:
        return self._painter.draw(float(self._dynamics.state[0]))

    def close(self):
        self._dynamics.close()

    # --- exact state save / restore ---------------------------------------------------------------

    def get_state(self) -> np.ndarray:
        """``[theta, theta_dot]`` as float64: everything the continuation depends on."""
        return np.array(self._dynamics.state, dtype=np.float64).reshape(STATE_SIZE).copy()

    def reset_to(self, state) -> dict[str, np.ndarray]:
        """Restore a state from :meth:`get_state` and return its observation."""
        state = np.asarray(state, dtype=np.float64)
        if state.shape != (STATE_SIZE,):
            raise ValueError(
                f"PendulumEnv.reset_to expects a state of shape ({STATE_SIZE},) [theta, theta_dot], got {state.shape}."
            )
        self._dynamics.state = state.copy()
        self._dynamics.last_u = None
        return self._get_obs()

    # --- helpers ----------------------------------------------------------------------------------

    def _get_obs(self) -> dict[str, np.ndarray]:
        theta, theta_dot = self._dynamics.state
        obs = {"agent_pos": np.array([np.cos(theta), np.sin(theta), theta_dot], dtype=np.float32)}
        if self.obs_type == "pixels_agent_pos":
            obs["pixels"] = self.render()
        return obs

    def _get_info(self) -> dict[str, Any]:
        theta, theta_dot = self._dynamics.state
        return {"is_success": is_upright(theta, theta_dot)}
