"""Poses in robosuite's world: the quaternion and yaw conventions, and what the simulator says about the arm.

Every pose here is the **grip site** (``env.robots[0].eef_site_id["right"]``) or a MuJoCo body in the world
frame, metres; quaternions are xyzw with w >= 0 (robosuite / scipy order, *not* MuJoCo's wxyz). A *top-down*
orientation points the approach axis (site z) down, and its *yaw* turns the finger closing axis (site x) about
world z: at yaw 0 the fingers close along world y (:data:`R_DOWN`). The scripted experts plan in these terms,
the motion primitives (``sigma_data/control.py``) servo in them and the evaluation reads grasps with them.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from sigma_data.episode import canonical_quat

# Top-down grasp orientation: site x (finger closing axis) = world +y, site z (approach) = world -z.
R_DOWN = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])

__all__ = [
    "R_DOWN",
    "arm_joint_speed",
    "base_rotation",
    "body_pose",
    "closest_symmetric_yaw",
    "grip_site_frame",
    "grip_site_pose",
    "gripper_width",
    "mat_to_quat",
    "quat_to_mat",
    "rotation_error",
    "site_yaw",
    "top_down_quat",
    "wrap_angle",
    "yaw_rotation",
]


def mat_to_quat(rot: np.ndarray) -> np.ndarray:
    """3x3 rotation matrix -> canonical xyzw quaternion (w >= 0)."""
    return canonical_quat(Rotation.from_matrix(rot).as_quat())


def quat_to_mat(quat_xyzw: Sequence[float]) -> np.ndarray:
    """xyzw quaternion -> 3x3 rotation matrix."""
    return Rotation.from_quat(np.asarray(quat_xyzw, dtype=np.float64)).as_matrix()


def yaw_rotation(yaw: float) -> np.ndarray:
    """Rotation by ``yaw`` radians about world +z (3x3)."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def top_down_quat(yaw: float) -> np.ndarray:
    """Grip-site quaternion (xyzw) pointing down with the top-down frame rotated by ``yaw`` about world z.

    At ``yaw = 0`` the fingers close along world y; the closing axis is ``(-sin yaw, cos yaw, 0)``.
    """
    return mat_to_quat(yaw_rotation(yaw) @ R_DOWN)


def site_yaw(rot: np.ndarray) -> float:
    """Yaw (rad) of a roughly top-down grip-site rotation, the inverse of :func:`top_down_quat`."""
    x_axis = rot[:, 0]
    return float(np.arctan2(-x_axis[0], x_axis[1]))


def object_yaw(rot: np.ndarray) -> float:
    """Yaw (rad) of a body's x axis in the world xy plane."""
    return float(np.arctan2(rot[1, 0], rot[0, 0]))


def wrap_angle(angle: float) -> float:
    """Wrap an angle to [-pi, pi)."""
    return float((angle + np.pi) % (2 * np.pi) - np.pi)


def closest_symmetric_yaw(object_yaw: float, reference_yaw: float, period: float) -> float:
    """The yaw ``object_yaw + k * period`` closest to ``reference_yaw`` (radians)."""
    k = np.round((reference_yaw - object_yaw) / period)
    return float(object_yaw + k * period)


def grip_site_frame(env: Any) -> tuple[np.ndarray, np.ndarray]:
    """World pose of the grip site as position (3,) metres and rotation matrix (3, 3).

    The servo works with rotation matrices; :func:`grip_site_pose` gives the same pose as position and xyzw
    quaternion.
    """
    site_id = env.robots[0].eef_site_id["right"]
    pos = np.array(env.sim.data.site_xpos[site_id], dtype=np.float64)
    rot = np.array(env.sim.data.site_xmat[site_id], dtype=np.float64).reshape(3, 3)
    return pos, rot


def grip_site_pose(env: Any) -> tuple[np.ndarray, np.ndarray]:
    """World position (3,) and xyzw quaternion (4,, w >= 0) of the robot's grip site (the OSC reference): the
    pose the recorder stores as ``observation.state``'s first 7 numbers."""
    pos, rot = grip_site_frame(env)
    return pos, mat_to_quat(rot)


def body_pose(env: Any, body_name: str) -> tuple[np.ndarray, np.ndarray]:
    """World pose of a MuJoCo body by name: position (3,) and rotation matrix (3, 3)."""
    body_id = env.sim.model.body_name2id(body_name)
    pos = np.array(env.sim.data.body_xpos[body_id], dtype=np.float64)
    rot = np.array(env.sim.data.body_xmat[body_id], dtype=np.float64).reshape(3, 3)
    return pos, rot


def base_rotation(env: Any) -> np.ndarray:
    """Rotation of the robot base (the OSC input frame) in the world."""
    return body_pose(env, env.robots[0].robot_model.root_body)[1]


def arm_joint_speed(env: Any) -> float:
    """Largest absolute arm joint velocity (rad/s)."""
    return float(np.max(np.abs(env.sim.data.qvel[env.robots[0]._ref_joint_vel_indexes])))


def gripper_width(env: Any) -> float:
    """Finger opening in metres (``q1 - q2``; Panda: 0.078 fully open, ~0.0 closed empty)."""
    q = env.sim.data.qpos[env.robots[0]._ref_gripper_joint_pos_indexes["right"]]
    return float(q[0] - q[1])


def rotation_error(rot_a: np.ndarray, rot_b: np.ndarray) -> float:
    """Geodesic angle (rad) between two rotation matrices."""
    return float(np.linalg.norm(Rotation.from_matrix(rot_a @ rot_b.T).as_rotvec()))
