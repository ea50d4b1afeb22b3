"""Motion primitives and the keyframe executor on a real robosuite Lift env."""

from __future__ import annotations

import numpy as np
import pytest

from sigma_data.control import (
    EnvDriver,
    KeyframeExecutor,
    MoveStatus,
    actuate_gripper,
    canonical_quat,
    closest_symmetric_yaw,
    grip_site_frame,
    grip_site_pose,
    gripper_width,
    mat_to_quat,
    move_to,
    quat_to_mat,
    rotation_error,
    site_yaw,
    top_down_quat,
)
from sigma_data.suite import get_task, make_env, reset_env


@pytest.fixture(scope="module")
def lift():
    task = get_task("lift")
    env = make_env(task)
    yield task, env
    env.close()


def test_quaternion_helpers_are_xyzw_with_nonnegative_w():
    q = canonical_quat([0.0, 0.0, 0.0, -2.0])
    np.testing.assert_allclose(q, [0, 0, 0, 1])
    for yaw in (-2.0, -0.3, 0.0, 1.2):
        rot = quat_to_mat(top_down_quat(yaw))
        assert site_yaw(rot) == pytest.approx(yaw)
        np.testing.assert_allclose(rot[:, 2], [0, 0, -1], atol=1e-12)  # approach axis points down
        assert mat_to_quat(rot)[3] >= 0
    assert closest_symmetric_yaw(0.1, 1.5, np.pi / 2) == pytest.approx(0.1 + np.pi / 2)


def test_pose_helpers_are_shared_with_the_recorder(lift):
    """control re-exports the one definition of ``grip_site_pose`` / ``canonical_quat``; frame == pose."""
    import sigma_data.episode
    import sigma_data.record

    assert grip_site_pose is sigma_data.record.grip_site_pose
    assert canonical_quat is sigma_data.episode.canonical_quat
    task, env = lift
    reset_env(env, task, task.variations[0], seed=1)
    pos, quat = grip_site_pose(env)
    frame_pos, rot = grip_site_frame(env)
    np.testing.assert_allclose(pos, frame_pos)
    assert rotation_error(quat_to_mat(quat), rot) < 1e-9 and quat[3] >= 0


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


def test_executor_replays_lift_expert_keyframes(lift):
    task, env = lift
    variation = task.variations[0]
    reset_env(env, task, variation, seed=3)
    demo = EnvDriver(env)
    task.expert(demo, variation, np.random.default_rng(3))
    assert task.success(env, variation)

    reset_env(env, task, variation, seed=3)
    assert not task.success(env, variation)
    replay = EnvDriver(env)
    results = KeyframeExecutor(replay).execute_all(demo.keyframes)
    assert task.success(env, variation)
    assert [r.gripper_steps > 0 for r in results] == [False, False, True, False]
    assert replay.num_steps <= task.max_steps


def test_executor_rejects_malformed_keyframes(lift):
    _, env = lift
    with pytest.raises(ValueError, match="9 finite values"):
        KeyframeExecutor(EnvDriver(env)).execute(np.zeros(7))
