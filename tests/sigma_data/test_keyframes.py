"""The ARM/PerAct keyframe heuristic and keyframe bookkeeping on hand-made sequences."""

import numpy as np
import pytest

from sigma_data.keyframes import (
    compare_keyframes,
    dedup_by_pose,
    discover_keyframes,
    keyframe_mask,
    next_keyframe_index,
)

MOVING = 0.5  # rad/s, above the 0.1 threshold


def velocities(stopped_frames, T):
    qd = np.full((T, 7), MOVING)
    qd[list(stopped_frames)] = 0.0
    return qd


def test_gripper_change_and_last_frame():
    g = np.array([1] * 5 + [0] * 5)
    assert discover_keyframes(velocities([], 10), g) == [5, 9]


def test_stopped_frames_with_buffer():
    # A long pause at frames 3..12: the first stopped frame is a keyframe, then at most one per 5 frames.
    T = 20
    assert discover_keyframes(velocities(range(3, 13), T), np.ones(T)) == [3, 8, 19]


def test_no_stopped_keyframe_next_to_a_gripper_change():
    # Stopped around a gripper change: the change is a keyframe, stops with an unsteady gripper are not.
    T = 12
    g = np.array([1] * 6 + [0] * 6)
    assert discover_keyframes(velocities([5, 6, 7], T), g) == [6, 11]
    assert discover_keyframes(velocities([4], T), g) == [4, 6, 11]  # two frames before: steady, stopped


def test_second_last_frame_is_never_stopped_and_consecutive_final_pair_is_deduped():
    T = 10
    assert discover_keyframes(velocities([8], T), np.ones(T)) == [9]
    # A gripper change at the second-last frame is a keyframe, then dropped as consecutive to the last.
    g = np.array([1] * 8 + [0] * 2)
    assert discover_keyframes(velocities([], T), g) == [9]


def test_threshold_is_inclusive_and_input_checked():
    T = 10
    qd = velocities([], T)
    qd[4] = 0.1
    assert discover_keyframes(qd, np.ones(T)) == [4, 9]
    with pytest.raises(ValueError, match="joint_velocities"):
        discover_keyframes(np.zeros((5, 7)), np.ones(6))


def test_next_keyframe_index_and_mask():
    np.testing.assert_array_equal(next_keyframe_index([2, 5], 6), [2, 2, 5, 5, 5, 5])
    np.testing.assert_array_equal(keyframe_mask([2, 5], 6), [0, 0, 1, 0, 0, 1])
    with pytest.raises(ValueError, match="include the last frame"):
        next_keyframe_index([2, 4], 6)


def test_dedup_by_pose():
    T = 6
    poses = np.zeros((T, 7))
    poses[:, 6] = 1
    poses[:, 0] = [0, 0.1, 0.105, 0.3, 0.3, 0.3]
    g = np.array([1, 1, 1, 1, 0, 0])
    # 1 -> 2 within 1 cm, same gripper: drop 1; 3 -> 4 same pose but the gripper changes: keep 3.
    assert dedup_by_pose([1, 2, 3, 4, 5], poses, g) == [2, 3, 5]
    rotated = poses.copy()
    rotated[1, 3:7] = [0, 0, np.sin(np.radians(5)), np.cos(np.radians(5))]  # 10 degrees about z
    assert dedup_by_pose([1, 2], rotated, g) == [1, 2]


def test_compare_keyframes():
    m = compare_keyframes([10, 20, 30], [9, 21, 25, 40], tolerance=2)
    assert (m.matched, m.recall, m.precision, m.mean_offset) == (2, 2 / 3, 0.5, 1.0)
