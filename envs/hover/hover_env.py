"""Quadrotor hover: fly a Crazyflie-like quadrotor to a point 1 m above the ground and stay there.

Laid out like gym-pybullet-drones' ``HoverAviary`` (kinematic observation with an action buffer,
RPM actions around the hover RPM, the same reward and truncation), on pybullet directly (DIRECT
mode, headless) with this repo's own URDF (``assets/quadrotor_x.urdf``).

* **Drone** Crazyflie 2.x-like, "X" configuration: mass 0.027 kg, arm 0.0397 m,
  kf = 3.16e-10 N/rpm^2, km = 7.94e-12 N m/rpm^2, thrust-to-weight 2.25,
  inertia ixx = iyy = 1.4e-5, izz = 2.17e-5 kg m^2; gravity 9.8 m/s^2. Hover RPM ~ 14468.
  Motor forces and the yaw drag torque are applied per motor at every physics step (see
  ``quadrotor.py``). Physics runs at 240 Hz, control at ``fps`` (which must divide 240).
* **Action** ``act_type="one_d_rpm"``: ``(1,)``, the same command for all four motors;
  ``act_type="rpm"``: ``(4,)``, one per motor. Each ``a`` in ``[-1, 1]`` (clipped) sets
  ``RPM = HOVER_RPM * (1 + 0.05 * a)``, i.e. thrust between 90% and 110% of the weight.
* **Observation** ``agent_pos``: 12 kinematic values - position xyz (m), roll/pitch/yaw (rad),
  linear velocity (m/s), angular velocity (rad/s), all in the world frame - followed by the last
  ``fps // 2`` actions (oldest first, zeros at the start of an episode), so the shape is
  ``(12 + (fps // 2) * A,)`` float32. Values are clipped to the observation space: position to
  +-10 m, velocity to +-20 m/s, angular velocity to +-100 rad/s (never reached before truncation).
* **Target** ``(0, 0, 1)`` (a small green sphere in the picture, visual only).
* **Reward** ``max(0, 2 - ||target - position||^4)`` per step (HoverAviary's): 2 at the target,
  0 beyond ~1.19 m.
* **Termination** never. **Truncation** (as HoverAviary) when ``|x| > 1.5`` or ``|y| > 1.5`` or
  ``z > 2`` m (out of bounds), or ``|roll| > 0.4`` or ``|pitch| > 0.4`` rad (tilted too far).
  The time limit (8 s = 240 steps at 30 fps) is added by hub-envs from the config's
  ``episode_length``.
* **Success** ``info["is_success"]`` is True when the drone *hovers at the target*: within 0.05 m
  of it **and** slower than 0.1 m/s (flying through the target does not count; random actions
  manage it in about 5% of one_d_rpm episodes).
* **Start** level, at rest, at ``x, y ~ U(-0.025, 0.025)`` m and ``z ~ U(0.1, 0.2)`` m, i.e. just
  above the ground plane and nearly under the target, so that ``one_d_rpm`` (which cannot move
  sideways) can still succeed. The drone can land on the ground and take off again.
* **Rendering** ``render()``: an RGB frame from a pybullet camera (ER_TINY_RENDERER),
  ``(render_height, render_width, 3)`` uint8. The front rotors are red, the back ones blue.
  ``render_camera`` sets it the way pybullet's debug camera is set (``resetDebugVisualizerCamera``):
  ``{"target": [x, y, z] or "drone", "distance": m, "yaw": deg, "pitch": deg}``, any subset of
  :data:`DEFAULT_CAMERA`, which looks at the whole flight volume (the ground up to above the target).
  ``"target": "drone"`` follows the drone (the card's GIF does: ``[tool.hub-envs.media]`` in
  pyproject.toml), so it stays framed wherever it flies. The camera changes the picture only:
  observations, rewards and states do not depend on it.
* **State** ``get_state()`` = ``[position(3), quaternion xyzw(4), linear velocity(3),
  angular velocity(3), action buffer (fps//2 * A)]`` float64. ``reset_to(state)`` restores it
  exactly: after every control step the env reads the body state and writes it back, so the
  pybullet state at each step boundary is a function of the recorded numbers alone (pybullet
  renormalises quaternions on write); this makes a restored continuation bit-identical to the
  original one, in the air and on the ground. The same happens to the ground contact points
  pybullet keeps between steps: they are dropped at every control step (and on restore), so
  contact is re-detected from the poses alone (a drone resting on the ground keeps a residual
  jitter below 1e-3 m/s and 1e-2 rad/s).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping, Sequence
from numbers import Real
from typing import Any

import gymnasium as gym
import numpy as np
import pybullet as p
import pybullet_data
from gymnasium import spaces

from .quadrotor import (
    BODY_STATE_SIZE,
    GRAVITY_ACCEL,
    URDF_PATH,
    apply_motor_forces,
    forget_contacts,
    load_params,
    read_body_state,
    write_body_state,
)

ACT_TYPES = {"one_d_rpm": 1, "rpm": 4}  # act_type -> action size A
PYB_FREQ = 240  # physics steps per second
KIN_DIM = 12  # position, roll/pitch/yaw, linear velocity, angular velocity
RPM_SPAN = 0.05  # RPM = HOVER_RPM * (1 + RPM_SPAN * a)
TARGET_POS = np.array([0.0, 0.0, 1.0])
SUCCESS_RADIUS = 0.05  # m
SUCCESS_MAX_SPEED = 0.1  # m/s
XY_LIMIT, Z_LIMIT, TILT_LIMIT = 1.5, 2.0, 0.4  # truncation bounds (m, m, rad)
POS_BOUND, VEL_BOUND, ANG_VEL_BOUND = 10.0, 20.0, 100.0  # observation clipping
START_XY, START_Z = 0.025, (0.1, 0.2)  # |x|, |y| <= 0.025 keeps the target reachable with one_d_rpm
#: render()'s camera, pybullet's debug-camera terms: it looks at ``target`` ("drone": the drone's position, followed)
#: from ``distance`` m, turned ``yaw`` degrees about z (0: from -y, 90: from +x) and ``pitch`` degrees (< 0: from above).
#: The default frames the flight volume, the ground to above the target at (0, 0, 1).
DEFAULT_CAMERA = {"target": (0.0, 0.0, 0.58), "distance": 1.5, "yaw": 61.4, "pitch": -6.0}
CAMERA_FOV = 45.0  # degrees, vertical


def check_act_type(act_type: str) -> int:
    """The action size for ``act_type``, or a ValueError naming the field and the allowed values."""
    if act_type not in ACT_TYPES:
        raise ValueError(f"act_type={act_type!r} is not supported; use one of {list(ACT_TYPES)}.")
    return ACT_TYPES[act_type]


def check_fps(fps: int) -> int:
    """The number of physics steps per control step, or a ValueError if fps does not divide 240."""
    if not isinstance(fps, (int, np.integer)) or fps < 2 or PYB_FREQ % fps:
        divisors = [f for f in range(2, PYB_FREQ + 1) if PYB_FREQ % f == 0]
        raise ValueError(f"fps={fps!r} is not supported: the physics runs at {PYB_FREQ} Hz, so fps must be one of {divisors}.")
    return PYB_FREQ // int(fps)


def check_camera(camera: Mapping[str, Any] | None) -> dict[str, Any]:
    """:data:`DEFAULT_CAMERA` with ``camera``'s entries, or a ValueError naming the entry and what it takes."""
    if camera is None:
        return dict(DEFAULT_CAMERA)
    if not isinstance(camera, Mapping):
        raise ValueError(f"render_camera={camera!r} must be a dict with some of {sorted(DEFAULT_CAMERA)}, e.g. {DEFAULT_CAMERA}.")
    unknown = sorted(set(camera) - set(DEFAULT_CAMERA))
    if unknown:
        raise ValueError(f"render_camera has unknown entries {unknown}; it takes {sorted(DEFAULT_CAMERA)}.")
    out = {**DEFAULT_CAMERA, **camera}

    def number(v: Any) -> bool:
        return isinstance(v, Real) and not isinstance(v, bool) and bool(np.isfinite(v))

    target = out["target"]
    if isinstance(target, str) and target == "drone":
        pass
    elif isinstance(target, str) or not (isinstance(target, Sequence) and len(target) == 3 and all(map(number, target))):
        raise ValueError(f'render_camera target={target!r}: give "drone" (follow it) or a point [x, y, z] in metres.')
    else:
        out["target"] = tuple(float(v) for v in target)
    for key in ("distance", "yaw", "pitch"):
        if not number(out[key]):
            raise ValueError(f"render_camera {key}={out[key]!r} must be a number.")
    if out["distance"] <= 0:
        raise ValueError(f"render_camera distance={out['distance']!r} must be > 0 (metres from the target).")
    return out


def observation_size(act_type: str, fps: int) -> int:
    """Length of ``agent_pos``: 12 kinematic values plus ``fps // 2`` buffered actions."""
    return KIN_DIM + (int(fps) // 2) * check_act_type(act_type)


class HoverEnv(gym.Env):
    """Crazyflie-like quadrotor that should hover at (0, 0, 1); see the module docstring."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(
        self,
        act_type: str = "one_d_rpm",
        fps: int = 30,
        render_height: int = 128,
        render_width: int = 128,
        render_mode: str | None = "rgb_array",
        render_camera: Mapping[str, Any] | None = None,
    ):
        self.act_dim = check_act_type(act_type)
        self.camera = check_camera(render_camera)
        self.physics_steps_per_control = check_fps(fps)
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode={render_mode!r} is not supported; use 'rgb_array' (or None).")
        self.act_type, self.fps = act_type, int(fps)
        self.render_mode = render_mode
        self.render_height, self.render_width = int(render_height), int(render_width)
        self.metadata = {**type(self).metadata, "render_fps": self.fps}
        self.buffer_size = self.fps // 2

        self.params = load_params(URDF_PATH)
        self.hover_rpm = self.params.hover_rpm

        self._client = p.connect(p.DIRECT)
        c = self._client
        p.resetSimulation(physicsClientId=c)
        p.setPhysicsEngineParameter(fixedTimeStep=1.0 / PYB_FREQ, deterministicOverlappingPairs=1, physicsClientId=c)
        p.setGravity(0, 0, -GRAVITY_ACCEL, physicsClientId=c)
        self._plane = p.loadURDF(str(pybullet_data.getDataPath() + "/plane.urdf"), physicsClientId=c)
        self._drone = p.loadURDF(str(URDF_PATH), [0, 0, START_Z[0]], flags=p.URDF_USE_INERTIA_FROM_FILE, physicsClientId=c)
        marker = p.createVisualShape(p.GEOM_SPHERE, radius=0.02, rgbaColor=[0.1, 0.8, 0.2, 1.0], physicsClientId=c)
        p.createMultiBody(baseMass=0, baseVisualShapeIndex=marker, basePosition=TARGET_POS.tolist(), physicsClientId=c)
        self._proj = p.computeProjectionMatrixFOV(
            fov=CAMERA_FOV, aspect=self.render_width / self.render_height, nearVal=0.02, farVal=20.0, physicsClientId=c
        )

        lo_kin = np.array([-POS_BOUND] * 3 + [-np.pi] * 3 + [-VEL_BOUND] * 3 + [-ANG_VEL_BOUND] * 3)
        self._kin_low, self._kin_high = lo_kin, -lo_kin
        low = np.concatenate([lo_kin, -np.ones(self.buffer_size * self.act_dim)]).astype(np.float32)
        self.observation_space = spaces.Dict({"agent_pos": spaces.Box(low=low, high=-low, dtype=np.float32)})
        self.action_space = spaces.Box(low=-1.0, high=1.0, shape=(self.act_dim,), dtype=np.float32)

        self._body_state = np.zeros(BODY_STATE_SIZE)
        self._actions: deque[np.ndarray] = deque(maxlen=self.buffer_size)
        start = np.array([0, 0, START_Z[0], 0, 0, 0, 1, 0, 0, 0, 0, 0, 0], dtype=np.float64)
        self._restore(np.concatenate([start, np.zeros(self.buffer_size * self.act_dim)]))

    # --- gymnasium API ---------------------------------------------------------------------------

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        xy = self.np_random.uniform(-START_XY, START_XY, size=2)
        z = self.np_random.uniform(*START_Z)
        body = np.array([xy[0], xy[1], z, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0], dtype=np.float64)
        self._restore(np.concatenate([body, np.zeros(self.buffer_size * self.act_dim)]))
        return self._get_obs(), self._get_info()

    def step(self, action):
        a = np.clip(np.asarray(action, dtype=np.float64).reshape(self.act_dim), -1.0, 1.0)
        self._actions.append(a)
        rpm = self.hover_rpm * (1.0 + RPM_SPAN * a)
        if self.act_dim == 1:
            rpm = np.repeat(rpm, 4)
        c, body = self._client, self._drone
        for _ in range(self.physics_steps_per_control):
            apply_motor_forces(c, body, self.params, rpm)
            p.stepSimulation(physicsClientId=c)
        self._canonicalize()

        pos = self._body_state[0:3]
        roll, pitch, _ = p.getEulerFromQuaternion(self._body_state[3:7].tolist(), physicsClientId=c)
        distance = float(np.linalg.norm(TARGET_POS - pos))
        reward = max(0.0, 2.0 - distance**4)
        truncated = bool(
            abs(pos[0]) > XY_LIMIT
            or abs(pos[1]) > XY_LIMIT
            or pos[2] > Z_LIMIT
            or abs(roll) > TILT_LIMIT
            or abs(pitch) > TILT_LIMIT
        )
        return self._get_obs(), float(reward), False, truncated, self._get_info()

    def view_matrix(self) -> tuple[float, ...]:
        """The camera's view matrix now (pybullet's, column-major): it moves with the drone when it follows it."""
        cam = self.camera
        target = self._body_state[0:3].tolist() if cam["target"] == "drone" else list(cam["target"])
        return p.computeViewMatrixFromYawPitchRoll(
            cameraTargetPosition=target,
            distance=float(cam["distance"]),
            yaw=float(cam["yaw"]),
            pitch=float(cam["pitch"]),
            roll=0.0,
            upAxisIndex=2,
            physicsClientId=self._client,
        )

    def render(self) -> np.ndarray:
        _, _, rgba, _, _ = p.getCameraImage(
            self.render_width,
            self.render_height,
            viewMatrix=self.view_matrix(),
            projectionMatrix=self._proj,
            renderer=p.ER_TINY_RENDERER,
            flags=p.ER_NO_SEGMENTATION_MASK,
            physicsClientId=self._client,
        )
        rgba = np.asarray(rgba, dtype=np.uint8).reshape(self.render_height, self.render_width, 4)
        return np.ascontiguousarray(rgba[..., :3])

    def close(self):
        if self._client is not None:
            p.disconnect(physicsClientId=self._client)
            self._client = None

    # --- exact state save / restore ---------------------------------------------------------------

    def get_state(self) -> np.ndarray:
        """Body state (13) then the action buffer (``fps//2 * A``, oldest first), float64."""
        return np.concatenate([self._body_state, np.concatenate(list(self._actions))]).astype(np.float64)

    def reset_to(self, state) -> dict[str, np.ndarray]:
        """Restore a state from :meth:`get_state` and return its observation."""
        state = np.asarray(state, dtype=np.float64)
        size = BODY_STATE_SIZE + self.buffer_size * self.act_dim
        if state.shape != (size,):
            raise ValueError(
                f"HoverEnv.reset_to expects a state of shape ({size},) for act_type={self.act_type!r}, fps={self.fps} "
                f"(13 body values + {self.buffer_size} x {self.act_dim} buffered actions), got {state.shape}."
            )
        self._restore(state)
        return self._get_obs()

    def _restore(self, state: np.ndarray) -> None:
        body = state[:BODY_STATE_SIZE].copy()
        write_body_state(self._client, self._drone, body)
        forget_contacts(self._client, self._drone, self._plane)
        self._body_state = body
        self._actions.clear()
        for a in state[BODY_STATE_SIZE:].reshape(self.buffer_size, self.act_dim):
            self._actions.append(a.copy())

    def _canonicalize(self) -> None:
        """Bring pybullet into the state that ``reset_to`` of the recorded numbers produces.

        Read the body state, write it back (pybullet renormalises the quaternion on write, so the
        internal state after a write is a function of the numbers written) and drop the contact
        points with the ground (pybullet keeps them, with their impulses, across steps). Done here
        at every step, the original run is then in exactly the state a restore reaches.
        """
        self._body_state = read_body_state(self._client, self._drone)
        write_body_state(self._client, self._drone, self._body_state)
        forget_contacts(self._client, self._drone, self._plane)

    # --- helpers ----------------------------------------------------------------------------------

    def _get_obs(self) -> dict[str, np.ndarray]:
        s = self._body_state
        rpy = p.getEulerFromQuaternion(s[3:7].tolist(), physicsClientId=self._client)
        kin = np.clip(np.concatenate([s[0:3], rpy, s[7:10], s[10:13]]), self._kin_low, self._kin_high)
        return {"agent_pos": np.concatenate([kin, *self._actions]).astype(np.float32)}

    def _get_info(self) -> dict[str, Any]:
        s = self._body_state
        near = np.linalg.norm(TARGET_POS - s[0:3]) < SUCCESS_RADIUS
        return {"is_success": bool(near and np.linalg.norm(s[7:10]) < SUCCESS_MAX_SPEED)}
