"""The KUKA LBR iiwa 7 from pybullet_data: loading, joint state read/write, end effector, contacts."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pybullet as p
import pybullet_data

KUKA_URDF = "kuka_iiwa/model.urdf"
NUM_JOINTS = 7
EE_LINK = 6  # lbr_iiwa_link_7; the end effector point is the origin of its URDF frame


@dataclass(frozen=True)
class ArmModel:
    body: int
    joints: tuple[int, ...]
    lower: np.ndarray  # joint limits from the URDF (rad)
    upper: np.ndarray
    max_force: tuple[float, ...]  # URDF effort limits (N m)


def load_arm(client: int) -> ArmModel:
    body = p.loadURDF(
        pybullet_data.getDataPath() + "/" + KUKA_URDF, basePosition=[0, 0, 0], useFixedBase=True, physicsClientId=client
    )
    joints = tuple(range(NUM_JOINTS))
    infos = [p.getJointInfo(body, j, physicsClientId=client) for j in joints]
    return ArmModel(
        body=body,
        joints=joints,
        lower=np.array([info[8] for info in infos]),
        upper=np.array([info[9] for info in infos]),
        max_force=tuple(float(info[10]) for info in infos),
    )


def read_joints(client: int, arm: ArmModel) -> np.ndarray:
    """``[q (7), q_dot (7)]`` float64."""
    states = p.getJointStates(arm.body, arm.joints, physicsClientId=client)
    return np.array([s[0] for s in states] + [s[1] for s in states], dtype=np.float64)


def write_joints(client: int, arm: ArmModel, qs: np.ndarray) -> None:
    """Set joint positions and velocities exactly (inverse of :func:`read_joints`)."""
    for i, j in enumerate(arm.joints):
        p.resetJointState(arm.body, j, float(qs[i]), float(qs[NUM_JOINTS + i]), physicsClientId=client)


def end_effector_position(client: int, arm: ArmModel) -> np.ndarray:
    state = p.getLinkState(arm.body, EE_LINK, computeForwardKinematics=True, physicsClientId=client)
    return np.array(state[4], dtype=np.float64)


def forget_contacts(client: int, arm: ArmModel, other: int) -> None:
    """Drop pybullet's persistent contact points (and warm-start impulses) between the arm and ``other``.

    Disabling and re-enabling collisions of a pair makes pybullet release its contact manifold; the
    next collision detection starts from the current poses alone, so no contact history survives a
    control step boundary that ``get_state`` could miss.
    """
    for link in arm.joints:
        p.setCollisionFilterPair(arm.body, other, link, -1, 0, physicsClientId=client)
        p.setCollisionFilterPair(arm.body, other, link, -1, 1, physicsClientId=client)
