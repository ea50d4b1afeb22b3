"""NutAssembly expert: grasp the named nut by its handle and drop it over its own peg.

Waypoints (ignore_collision label): 8 cm above the grasp point (0) -> the grasp point on the handle, 8 mm
beyond the handle site away from the nut (1) -> close (1) -> lift the nut
to 25 cm above the table (0) -> (round nut only) turn the hand in place about the vertical so the nut hangs away
from the robot, on the +x side of the handle where the wrist allows (0) -> nut centre over the peg, 4 cm above its
top, corrected in closed loop from the measured nut position (<= 4 iterations, 3 mm; one keyframe), the square nut
turning on the way by the least angle that squares it with its peg (0) -> down until the nut centre is 2.5 cm above
the table (1) -> open (1) -> retreat 8 cm up (0).

The fingers close across the handle (closing axis perpendicular to centre->handle); of the two such grasps
the one needing the smaller hand rotation overall is taken.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from sigma_data.experts.base import EpisodeRecorder, ExpertFailure, WaypointArm, check_grasp
from sigma_data.poses import (
    body_pose,
    closest_symmetric_yaw,
    grip_site_frame,
    site_yaw,
    top_down_quat,
    wrap_angle,
    yaw_rotation,
)
from sigma_data.tasks.nut_assembly import nut_object, peg_body_id

if TYPE_CHECKING:
    from sigma_data.tasks.spec import Variation

PREGRASP_HEIGHT = 0.08
GRASP_OFFSET = 0.003  # grip site above the handle centre (fingertips reach ~9 mm below the site)
# Grip site this far beyond the handle site, away from the nut: the finger pads (+-11 mm along the handle) then
# clear the nut's ring by >= 5 mm (square nut: ring edge 43.75 mm, handle site 54 mm, handle end 79 mm from
# the centre); grasping at the handle site let a finger land on the ring corner and push the nut away.
HANDLE_OUTWARD = 0.008
LIFT_ABOVE_TABLE = 0.25
HOVER_ABOVE_PEG = 0.04  # nut bottom above the peg top while aligning
PEG_HALF_HEIGHT = 0.10
NUT_HALF_THICKNESS = 0.01
RELEASE_ABOVE_TABLE = 0.025  # nut centre height at release (robosuite counts it on the peg below 5 cm)
ALIGN_TOL = 0.003
ALIGN_ITERATIONS = 4
RETREAT = 0.08


# Allowed directions (rad, world yaw) from the handle to the nut centre while placing: never toward the robot (the
# hand would hover 6 cm beyond the square peg, out of the arm's reach at that height: it stalls about 3 cm short).
# The square hole fits the square peg only near 0 mod 90 degrees of nut yaw; the round nut fits at any yaw. The square
# nut turns the least: unless its centre lies toward the robot from the handle, the turn is at most 45 degrees and
# the hand ends at its grasp yaw rounded to a multiple of 90 degrees (the fingers close across the handle, so the
# hand's yaw and the nut's agree mod 90), a yaw the policy can read from where its hand is (docs/learning.md "The
# square nut hung toward the robot" and "The square nut turns on the way to its peg").
HANG_DIRECTIONS = {
    "square": np.radians([0.0, 90.0, -90.0]),
    "round": np.radians(np.arange(-90.0, 91.0, 15.0)),
}
WRIST_LIMIT = 2.6  # rad; keep the Panda's joint 7 (range +-2.897) this far inside its range
OFF_AXIS_PENALTY = 0.3  # rad-equivalent cost of not hanging the round nut straight out along +x


def wrist_angle(env) -> float:
    """Current Panda joint 7 angle (rad)."""
    return float(env.sim.data.qpos[env.robots[0]._ref_joint_pos_indexes[6]])


def plan_yaws(handle_yaw: float, hand_yaw: float, q7: float, nut: str) -> tuple[float, float]:
    """(grasp yaw, turn) for the handle grasp and the in-hand turn before placing.

    The fingers close across the handle (grasp yaw = handle yaw mod pi). After turning the hand by ``turn``
    the handle->centre direction (``handle_yaw + pi`` now) becomes one of ``HANG_DIRECTIONS[nut]``. Joint 7 turns
    opposite to the site yaw (q7 ~ q7_now - (yaw - yaw_now)); both yaws must keep it within
    ``WRIST_LIMIT``. The round nut minimises the largest hand rotation away from ``hand_yaw`` plus a penalty for
    hanging the nut off the +x axis; the square nut the grasp's rotation away from ``hand_yaw`` plus the turn.
    """
    base = closest_symmetric_yaw(handle_yaw, hand_yaw, np.pi)
    best, best_cost = None, np.inf
    for direction in HANG_DIRECTIONS[nut]:
        turn = wrap_angle(direction - (handle_yaw + np.pi))
        for yaw in (base - np.pi, base, base + np.pi):
            wrist = [q7 - (y - hand_yaw) for y in (yaw, yaw + turn)]
            if max(abs(w) for w in wrist) > WRIST_LIMIT:
                continue
            if nut == "square":
                cost = abs(yaw - hand_yaw) + abs(turn)
            else:
                cost = max(abs(yaw - hand_yaw), abs(yaw + turn - hand_yaw)) + OFF_AXIS_PENALTY * abs(
                    direction
                )
            if cost < best_cost:
                best, best_cost = (yaw, turn), cost
    if best is None:
        raise ExpertFailure(f"no handle grasp keeps the wrist in range (handle yaw {handle_yaw:.2f} rad)")
    return best


def nut_assembly_expert(recorder: EpisodeRecorder, variation: Variation, rng: np.random.Generator) -> None:
    env = recorder.env
    arm = WaypointArm(recorder, rng=rng)
    nut = nut_object(env, variation.params["nut"])
    table_z = float(env.table_offset[2])
    peg_pos = np.array(env.sim.data.body_xpos[peg_body_id(env, variation.params["nut"])])
    peg_top = peg_pos[2] + PEG_HALF_HEIGHT

    centre, _ = body_pose(env, nut.root_body)
    handle = np.array(env.sim.data.site_xpos[env.sim.model.site_name2id(nut.important_sites["handle"])])
    handle_yaw = float(np.arctan2(*(handle - centre)[1::-1]))
    yaw, turn = plan_yaws(
        handle_yaw, site_yaw(grip_site_frame(env)[1]), wrist_angle(env), variation.params["nut"]
    )
    quat = top_down_quat(yaw)

    outward = (handle - centre) * [1, 1, 0]
    grasp = handle + HANDLE_OUTWARD * outward / np.linalg.norm(outward) + [0, 0, GRASP_OFFSET]
    arm.move("pregrasp", grasp + [0, 0, PREGRASP_HEIGHT], quat, ignore_collision=False, approach=True)
    arm.move("grasp", grasp, quat, ignore_collision=True)
    arm.grip(open=False)
    check_grasp(env, nut, f"{variation.params['nut']} nut")
    arm.move("lift", [*grasp[:2], table_z + LIFT_ABOVE_TABLE], quat, ignore_collision=False)

    quat = top_down_quat(yaw + turn)
    if variation.params["nut"] == "round":  # the square nut turns on the way to its peg: no keyframe in place
        site, _ = grip_site_frame(env)
        arm.move("turn", site, quat, ignore_collision=False)
        check_grasp(env, nut, f"{variation.params['nut']} nut (after the turn)")

    # Hover the nut centre over the peg, re-measuring the in-hand offset (the nut swings and slips a little); a hand
    # still to turn counts the offset turned with it.
    hover_z = peg_top + HOVER_ABOVE_PEG + NUT_HALF_THICKNESS
    for _ in range(ALIGN_ITERATIONS):
        site, rot = grip_site_frame(env)
        in_hand = yaw_rotation(yaw + turn - site_yaw(rot)) @ (body_pose(env, nut.root_body)[0] - site)
        target = np.array([*(peg_pos[:2] - in_hand[:2]), hover_z - in_hand[2]])
        arm.move(
            "align", target, quat, ignore_collision=False, keyframe=False, allow_stall=True, pos_tol=0.03
        )
        error = np.linalg.norm(body_pose(env, nut.root_body)[0][:2] - peg_pos[:2])
        if error < ALIGN_TOL:
            break
    else:
        raise ExpertFailure(
            f"nut not aligned over its peg: {1000 * error:.1f} mm off after {ALIGN_ITERATIONS} tries"
        )
    recorder.mark_keyframe(arm.gripper_open, False)
    check_grasp(env, nut, f"{variation.params['nut']} nut (over its peg)")

    site, _ = grip_site_frame(env)
    in_hand = body_pose(env, nut.root_body)[0] - site
    place = np.array([*site[:2], table_z + RELEASE_ABOVE_TABLE - in_hand[2]])
    arm.move("insert", place, quat, ignore_collision=True, allow_stall=True, pos_tol=0.03)
    arm.grip(open=True)
    arm.move("retreat", place + [0, 0, RETREAT], quat, ignore_collision=False)
