"""EpisodeRecorder on a real robosuite Lift env, driven by a simple scripted motion (no expert needed)."""

import numpy as np
import pytest

from sigma_data.poses import grip_site_pose
from sigma_data.record import EpisodeRecorder, robot_state
from sigma_data.suite import get_task, make_env, reset_env


@pytest.fixture(scope="module")
def env():
    task = get_task("lift")
    env = make_env(task)  # no cameras: stepping never renders
    yield env
    env.close()


def scripted(recorder: EpisodeRecorder) -> None:
    """Move up 5 steps (open), mark; close the gripper 6 steps, mark."""
    for _ in range(5):
        recorder.step(np.array([0, 0, 0.5, 0, 0, 0, -1.0]))
    recorder.mark_keyframe(gripper_open=True, ignore_collision=False)
    for _ in range(6):
        recorder.step(np.array([0, 0, 0, 0, 0, 0, 1.0]))
    recorder.mark_keyframe(gripper_open=False, ignore_collision=True)


def test_records_every_step_and_keyframes(env):
    task = get_task("lift")
    reset_env(env, task, task.variations[0], seed=0)
    rec = EpisodeRecorder(env)
    z0 = grip_site_pose(env)[0][2]
    scripted(rec)
    assert rec.num_steps == 11
    ep = rec.to_episode("lift", "lift_cube", "lift the cube", seed=0)
    assert len(ep) == 12 and ep.sim_states.shape[0] == 12 and ep.joint_velocities.shape == (12, 7)
    assert ep.keyframe_indices == [5, 11]
    assert [(k.gripper_open, k.ignore_collision) for k in ep.keyframes] == [(True, False), (False, True)]
    # Frame t is the state before action t; the last frame holds with the last grip command.
    np.testing.assert_array_equal(ep.actions[0], [0, 0, 0.5, 0, 0, 0, -1])
    np.testing.assert_array_equal(ep.actions[-1], [0, 0, 0, 0, 0, 0, 1])
    np.testing.assert_array_equal(ep.states[:, 7], [1] * 6 + [0] * 6)
    assert ep.states[5, 2] > z0 + 0.02  # moved up
    assert ep.states[-1, 8] < ep.states[5, 8]  # fingers closing (finger_q1 shrinks)
    np.testing.assert_allclose(np.linalg.norm(ep.states[:, 3:7], axis=1), 1, atol=1e-6)
    assert (ep.states[:, 6] >= 0).all()


def test_state_replay_reproduces_the_recorded_state(env):
    task = get_task("lift")
    reset_env(env, task, task.variations[0], seed=1)
    rec = EpisodeRecorder(env)
    scripted(rec)
    ep = rec.to_episode("lift", "lift_cube", "lift the cube", seed=1)
    for t in (0, 5, 11):
        env.sim.set_state_from_flattened(ep.sim_states[t])
        env.sim.forward()
        np.testing.assert_allclose(robot_state(env, bool(ep.states[t, 7])), ep.states[t], atol=1e-6)


def test_recorder_errors(env):
    task = get_task("lift")
    reset_env(env, task, task.variations[0], seed=0)
    rec = EpisodeRecorder(env)
    with pytest.raises(RuntimeError, match="before any step"):
        rec.mark_keyframe(True, False)
    with pytest.raises(ValueError, match="7 finite values"):
        rec.step(np.zeros(6))
    with pytest.raises(RuntimeError, match="nothing recorded"):
        rec.to_episode("lift", "lift_cube", "lift the cube")
    rec.step(np.zeros(7))
    rec.mark_keyframe(True, False)
    with pytest.raises(RuntimeError, match="already a keyframe"):
        rec.mark_keyframe(True, False)
