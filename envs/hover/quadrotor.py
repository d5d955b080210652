"""The quadrotor model: constants read from the URDF, motor forces, and exact state read/write.

Physics is gym-pybullet-drones' ``Physics.PYB`` model (no drag, ground effect or downwash): each
motor ``i`` spinning at ``rpm_i`` pushes along the body z axis with ``kf * rpm_i^2`` newtons at its
rotor position, and the four drag torques ``km * rpm_i^2`` add up to a yaw torque
``-t0 + t1 - t2 + t3`` about the body z axis. Forces are applied to the base with positions given
in the body frame, which is equivalent to gym-pybullet-drones' forces on the (massless, fixed)
rotor links, but uses the base pose pybullet has just integrated rather than the links' cached
poses (these are stale right after a pose reset, which would make ``reset_to`` inexact).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pybullet as p

URDF_PATH = Path(__file__).parent / "assets" / "quadrotor_x.urdf"
GRAVITY_ACCEL = 9.8  # m/s^2, as gym-pybullet-drones
BODY_STATE_SIZE = 13  # position (3), quaternion xyzw (4), linear velocity (3), angular velocity (3)


@dataclass(frozen=True)
class QuadrotorParams:
    mass: float
    arm: float
    kf: float
    km: float
    thrust2weight: float
    prop_positions: tuple[tuple[float, float, float], ...]  # rotor positions in the body frame

    @property
    def weight(self) -> float:
        return self.mass * GRAVITY_ACCEL

    @property
    def hover_rpm(self) -> float:
        """RPM at which the four motors together exactly carry the weight."""
        return math.sqrt(self.weight / (4 * self.kf))

    @property
    def max_rpm(self) -> float:
        return math.sqrt(self.thrust2weight * self.weight / (4 * self.kf))


def load_params(urdf_path: Path = URDF_PATH) -> QuadrotorParams:
    """Read mass and the motor constants (the non-URDF ``<properties>`` tag) from the URDF."""
    root = ET.parse(urdf_path).getroot()
    props = root.find("properties").attrib
    mass = float(root.find("link[@name='base_link']/inertial/mass").attrib["value"])
    positions = []
    for i in range(4):
        joint = root.find(f"joint[@name='prop{i}_joint']/origin")
        positions.append(tuple(float(v) for v in joint.attrib["xyz"].split()))
    return QuadrotorParams(
        mass=mass,
        arm=float(props["arm"]),
        kf=float(props["kf"]),
        km=float(props["km"]),
        thrust2weight=float(props["thrust2weight"]),
        prop_positions=tuple(positions),
    )


def apply_motor_forces(client: int, body: int, params: QuadrotorParams, rpm: np.ndarray) -> None:
    """Per-motor thrust and the total drag (yaw) torque, for one physics step (pybullet clears them)."""
    rpm_sq = np.asarray(rpm, dtype=np.float64) ** 2
    forces = (rpm_sq * params.kf).tolist()
    drag = rpm_sq * params.km
    z_torque = float(-drag[0] + drag[1] - drag[2] + drag[3])
    for i in range(4):
        p.applyExternalForce(
            body, -1, forceObj=(0.0, 0.0, forces[i]), posObj=params.prop_positions[i], flags=p.LINK_FRAME, physicsClientId=client
        )
    p.applyExternalTorque(body, -1, torqueObj=(0.0, 0.0, z_torque), flags=p.LINK_FRAME, physicsClientId=client)


def read_body_state(client: int, body: int) -> np.ndarray:
    """``[pos(3), quat xyzw(4), lin vel(3), ang vel(3)]`` in the world frame, float64."""
    pos, quat = p.getBasePositionAndOrientation(body, physicsClientId=client)
    lin, ang = p.getBaseVelocity(body, physicsClientId=client)
    return np.array([*pos, *quat, *lin, *ang], dtype=np.float64)


def forget_contacts(client: int, body_a: int, body_b: int) -> None:
    """Drop pybullet's persistent contact points (and their warm-start impulses) between two bodies.

    Disabling and re-enabling collisions of the pair makes pybullet release their contact
    manifold; the next collision detection starts from the current poses alone. Done at every
    control step boundary, this leaves no contact history behind that ``get_state`` could miss.
    """
    p.setCollisionFilterPair(body_a, body_b, -1, -1, 0, physicsClientId=client)
    p.setCollisionFilterPair(body_a, body_b, -1, -1, 1, physicsClientId=client)


def write_body_state(client: int, body: int, state: np.ndarray) -> None:
    """Inverse of :func:`read_body_state` (pybullet renormalises the quaternion; see HoverEnv)."""
    s = [float(v) for v in state]
    p.resetBasePositionAndOrientation(body, s[0:3], s[3:7], physicsClientId=client)
    p.resetBaseVelocity(body, s[7:10], s[10:13], physicsClientId=client)
