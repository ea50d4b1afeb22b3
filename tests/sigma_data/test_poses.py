"""Pose conventions and simulator queries (``sigma_data/poses.py``), on a real robosuite Lift env."""

from __future__ import annotations

import numpy as np
import pytest

from sigma_data.episode import canonical_quat
from sigma_data.poses import (
    closest_symmetric_yaw,
    grip_site_frame,
    grip_site_pose,
    mat_to_quat,
    quat_to_mat,
    rotation_error,
    site_yaw,
    top_down_quat,
    wrap_angle,
)
from sigma_data.suite import reset_env


def test_quaternion_helpers_are_xyzw_with_nonnegative_w():
    q = canonical_quat([0.0, 0.0, 0.0, -2.0])
    np.testing.assert_allclose(q, [0, 0, 0, 1])
    for yaw in (-2.0, -0.3, 0.0, 1.2):
        rot = quat_to_mat(top_down_quat(yaw))
        assert site_yaw(rot) == pytest.approx(yaw)
        np.testing.assert_allclose(rot[:, 2], [0, 0, -1], atol=1e-12)  # approach axis points down
        assert mat_to_quat(rot)[3] >= 0
    assert closest_symmetric_yaw(0.1, 1.5, np.pi / 2) == pytest.approx(0.1 + np.pi / 2)


def test_grip_site_frame_is_the_recorded_pose(lift):
    """The recorder's ``grip_site_pose`` (position, xyzw) and the servo's ``grip_site_frame`` (position, matrix)
    are one pose."""
    task, env = lift
    reset_env(env, task, task.variations[0], seed=1)
    pos, quat = grip_site_pose(env)
    frame_pos, rot = grip_site_frame(env)
    np.testing.assert_allclose(pos, frame_pos)
    assert rotation_error(quat_to_mat(quat), rot) < 1e-9 and quat[3] >= 0


def test_wrap_angle_is_half_open():
    assert wrap_angle(np.pi) == pytest.approx(-np.pi)
    assert wrap_angle(3 * np.pi / 2) == pytest.approx(-np.pi / 2)
    assert wrap_angle(-0.25) == pytest.approx(-0.25)
