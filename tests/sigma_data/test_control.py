"""The motion primitives (``sigma_data/control.py``) on a real robosuite Lift env."""

from __future__ import annotations

import numpy as np
import pytest

from sigma_data.control import EnvDriver, MoveStatus, actuate_gripper, move_to
from sigma_data.poses import (
    grip_site_frame,
    gripper_width,
    quat_to_mat,
    rotation_error,
    top_down_quat,
)
from sigma_data.suite import reset_env


def test_move_to_converges_within_tolerance(lift):
    task, env = lift
    reset_env(env, task, task.variations[0], seed=0)
    start, _ = grip_site_frame(env)
    target = start + [0.05, -0.04, -0.06]
    quat = top_down_quat(0.4)
    result = move_to(EnvDriver(env), target, quat, grip=-1.0)
    assert result.status == MoveStatus.CONVERGED
    pos, rot = grip_site_frame(env)
    assert np.linalg.norm(pos - target) < 0.004
    assert rotation_error(rot, quat_to_mat(quat)) < 0.04
    assert result.steps < 60


def test_move_to_stalls_against_the_table(lift):
    task, env = lift
    reset_env(env, task, task.variations[0], seed=0)
    start, _ = grip_site_frame(env)
    result = move_to(EnvDriver(env), [start[0], start[1] + 0.15, 0.70], top_down_quat(0.0), grip=-1.0)
    assert result.status in (MoveStatus.STALLED, MoveStatus.BUDGET)
    assert result.pos_error > 0.05  # the table (top at z = 0.8) blocks the way down


def test_move_to_rejects_a_bad_grip(lift):
    _, env = lift
    with pytest.raises(ValueError, match="grip must be"):
        move_to(EnvDriver(env), [0, 0, 1], [0, 0, 0, 1], grip=0.5)


def test_gripper_closes_and_opens(lift):
    task, env = lift
    reset_env(env, task, task.variations[0], seed=0)
    driver = EnvDriver(env)
    assert gripper_width(env) > 0.075
    steps = actuate_gripper(driver, open=False)
    assert gripper_width(env) < 0.01 and 3 <= steps <= 25
    assert np.all(np.array(driver.actions)[:, 6] == 1.0)
    actuate_gripper(driver, open=True)
    assert gripper_width(env) > 0.075
