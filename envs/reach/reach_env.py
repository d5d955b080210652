"""Reach: move a KUKA LBR iiwa 7 arm's end effector to a green ball seen by a camera.

A pybullet (DIRECT mode, headless) scene: the KUKA iiwa from ``pybullet_data``
(``kuka_iiwa/model.urdf``) bolted to the ground plane at the origin, and a target ball sampled
in front of it at every reset. Physics at 240 Hz, control at ``fps`` (20 by default; must divide
240), joints driven by pybullet's position controllers with the URDF effort limits (300 N m).

* **Action** ``(7,)`` float32 in ``[-1, 1]`` (clipped): joint position deltas. Each control step
  sets the joint targets to ``q + 0.05 * a`` rad (clipped to the joint limits), where ``q`` are the
  current joint positions; ``a = 0`` holds the arm where it is.
* **Observation** ``agent_pos`` ``(14,)`` float32: the 7 joint positions (rad) then the 7 joint
  velocities (rad/s, clipped to +-10). With ``obs_type="pixels_agent_pos"`` (default) also
  ``pixels``: an RGB image ``(observation_height, observation_width, 3)`` uint8 (96x96 by default)
  from a fixed camera that sees the arm and the ball; the ball's position is only in the image.
  With ``obs_type="environment_state_agent_pos"``, ``environment_state`` ``(3,)`` float32 is the
  ball's position (m) instead of the image.
* **Target** a green ball (visual only, radius 0.035 m, with a dark green disc on the floor under
  it as a depth cue) at ``x ~ U(0.3, 0.7)``, ``y ~ U(-0.3, 0.3)``, ``z ~ U(0.15, 0.6)`` m, resampled
  until it is at least 0.15 m from the start end effector.
* **End effector** the origin of the last link's frame (``lbr_iiwa_link_7``).
* **Reward** ``-distance(end effector, target)`` in metres, every step (dense).
* **Success** ``info["is_success"]`` is True when the end effector is within 0.05 m of the
  target's centre; the episode then terminates.
* **Termination** on success. No truncation by the env; the time limit (``episode_length``,
  100 steps = 5 s at 20 fps) is added by hub-envs.
* **Start** joints at the home pose ``(0, 0.5, 0, -1.5, 0, 1.1, 0)`` rad plus ``U(-0.1, 0.1)`` each,
  at rest; the end effector starts around ``(0.57, 0, 0.48)`` m.
* **Rendering** ``render()`` returns the camera image (the same camera as ``pixels``, pybullet's
  ER_TINY_RENDERER), ``(render_height, render_width, 3)`` (96x96 by default, as ``pixels``).
* **State** ``get_state()`` = ``[q (7), q_dot (7), target xyz (3)]`` float64; ``reset_to(state)``
  restores it exactly. After every control step the env reads the joint state, writes it back and
  drops pybullet's persistent arm-ground contact points, so the pybullet state at a step boundary
  is a function of the recorded numbers alone and a restored continuation is bit-identical to the
  original one (observations, images, rewards).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pybullet as p
import pybullet_data
from gymnasium import spaces

from .arm import NUM_JOINTS, end_effector_position, forget_contacts, load_arm, read_joints, write_joints

OBS_TYPES = ("pixels_agent_pos", "environment_state_agent_pos")
PYB_FREQ = 240
GRAVITY_ACCEL = 9.81
MAX_JOINT_DELTA = 0.05  # rad per control step for a = +-1
MAX_JOINT_SPEED = 10.0  # rad/s, observation clipping (the URDF velocity limit)
HOME = np.array([0.0, 0.5, 0.0, -1.5, 0.0, 1.1, 0.0])
HOME_NOISE = 0.1  # rad
TARGET_LOW = np.array([0.3, -0.3, 0.15])
TARGET_HIGH = np.array([0.7, 0.3, 0.6])
TARGET_MIN_START_DISTANCE = 0.15  # m
WORKSPACE_LOW = np.array([-1.5, -1.5, -0.5])  # bounds of environment_state (targets given to reset_to may
WORKSPACE_HIGH = np.array([1.5, 1.5, 2.0])  # lie outside the sampling box; values are clipped to these)
TARGET_RADIUS = 0.035  # m, the ball in the picture
SUCCESS_DISTANCE = 0.05  # m
STATE_SIZE = 2 * NUM_JOINTS + 3


def check_fps(fps: int) -> int:
    """Physics steps per control step, or a ValueError if fps does not divide 240."""
    if not isinstance(fps, (int, np.integer)) or fps < 1 or PYB_FREQ % fps:
        divisors = [f for f in range(1, PYB_FREQ + 1) if PYB_FREQ % f == 0]
        raise ValueError(f"fps={fps!r} is not supported: the physics runs at {PYB_FREQ} Hz, so fps must be one of {divisors}.")
    return PYB_FREQ // int(fps)


def check_obs_type(obs_type: str) -> str:
    if obs_type not in OBS_TYPES:
        raise ValueError(f"obs_type={obs_type!r} is not supported; use one of {list(OBS_TYPES)}.")
    return obs_type


class ReachEnv(gym.Env):
    """KUKA iiwa reaching a target ball; state + image observations. See the module docstring."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}

    def __init__(
        self,
        obs_type: str = "pixels_agent_pos",
        observation_height: int = 96,
        observation_width: int = 96,
        fps: int = 20,
        render_mode: str | None = "rgb_array",
        render_height: int | None = None,
        render_width: int | None = None,
    ):
        self.obs_type = check_obs_type(obs_type)
        self.physics_steps_per_control = check_fps(fps)
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode={render_mode!r} is not supported; use 'rgb_array' (or None).")
        self.render_mode = render_mode
        self.fps = int(fps)
        self.metadata = {**type(self).metadata, "render_fps": self.fps}
        self.height, self.width = int(observation_height), int(observation_width)
        # render(): the same camera, at the observation's size unless asked otherwise (the card's GIF asks for 256 px)
        self.render_height = int(render_height) if render_height else self.height
        self.render_width = int(render_width) if render_width else self.width

        self._client = p.connect(p.DIRECT)
        c = self._client
        p.resetSimulation(physicsClientId=c)
        p.setPhysicsEngineParameter(fixedTimeStep=1.0 / PYB_FREQ, deterministicOverlappingPairs=1, physicsClientId=c)
        p.setGravity(0, 0, -GRAVITY_ACCEL, physicsClientId=c)
        self._plane = p.loadURDF(pybullet_data.getDataPath() + "/plane.urdf", physicsClientId=c)
        self.arm = load_arm(c)
        ball = p.createVisualShape(p.GEOM_SPHERE, radius=TARGET_RADIUS, rgbaColor=[0.1, 0.85, 0.1, 1.0], physicsClientId=c)
        self._ball = p.createMultiBody(baseMass=0, baseVisualShapeIndex=ball, basePosition=[0.5, 0, 0.3], physicsClientId=c)
        # a dark green disc on the floor under the ball: a depth cue for the single camera
        disc = p.createVisualShape(
            p.GEOM_CYLINDER, radius=TARGET_RADIUS, length=0.002, rgbaColor=[0.05, 0.35, 0.05, 1.0], physicsClientId=c
        )
        self._disc = p.createMultiBody(baseMass=0, baseVisualShapeIndex=disc, basePosition=[0.5, 0, 0.001], physicsClientId=c)
        self._view = p.computeViewMatrix(
            cameraEyePosition=[1.0, -1.2, 1.0], cameraTargetPosition=[0.4, 0.0, 0.33], cameraUpVector=[0, 0, 1], physicsClientId=c
        )
        self._proj = p.computeProjectionMatrixFOV(
            fov=50, aspect=self.width / self.height, nearVal=0.05, farVal=10.0, physicsClientId=c
        )

        obs_spaces = {
            "agent_pos": spaces.Box(
                low=np.concatenate([self.arm.lower, -MAX_JOINT_SPEED * np.ones(NUM_JOINTS)]).astype(np.float32),
                high=np.concatenate([self.arm.upper, MAX_JOINT_SPEED * np.ones(NUM_JOINTS)]).astype(np.float32),
                dtype=np.float32,
            )
        }
        if self.obs_type == "pixels_agent_pos":
            obs_spaces["pixels"] = spaces.Box(low=0, high=255, shape=(self.height, self.width, 3), dtype=np.uint8)
        else:
            obs_spaces["environment_state"] = spaces.Box(
                low=WORKSPACE_LOW.astype(np.float32), high=WORKSPACE_HIGH.astype(np.float32), dtype=np.float32
            )
        self.observation_space = spaces.Dict(obs_spaces)
        self.action_space = spaces.Box(low=-1.0, high=1.0, shape=(NUM_JOINTS,), dtype=np.float32)
        self._obs_low = obs_spaces["agent_pos"].low.astype(np.float64)
        self._obs_high = obs_spaces["agent_pos"].high.astype(np.float64)

        self._joints = np.concatenate([HOME, np.zeros(NUM_JOINTS)])
        self._target = np.array([0.5, 0.0, 0.3])
        self._restore(np.concatenate([self._joints, self._target]))

    # --- gymnasium API ---------------------------------------------------------------------------

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        q = np.clip(HOME + self.np_random.uniform(-HOME_NOISE, HOME_NOISE, size=NUM_JOINTS), self.arm.lower, self.arm.upper)
        write_joints(self._client, self.arm, np.concatenate([q, np.zeros(NUM_JOINTS)]))
        start = end_effector_position(self._client, self.arm)
        while True:
            target = self.np_random.uniform(TARGET_LOW, TARGET_HIGH)
            if np.linalg.norm(target - start) >= TARGET_MIN_START_DISTANCE:
                break
        self._restore(np.concatenate([q, np.zeros(NUM_JOINTS), target]))
        return self._get_obs(), self._get_info()

    def step(self, action):
        a = np.clip(np.asarray(action, dtype=np.float64).reshape(NUM_JOINTS), -1.0, 1.0)
        q = self._joints[:NUM_JOINTS]
        targets = np.clip(q + MAX_JOINT_DELTA * a, self.arm.lower, self.arm.upper)
        c = self._client
        p.setJointMotorControlArray(
            self.arm.body,
            self.arm.joints,
            p.POSITION_CONTROL,
            targetPositions=targets.tolist(),
            forces=self.arm.max_force,
            physicsClientId=c,
        )
        for _ in range(self.physics_steps_per_control):
            p.stepSimulation(physicsClientId=c)
        self._canonicalize()
        distance = self.distance_to_target()
        success = bool(distance < SUCCESS_DISTANCE)
        return self._get_obs(), -distance, success, False, {"is_success": success}

    def render(self) -> np.ndarray:
        return self._camera(self.render_height, self.render_width)

    def _camera(self, height: int, width: int) -> np.ndarray:
        proj = self._proj
        if (height, width) != (self.height, self.width):
            proj = p.computeProjectionMatrixFOV(
                fov=50, aspect=width / height, nearVal=0.05, farVal=10.0, physicsClientId=self._client
            )
        _, _, rgba, _, _ = p.getCameraImage(
            width,
            height,
            viewMatrix=self._view,
            projectionMatrix=proj,
            renderer=p.ER_TINY_RENDERER,
            flags=p.ER_NO_SEGMENTATION_MASK,
            physicsClientId=self._client,
        )
        rgba = np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)
        return np.ascontiguousarray(rgba[..., :3])

    def close(self):
        if self._client is not None:
            p.disconnect(physicsClientId=self._client)
            self._client = None

    # --- exact state save / restore ---------------------------------------------------------------

    def get_state(self) -> np.ndarray:
        """``[q (7), q_dot (7), target xyz (3)]`` float64."""
        return np.concatenate([self._joints, self._target]).astype(np.float64)

    def reset_to(self, state) -> dict[str, np.ndarray]:
        """Restore a state from :meth:`get_state` and return its observation."""
        state = np.asarray(state, dtype=np.float64)
        if state.shape != (STATE_SIZE,):
            raise ValueError(
                f"ReachEnv.reset_to expects a state of shape ({STATE_SIZE},) [q (7), q_dot (7), target (3)], got {state.shape}."
            )
        self._restore(state)
        return self._get_obs()

    def end_effector_position(self) -> np.ndarray:
        """World position (m) of the end effector point."""
        return end_effector_position(self._client, self.arm)

    def distance_to_target(self) -> float:
        return float(np.linalg.norm(self.end_effector_position() - self._target))

    def _restore(self, state: np.ndarray) -> None:
        self._joints = state[: 2 * NUM_JOINTS].copy()
        self._target = state[2 * NUM_JOINTS :].copy()
        write_joints(self._client, self.arm, self._joints)
        forget_contacts(self._client, self.arm, self._plane)
        x, y, z = self._target.tolist()
        p.resetBasePositionAndOrientation(self._ball, [x, y, z], [0, 0, 0, 1], physicsClientId=self._client)
        p.resetBasePositionAndOrientation(self._disc, [x, y, 0.001], [0, 0, 0, 1], physicsClientId=self._client)

    def _canonicalize(self) -> None:
        """Put pybullet in exactly the state ``reset_to`` of the recorded numbers produces.

        Read the joint state and write it back, and drop the arm-ground contact points pybullet
        keeps across steps (with their warm-start impulses), at every control step boundary.
        """
        self._joints = read_joints(self._client, self.arm)
        write_joints(self._client, self.arm, self._joints)
        forget_contacts(self._client, self.arm, self._plane)

    # --- helpers ----------------------------------------------------------------------------------

    def _get_obs(self) -> dict[str, np.ndarray]:
        obs = {"agent_pos": np.clip(self._joints, self._obs_low, self._obs_high).astype(np.float32)}
        if self.obs_type == "pixels_agent_pos":
            obs["pixels"] = self._camera(self.height, self.width)
        else:
            obs["environment_state"] = np.clip(self._target, WORKSPACE_LOW, WORKSPACE_HIGH).astype(np.float32)
        return obs

    def _get_info(self) -> dict[str, Any]:
        return {"is_success": bool(self.distance_to_target() < SUCCESS_DISTANCE)}
