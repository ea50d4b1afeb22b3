"""Door expert (latched door): grasp the lever horizontally, turn it down, pull the door open about its hinge.

Waypoints (ignore_collision label): 18 cm in front of the handle along the latch axis (0) -> the handle
(1) -> close (1) -> turn the lever down about the latch axis by 1.3 rad, an arc of small servo moves with one
keyframe at its end (1) -> pull the door open along an arc about the hinge axis until the hinge passes
0.35 rad, one keyframe at the end (1).

A top-down grasp makes the wrist links hit the door panel, so the hand approaches along the latch axis
(site z into the door) with the fingers closing vertically (robosuite_notes §3.4).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial.transform import Rotation

from sigma_data.control import grip_site_pose, mat_to_quat, rotation_error
from sigma_data.experts.base import EpisodeRecorder, ExpertFailure, WaypointArm
from sigma_data.tasks.door import hinge_angle

if TYPE_CHECKING:
    from sigma_data.tasks.registry import Variation

STANDOFF = 0.18
LEVER_TURN = 1.3  # rad about the latch axis (the latch releases beyond ~1.0)
LEVER_STEPS = 9
PULL_ANGLE = 0.45  # rad about the hinge axis (success beyond 0.3; the hinge stops at 0.4)
PULL_STEPS = 10
OPEN_TARGET = 0.35


def _joint_frame(env, name: str) -> tuple[np.ndarray, np.ndarray]:
    jid = env.sim.model.joint_name2id(name)
    return np.array(env.sim.data.xanchor[jid]), np.array(env.sim.data.xaxis[jid])


def door_expert(recorder: EpisodeRecorder, variation: Variation, rng: np.random.Generator) -> None:
    env = recorder.env
    arm = WaypointArm(recorder, fail_pos_tol=0.03, fail_rot_tol=0.3)
    hinge_name, latch_name = env.door.joints[0], env.door.joints[1]
    latch_anchor, latch_axis = _joint_frame(env, latch_name)
    handle = np.array(env.sim.data.site_xpos[env.door_handle_site_id])

    # Site z (approach) along the latch axis, into the door; site x (finger closing) vertical.
    approach = latch_axis / np.linalg.norm(latch_axis)
    x_axis = np.array([0.0, 0.0, 1.0])
    x_axis = x_axis - approach * (x_axis @ approach)
    x_axis /= np.linalg.norm(x_axis)
    # Of the two vertical finger orientations, take the one nearer the current hand orientation.
    _, current = grip_site_pose(env)
    rot0 = min(
        (np.column_stack([sx, np.cross(approach, sx), approach]) for sx in (x_axis, -x_axis)),
        key=lambda r: rotation_error(r, current),
    )
    quat = mat_to_quat(rot0)

    # Turn the hand first, away from the door (no keyframe), then approach the handle head-on.
    start, _ = grip_site_pose(env)
    arm.move("orient", start, quat, ignore_collision=False, keyframe=False, allow_stall=True, pos_tol=0.05)
    arm.move("approach", handle - STANDOFF * approach, quat, ignore_collision=False)
    arm.move("grasp", handle, quat, ignore_collision=True, allow_stall=True, pos_tol=0.03)
    arm.grip(open=False)

    # Turn the lever so that the handle goes down.
    lever = handle - latch_anchor
    sign = -1.0 if np.cross(approach, lever)[2] > 0 else 1.0
    for k in range(1, LEVER_STEPS + 1):
        turn = Rotation.from_rotvec(sign * approach * LEVER_TURN * k / LEVER_STEPS)
        pos = latch_anchor + turn.apply(lever)
        arm.move(
            "turn_lever",
            pos,
            mat_to_quat(turn.as_matrix() @ rot0),
            ignore_collision=True,
            keyframe=k == LEVER_STEPS,
            allow_stall=True,
            pos_tol=0.05,
            max_steps=30,
        )

    hinge_anchor, hinge_axis = _joint_frame(env, hinge_name)
    start_pos, start_rot = grip_site_pose(env)
    for k in range(1, PULL_STEPS + 1):
        swing = Rotation.from_rotvec(hinge_axis * PULL_ANGLE * k / PULL_STEPS)
        pos = hinge_anchor + swing.apply(start_pos - hinge_anchor)
        last = k == PULL_STEPS or hinge_angle(env) > OPEN_TARGET
        arm.move(
            "pull",
            pos,
            mat_to_quat(swing.as_matrix() @ start_rot),
            ignore_collision=True,
            keyframe=last,
            allow_stall=True,
            pos_tol=0.06,
            max_steps=30,
        )
        if last:
            break
    if hinge_angle(env) <= OPEN_TARGET - 0.05:
        raise ExpertFailure(f"door opened only {hinge_angle(env):.2f} rad")
