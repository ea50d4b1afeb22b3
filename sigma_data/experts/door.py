"""Door expert (latched door): grasp the lever horizontally, turn it down, pull the door open about its hinge.

Waypoints (ignore_collision label): turn the top-down hand a quarter turn about the vertical, in place (0) ->
tilt the hand horizontal, site z along the latch axis into the door, in place (0) -> 18 cm in front of the
handle (0) -> the handle (1) -> close (1) -> turn the lever down about the latch axis by 1.45 rad, an arc of
small servo moves with a keyframe every third move (1) -> pull the door open along an arc about the hinge
axis until the hinge passes 0.35 rad, a keyframe every third move and at the end (1).

A top-down grasp makes the wrist links hit the door panel, so the hand approaches along the latch axis with
the fingers closing vertically (docs/robosuite.md §6). Turning the lever turns the hand about its approach
axis, i.e. mostly the wrist joint 7 (range +-2.9 rad): the latch tip clears the frame only beyond ~1.25 rad of
lever turn, and from the wrist angle the direct reorientation gives (~2.1 rad) the turn runs into the joint
limit at ~1.2 rad (the door then sticks at ~0.12 rad). So the fingers grasp with site x pointing *up*, which
the wrist reaches at ~-1.1 rad when the hand first turns a quarter turn about the vertical (joint 7 goes
opposite to the site yaw); the full lever turn then ends near +0.4 rad. Both reorientations are keyframes, so
a keyframe replay takes the same wrist path.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial.transform import Rotation

from sigma_data.experts.base import EpisodeRecorder, ExpertFailure, WaypointArm
from sigma_data.poses import grip_site_frame, mat_to_quat, site_yaw, top_down_quat
from sigma_data.tasks.door import hinge_angle

if TYPE_CHECKING:
    from sigma_data.tasks.spec import Variation

STANDOFF = 0.18  # m in front of the handle along the latch axis
WRIST_PRE_TURN = np.pi / 2  # rad of site yaw before tilting the hand: joint 7 moves by about minus this
LEVER_TURN = 1.45  # rad about the latch axis (the latch tip clears the frame only beyond ~1.25)
LEVER_STEPS = 9
KEYFRAME_EVERY = 3  # arcs are cut into servo moves; every third one ends a keyframe (chords a replay follows)
PULL_ANGLE = 0.45  # rad about the hinge axis (success beyond 0.3; the hinge stops at 0.4)
PULL_STEPS = 10
OPEN_TARGET = 0.35


def _joint_frame(env, name: str) -> tuple[np.ndarray, np.ndarray]:
    jid = env.sim.model.joint_name2id(name)
    return np.array(env.sim.data.xanchor[jid]), np.array(env.sim.data.xaxis[jid])


def door_expert(recorder: EpisodeRecorder, variation: Variation, rng: np.random.Generator) -> None:
    env = recorder.env
    arm = WaypointArm(recorder, fail_pos_tol=0.03, fail_rot_tol=0.3, rng=rng)
    hinge_name, latch_name = env.door.joints[0], env.door.joints[1]
    latch_anchor, latch_axis = _joint_frame(env, latch_name)
    handle = np.array(env.sim.data.site_xpos[env.door_handle_site_id])

    # Site z (approach) along the latch axis, into the door; site x (finger closing) vertical, pointing up.
    approach = latch_axis / np.linalg.norm(latch_axis)
    x_axis = np.array([0.0, 0.0, 1.0])
    x_axis = x_axis - approach * (x_axis @ approach)
    x_axis /= np.linalg.norm(x_axis)
    rot0 = np.column_stack([x_axis, np.cross(approach, x_axis), approach])
    quat = mat_to_quat(rot0)

    # Reorient in place, away from the door: a quarter turn about the vertical, then tilt horizontal.
    start, current = grip_site_frame(env)
    pre_turn = top_down_quat(site_yaw(current) + WRIST_PRE_TURN)
    arm.move("wrist_turn", start, pre_turn, ignore_collision=False, allow_stall=True, pos_tol=0.05)
    arm.move("orient", start, quat, ignore_collision=False, allow_stall=True, pos_tol=0.05)
    arm.move("approach", handle - STANDOFF * approach, quat, ignore_collision=False)
    arm.move("grasp", handle, quat, ignore_collision=True, allow_stall=True, pos_tol=0.03)
    arm.grip(open=False)

    # Turn the lever so that the handle goes down.
    lever = handle - latch_anchor
    sign = -1.0 if np.cross(approach, lever)[2] > 0 else 1.0
    for k in range(1, LEVER_STEPS + 1):
        turn = Rotation.from_rotvec(sign * approach * LEVER_TURN * k / LEVER_STEPS)
        arm.move(
            "turn_lever",
            latch_anchor + turn.apply(lever),
            mat_to_quat(turn.as_matrix() @ rot0),
            ignore_collision=True,
            keyframe=k % KEYFRAME_EVERY == 0 or k == LEVER_STEPS,
            allow_stall=True,
            pos_tol=0.05,
            max_steps=30,
        )

    hinge_anchor, hinge_axis = _joint_frame(env, hinge_name)
    start_pos, start_rot = grip_site_frame(env)
    for k in range(1, PULL_STEPS + 1):
        swing = Rotation.from_rotvec(hinge_axis * PULL_ANGLE * k / PULL_STEPS)
        last = k == PULL_STEPS or hinge_angle(env) > OPEN_TARGET
        arm.move(
            "pull",
            hinge_anchor + swing.apply(start_pos - hinge_anchor),
            mat_to_quat(swing.as_matrix() @ start_rot),
            ignore_collision=True,
            keyframe=last or k % KEYFRAME_EVERY == 0,
            allow_stall=True,
            pos_tol=0.06,
            max_steps=30,
        )
        if last:
            break
    if hinge_angle(env) <= OPEN_TARGET - 0.05:
        raise ExpertFailure(f"door opened only {hinge_angle(env):.2f} rad")
