"""Episode: validation of shapes and keyframes, keyframe poses, decision frames, gripper flags."""

import numpy as np
import pytest

from sigma_data.episode import (
    CameraStream,
    Episode,
    Keyframe,
    canonical_quat,
    gripper_open_from_actions,
    hold_action,
    with_final_keyframe,
)


def make_episode(T=6, keyframes=(2, 5), **kwargs) -> Episode:
    states = np.zeros((T, 10), dtype=np.float32)
    states[:, 0] = np.arange(T) * 0.01
    states[:, 3:7] = [0, 0, 0, -1]  # w < 0: keyframe poses must flip it
    states[:, 7] = 1
    stream = CameraStream(
        rgb=np.zeros((T, 4, 4, 3), np.uint8),
        depth=np.ones((T, 4, 4), np.float32),
        intrinsics=np.tile(np.eye(3, dtype=np.float32), (T, 1, 1)),
        extrinsics=np.tile(np.eye(4, dtype=np.float32), (T, 1, 1)),
    )
    args = {
        "task": "lift",
        "variation": "lift_cube",
        "instruction": "lift the cube",
        "states": states,
        "actions": np.zeros((T, 7), np.float32),
        "keyframes": [Keyframe(k, True, k == keyframes[0]) for k in keyframes],
        "images": {"cam": stream},
        "seed": 3,
    }
    args.update(kwargs)
    return Episode(**args)


def test_keyframe_poses_are_canonical_and_carry_labels():
    ep = make_episode()
    poses = ep.keyframe_poses()
    assert poses.shape == (2, 9)
    np.testing.assert_allclose(poses[:, 3:7], [[0, 0, 0, 1]] * 2)
    np.testing.assert_allclose(poses[:, 0], [0.02, 0.05], atol=1e-7)
    np.testing.assert_array_equal(poses[:, 7:], [[1, 1], [1, 0]])


def test_decision_frames():
    ep = make_episode(T=8, keyframes=(2, 5, 7))
    assert ep.decision_frames() == [0, 2, 5, 7]
    assert ep.decision_frames(3) == [3, 5, 7]
    assert ep.decision_frames(5) == [5, 7]


@pytest.mark.parametrize(
    ("keyframes", "match"),
    [
        ((2, 4), "end at the last frame"),
        ((0, 5), "in \\[1, 5\\]"),
        ((3, 2, 5), "increasing"),
        ((), "keyframes"),
    ],
)
def test_bad_keyframes_are_rejected_with_the_episode_named(keyframes, match):
    with pytest.raises(ValueError, match=match) as err:
        make_episode(keyframes=keyframes)
    assert "lift/lift_cube seed 3" in str(err.value)


def test_shape_and_source_errors():
    with pytest.raises(ValueError, match="actions must be"):
        make_episode(actions=np.zeros((6, 9)))
    with pytest.raises(ValueError, match="NaN"):
        states = np.zeros((6, 10), np.float32)
        states[2, 1] = np.nan
        make_episode(states=states)
    with pytest.raises(ValueError, match="no pixels source"):
        make_episode(images=None)
    with pytest.raises(ValueError, match="camera 'cam' has 6 stored frames, not 7"):
        ep = make_episode()
        make_episode(T=7, keyframes=(6,), images=ep.images)


def test_gripper_flags_follow_the_previous_command():
    actions = np.zeros((5, 7))
    actions[:, 6] = [-1, 1, 1, -1, -1]
    np.testing.assert_array_equal(gripper_open_from_actions(actions), [1, 1, 0, 0, 1])
    np.testing.assert_array_equal(gripper_open_from_actions(actions, initial_open=False)[0], 0)


def test_final_keyframe_and_hold_action():
    kfs = with_final_keyframe([Keyframe(3, False, True)], 6, gripper_open=False)
    assert [k.index for k in kfs] == [3, 5] and kfs[-1].source == "final" and not kfs[-1].gripper_open
    assert with_final_keyframe(kfs, 6, True) == kfs
    np.testing.assert_array_equal(hold_action(np.array([0.3, 0, 0, 0, 0, 0, 1.0])), [0, 0, 0, 0, 0, 0, 1])


def test_canonical_quat_batch():
    q = canonical_quat(np.array([[0, 0, 0, -2.0], [0, 1, 0, 0]]))
    np.testing.assert_allclose(q, [[0, 0, 0, 1], [0, 1, 0, 0]])


def test_state_quaternion_is_made_continuous_and_keyframe_poses_keep_w_nonnegative():
    """Gripper pointing down: w ~ 0 and the w >= 0 rule flips the sign back and forth; the episode's state keeps
    one hemisphere (same rotations), while the keyframe poses keep the w >= 0 convention."""
    from scipy.spatial.transform import Rotation

    T = 6
    w = np.array([0.02, -0.01, -0.03, 0.01, -0.02, 0.02])
    quats = canonical_quat(np.column_stack([np.full(T, 0.99), np.full(T, 0.1), np.zeros(T), w]))
    assert (np.einsum("ij,ij->i", quats[1:], quats[:-1]) < 0).any()  # the input does flip
    states = np.zeros((T, 10), np.float32)
    states[:, 3:7] = quats
    ep = make_episode(T=T, keyframes=(2, 5), states=states)
    q = ep.states[:, 3:7].astype(np.float64)
    assert (np.einsum("ij,ij->i", q[1:], q[:-1]) > 0).all() and q[0, 3] >= 0
    angle = (Rotation.from_quat(q).inv() * Rotation.from_quat(quats)).magnitude()
    np.testing.assert_allclose(angle, 0, atol=1e-5)  # same rotations
    assert (ep.keyframe_poses()[:, 6] >= 0).all()


def test_zero_state_quaternion_is_a_clear_error():
    states = np.zeros((6, 10), np.float32)
    with pytest.raises(ValueError, match=r"states\[0, 3:7\] \(eef quaternion\) has norm 0.0000"):
        make_episode(states=states)
