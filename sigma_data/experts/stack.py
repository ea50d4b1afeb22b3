"""Stack expert: pick the variation's top cube and set it down on the bottom cube.

Waypoints (ignore_collision label): above the top cube +8 cm (0) -> its centre -3 mm (1) -> close (1) ->
lift so the held cube clears the bottom cube by 8 cm (0) -> above the bottom cube, using the measured
cube-in-hand offset (0) -> down until the held cube's bottom is 8 mm above the bottom cube's top (1) ->
open (1) -> retreat 8 cm up (0).

The grasp yaw is the cube-symmetric yaw (mod 90 degrees) whose finger-closing axis is most perpendicular to
the top->bottom direction, so the fingers never hit the other cube when the two stand close.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from sigma_data.experts.base import EpisodeRecorder, WaypointArm, check_grasp
from sigma_data.experts.lift import GRASP_OFFSET, PREGRASP_HEIGHT
from sigma_data.poses import (
    body_pose,
    closest_symmetric_yaw,
    grip_site_frame,
    object_yaw,
    site_yaw,
    top_down_quat,
)
from sigma_data.tasks.stack import cube, cube_half_size

if TYPE_CHECKING:
    from sigma_data.tasks.spec import Variation

CLEARANCE = 0.08  # held cube bottom above the bottom cube's top while travelling
PLACE_GAP = 0.008  # held cube bottom above the bottom cube's top at release
RETREAT = 0.08


def grasp_yaw_away_from(cube_yaw: float, toward: np.ndarray, current_yaw: float) -> float:
    """Cube-symmetric grasp yaw whose closing axis is most perpendicular to the xy direction ``toward``."""
    direction = toward / max(np.linalg.norm(toward), 1e-9)
    candidates = [cube_yaw, cube_yaw + np.pi / 2]
    # closing axis of yaw t is (-sin t, cos t); minimise its alignment with the direction to the other cube
    best = min(candidates, key=lambda t: abs(-np.sin(t) * direction[0] + np.cos(t) * direction[1]))
    return closest_symmetric_yaw(best, current_yaw, np.pi)


def stack_expert(recorder: EpisodeRecorder, variation: Variation, rng: np.random.Generator) -> None:
    env = recorder.env
    arm = WaypointArm(recorder, rng=rng)
    top, bottom = cube(env, variation.params["top"]), cube(env, variation.params["bottom"])
    h_top, h_bottom = (
        cube_half_size(env, variation.params["top"]),
        cube_half_size(env, variation.params["bottom"]),
    )
    top_pos, top_rot = body_pose(env, top.root_body)
    bottom_pos, _ = body_pose(env, bottom.root_body)

    yaw = grasp_yaw_away_from(
        object_yaw(top_rot), bottom_pos[:2] - top_pos[:2], site_yaw(grip_site_frame(env)[1])
    )
    quat = top_down_quat(yaw)
    arm.move("pregrasp", top_pos + [0, 0, PREGRASP_HEIGHT], quat, ignore_collision=False, approach=True)
    arm.move("grasp", top_pos + [0, 0, GRASP_OFFSET], quat, ignore_collision=True)
    arm.grip(open=False)
    check_grasp(env, top, "top cube")

    bottom_pos, _ = body_pose(env, bottom.root_body)  # it may have been nudged
    bottom_top = bottom_pos[2] + h_bottom
    # Site height that puts the held cube's bottom `gap` above the bottom cube (grasp offset below the centre).
    site_z = bottom_top + h_top - GRASP_OFFSET
    site_pos, _ = grip_site_frame(env)
    arm.move("lift", [*site_pos[:2], site_z + CLEARANCE], quat, ignore_collision=False)

    in_hand = (
        body_pose(env, top.root_body)[0] - grip_site_frame(env)[0]
    )  # held cube centre relative to the site
    above = np.array([*(bottom_pos[:2] - in_hand[:2]), bottom_top + h_top + CLEARANCE - in_hand[2]])
    arm.move("above_bottom", above, quat, ignore_collision=False)
    in_hand = body_pose(env, top.root_body)[0] - grip_site_frame(env)[0]
    place = np.array([*(bottom_pos[:2] - in_hand[:2]), bottom_top + h_top + PLACE_GAP - in_hand[2]])
    arm.move("place", place, quat, ignore_collision=True)
    arm.grip(open=True)
    arm.move("retreat", place + [0, 0, RETREAT], quat, ignore_collision=False)
