"""Low-level motion primitives on robosuite's default OSC_POSE (delta) controller.

One set of primitives serves the scripted experts, keyframe replay and closed-loop evaluation:

* :func:`move_to` -- the servo primitive: a velocity-limited reference pose walks toward the target
  (straight line, geodesic rotation) and each control step sends the delta that drives the grip site to
  the reference. Stops when converged, stalled or out of budget.
* :func:`actuate_gripper` -- hold the current pose and command the gripper until the fingers have moved
  and come to rest.
* :func:`hold` -- hold the current pose for a number of control steps.

``sigma_data/keyframe_executor.py`` builds the 9-D keyframe executor from them, and ``sigma_data/poses.py``
holds the pose conventions and simulator queries they use.

Conventions
-----------
* Poses are the **grip site** in the world frame, metres; quaternions are xyzw with w >= 0
  (``sigma_data/poses.py``).
* Actions are robosuite's 7-D OSC_POSE delta ``[dx, dy, dz, rx, ry, rz, grip]`` in ``[-1, 1]``, expressed
  in the robot base frame; one unit is 5 cm / 0.5 rad per control step. ``grip`` is +1 close, -1 open.
* Everything drives the simulator through a *driver*: any object with ``env`` and ``step(action)``
  (the collection pipeline's ``EpisodeRecorder``, or :class:`EnvDriver` here).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any, Protocol

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from sigma_data.poses import (
    arm_joint_speed,
    base_rotation,
    grip_site_frame,
    grip_site_pose,
    gripper_width,
    quat_to_mat,
    rotation_error,
)

# OSC_POSE delta scale of the default BASIC composite controller (output_max for input 1).
POS_SCALE = 0.05  # metres per unit action per control step
ROT_SCALE = 0.5  # radians per unit action per control step

GRIP_OPEN = -1.0
GRIP_CLOSE = 1.0

__all__ = [
    "GRIP_CLOSE",
    "GRIP_OPEN",
    "POS_SCALE",
    "ROT_SCALE",
    "Driver",
    "EnvDriver",
    "GripperConfig",
    "MoveResult",
    "MoveStatus",
    "ServoConfig",
    "actuate_gripper",
    "hold",
    "move_to",
    "servo_action",
]


class Driver(Protocol):
    """What the primitives need: the env and a way to execute (and possibly record) one control step."""

    env: Any

    def step(self, action: np.ndarray) -> None: ...


# --------------------------------------------------------------------------------------------------
# The servo action
# --------------------------------------------------------------------------------------------------


def servo_action(env: Any, ref_pos: np.ndarray, ref_rot: np.ndarray, grip: float) -> np.ndarray:
    """One OSC_POSE delta action (7,) driving the grip site toward the reference pose.

    Errors are computed in the world frame and rotated into the robot base frame, then scaled to the
    controller's unit action and clipped to [-1, 1].
    """
    pos, rot = grip_site_frame(env)
    base_rot_t = base_rotation(env).T
    dpos = base_rot_t @ (ref_pos - pos) / POS_SCALE
    drot = base_rot_t @ Rotation.from_matrix(ref_rot @ rot.T).as_rotvec() / ROT_SCALE
    action = np.zeros(7)
    action[:3] = np.clip(dpos, -1.0, 1.0)
    action[3:6] = np.clip(drot, -1.0, 1.0)
    action[6] = grip
    return action


# --------------------------------------------------------------------------------------------------
# Primitives
# --------------------------------------------------------------------------------------------------


class MoveStatus(StrEnum):
    CONVERGED = "converged"
    STALLED = "stalled"
    BUDGET = "budget"


@dataclass(frozen=True)
class MoveResult:
    """Outcome of :func:`move_to`: why it stopped, control steps used and the final pose errors."""

    status: MoveStatus
    steps: int
    pos_error: float  # metres
    rot_error: float  # radians


@dataclass(frozen=True)
class ServoConfig:
    """Servo primitive parameters (docs/robosuite.md §4.2). Units: metres, radians, control steps."""

    max_lin_step: float = 0.015  # reference speed limit, m per control step
    max_ang_step: float = 0.15  # reference speed limit, rad per control step
    pos_tol: float = 0.004
    rot_tol: float = 0.04
    joint_speed_tol: float = 0.05  # rad/s; "settled" when every arm joint is slower
    stall_steps: int = 6  # reference arrived and the site moved < stall_motion for this many steps
    stall_motion: float = 0.0005  # m per control step
    stall_rotation: float = 0.003  # rad per control step
    max_steps: int = 120


def _validate_grip(grip: float) -> float:
    if grip not in (GRIP_OPEN, GRIP_CLOSE):
        raise ValueError(f"grip must be {GRIP_OPEN} (open) or {GRIP_CLOSE} (close), got {grip!r}")
    return float(grip)


def move_to(
    driver: Driver,
    pos: Sequence[float],
    quat_xyzw: Sequence[float],
    grip: float,
    config: ServoConfig = ServoConfig(),
    max_steps: int | None = None,
) -> MoveResult:
    """Servo the grip site to a world pose while holding the gripper command ``grip`` (+1 close, -1 open).

    A reference pose moves toward the target at <= ``max_lin_step`` / ``max_ang_step`` per control step;
    each step sends :func:`servo_action` toward the reference. Stops when the pose is within tolerance with
    the joints settled (``CONVERGED``), when the reference has arrived but the site stopped moving and turning
    (``STALLED``: contact, joint limits, sag), or after ``max_steps`` steps (``BUDGET``).
    """
    grip = _validate_grip(grip)
    budget = config.max_steps if max_steps is None else max_steps
    env = driver.env
    target_pos = np.asarray(pos, dtype=np.float64)
    target_rot = quat_to_mat(quat_xyzw)
    ref_pos, ref_rot = grip_site_frame(env)

    # Geodesic interpolation between the start and target orientations, walked at a bounded rate.
    total_angle = rotation_error(target_rot, ref_rot)
    slerp = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([ref_rot, target_rot])))
    ang_frac = 0.0

    still_steps = 0
    prev_pos, prev_rot = ref_pos.copy(), ref_rot.copy()
    steps = 0
    status = MoveStatus.BUDGET
    while steps < budget:
        delta = target_pos - ref_pos
        dist = float(np.linalg.norm(delta))
        ref_pos = (
            target_pos.copy()
            if dist <= config.max_lin_step
            else ref_pos + delta * (config.max_lin_step / dist)
        )
        if total_angle > 1e-9:
            ang_frac = min(1.0, ang_frac + config.max_ang_step / total_angle)
        ref_rot = slerp([ang_frac]).as_matrix()[0] if total_angle > 1e-9 else target_rot

        driver.step(servo_action(env, ref_pos, ref_rot, grip))
        steps += 1

        cur_pos, cur_rot = grip_site_frame(env)
        pos_err = float(np.linalg.norm(target_pos - cur_pos))
        rot_err = rotation_error(target_rot, cur_rot)
        if (
            pos_err < config.pos_tol
            and rot_err < config.rot_tol
            and arm_joint_speed(env) < config.joint_speed_tol
        ):
            status = MoveStatus.CONVERGED
            break
        ref_arrived = dist <= config.max_lin_step and ang_frac >= 1.0
        still = (
            float(np.linalg.norm(cur_pos - prev_pos)) < config.stall_motion
            and rotation_error(cur_rot, prev_rot) < config.stall_rotation
        )
        prev_pos, prev_rot = cur_pos, cur_rot
        still_steps = still_steps + 1 if (ref_arrived and still) else 0
        if still_steps >= config.stall_steps:
            status = MoveStatus.STALLED
            break

    cur_pos, cur_rot = grip_site_frame(env)
    return MoveResult(
        status=status,
        steps=steps,
        pos_error=float(np.linalg.norm(target_pos - cur_pos)),
        rot_error=rotation_error(target_rot, cur_rot),
    )


@dataclass(frozen=True)
class GripperConfig:
    """Gripper primitive parameters. Units: metres of finger opening, control steps."""

    moved_width: float = 0.002  # the fingers count as having moved after this change in opening
    settled_width_step: float = 0.0005  # "at rest" when the opening changes less than this per step
    settled_steps: int = 2
    idle_steps: int = 6  # give up waiting for motion (already open / already clamped) after this
    max_steps: int = 25


def actuate_gripper(driver: Driver, open: bool, config: GripperConfig = GripperConfig()) -> int:
    """Hold the current grip-site pose and command the gripper open (``True``) or closed (``False``).

    Runs until the fingers have moved and come to rest (the fingers need 1-3 steps to start moving, so
    "slow" alone would stop too early), or until they stayed still for ``idle_steps`` (nothing to do:
    already open, or clamped on an object). Returns the number of control steps taken.
    """
    env = driver.env
    grip = GRIP_OPEN if open else GRIP_CLOSE
    hold_pos, hold_rot = grip_site_frame(env)
    width0 = prev = gripper_width(env)
    moved = False
    rest = 0
    for steps in range(1, config.max_steps + 1):
        driver.step(servo_action(env, hold_pos, hold_rot, grip))
        width = gripper_width(env)
        moved = moved or abs(width - width0) > config.moved_width
        rest = rest + 1 if abs(width - prev) < config.settled_width_step else 0
        prev = width
        if rest >= config.settled_steps and (moved or steps >= config.idle_steps):
            return steps
    return config.max_steps


def hold(driver: Driver, steps: int, grip: float) -> None:
    """Hold the current grip-site pose for ``steps`` control steps with gripper command ``grip``."""
    grip = _validate_grip(grip)
    hold_pos, hold_rot = grip_site_frame(driver.env)
    for _ in range(steps):
        driver.step(servo_action(driver.env, hold_pos, hold_rot, grip))


# --------------------------------------------------------------------------------------------------
# A driver that executes without recording states (closed-loop eval, benchmarks)
# --------------------------------------------------------------------------------------------------


@dataclass
class EnvDriver:
    """Executes actions on a robosuite env and keeps what a keyframe replay needs, but no states.

    Implements the ``EpisodeRecorder`` protocol of ``sigma_data.record`` minus state recording:
    ``keyframes`` holds, per :meth:`mark_keyframe`, the 9-D keyframe ``[x, y, z, qx, qy, qz, qw,
    gripper_open, ignore_collision]`` of the grip site after the last step, and ``keyframe_steps`` the
    0-based index of that step.
    """

    env: Any
    actions: list[np.ndarray] = field(default_factory=list)
    keyframes: list[np.ndarray] = field(default_factory=list)
    keyframe_steps: list[int] = field(default_factory=list)

    def step(self, action: np.ndarray) -> None:
        action = np.asarray(action, dtype=np.float64)
        self.env.step(action)
        self.actions.append(action)

    def mark_keyframe(self, gripper_open: bool, ignore_collision: bool) -> None:
        if not self.actions:
            raise RuntimeError("mark_keyframe() called before any step()")
        self.env.sim.forward()  # site poses lag qpos by one substep after env.step
        pos, quat = grip_site_pose(self.env)
        self.keyframes.append(np.concatenate([pos, quat, [float(gripper_open), float(ignore_collision)]]))
        self.keyframe_steps.append(len(self.actions) - 1)

    @property
    def num_steps(self) -> int:
        return len(self.actions)
