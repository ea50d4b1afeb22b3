"""Lift expert: top-down grasp of the cube, then lift it 15 cm.

Waypoints (ignore_collision label): above the cube +8 cm (0) -> cube centre -3 mm (1) -> close (1) ->
lift +15 cm (0). The grasp yaw is the cube's yaw modulo 90 degrees closest to the current hand yaw.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from sigma_data.experts.base import EpisodeRecorder, WaypointArm, check_grasp
from sigma_data.poses import (
    body_pose,
    closest_symmetric_yaw,
    grip_site_frame,
    object_yaw,
    site_yaw,
    top_down_quat,
)

if TYPE_CHECKING:
    from sigma_data.tasks.spec import Variation

PREGRASP_HEIGHT = 0.08
GRASP_OFFSET = -0.003
LIFT_HEIGHT = 0.15


def cube_grasp_quat(env, cube_rot: np.ndarray) -> np.ndarray:
    """Top-down grip-site quaternion closing across two cube faces, the one nearest the current hand yaw."""
    yaw = closest_symmetric_yaw(object_yaw(cube_rot), site_yaw(grip_site_frame(env)[1]), np.pi / 2)
    return top_down_quat(yaw)


def lift_expert(recorder: EpisodeRecorder, variation: Variation, rng: np.random.Generator) -> None:
    env = recorder.env
    arm = WaypointArm(recorder, rng=rng)
    cube_pos, cube_rot = body_pose(env, env.cube.root_body)
    quat = cube_grasp_quat(env, cube_rot)

    arm.move("pregrasp", cube_pos + [0, 0, PREGRASP_HEIGHT], quat, ignore_collision=False, approach=True)
    arm.move("grasp", cube_pos + [0, 0, GRASP_OFFSET], quat, ignore_collision=True)
    arm.grip(open=False)
    check_grasp(env, env.cube, "cube")
    arm.move("lift", cube_pos + [0, 0, GRASP_OFFSET + LIFT_HEIGHT], quat, ignore_collision=False)
