"""Tests for sigma_policy/test_time.py: the turns, the yaw bins they shift and the passes' vote."""

from __future__ import annotations

import pytest
import torch

from sigma_policy.rotation import matrix_to_quat, quat_to_bins, quat_to_matrix
from sigma_policy.test_time import (
    EnsemblePass,
    check_yaw_angles,
    consensus,
    roll_yaw_bins,
    transform_points,
    yaw_about_box_centre,
)

BOXES = torch.tensor([[0.0, 0.0, 0.8, 0.4, 0.2, 1.2], [-0.5, -0.5, 0.7, 0.5, 0.5, 1.7]])


def test_a_quarter_turn_keeps_the_box_centre_line_and_turns_x_into_y():
    T = yaw_about_box_centre(BOXES, 90.0)
    centre = (BOXES[:, :3] + BOXES[:, 3:]) / 2
    moved = transform_points(T, centre + torch.tensor([0.1, 0.0, 0.05]))
    torch.testing.assert_close(moved, centre + torch.tensor([0.0, 0.1, 0.05]))
    cloud = torch.randn(2, 7, 3)
    torch.testing.assert_close(transform_points(T, transform_points(T, cloud), inverse=True), cloud)


def test_a_world_yaw_shifts_only_the_yaw_bin_and_rolling_it_back_recovers_the_pass():
    """Rz(phi) R has the Euler bins of R with phi / 5° added to the yaw: the turned pass, rolled back, is the
    unturned one (a top-down grasp and a tilted pose)."""
    quats = torch.tensor([[1.0, 0.0, 0.0, 0.0], [0.9, 0.1, 0.3, 0.2]])
    quats = quats / quats.norm(dim=-1, keepdim=True)
    T = yaw_about_box_centre(BOXES, 30.0)
    turned = matrix_to_quat(T[:, :3, :3] @ quat_to_matrix(quats))
    bins, turned_bins = quat_to_bins(quats), quat_to_bins(turned)
    assert (turned_bins[:, :2] == bins[:, :2]).all()
    assert ((turned_bins[:, 2] - bins[:, 2]) % 72 == 6).all()
    one_hot = torch.nn.functional.one_hot(turned_bins, 72).float()
    assert (roll_yaw_bins(one_hot, 30.0).argmax(-1) == bins).all()


def test_angles_off_the_bins_or_zero_are_refused():
    assert check_yaw_angles([-15, 15], 72) == [-15.0, 15.0]
    with pytest.raises(ValueError, match="multiples of the 5° rotation bins, got \\[7, 360\\]"):
        check_yaw_angles([7, 10, 360], 72)
    with pytest.raises(ValueError, match="not a multiple of the 5° rotation bins"):
        roll_yaw_bins(torch.ones(1, 3, 72) / 72, 7.0)


def _pass(x: float, open_prob: float) -> EnsemblePass:
    return EnsemblePass(
        point=torch.tensor([[x, 0.0, 1.0]]),
        rotation_probs=torch.full((1, 3, 72), 1 / 72),
        gripper_probs=torch.tensor([[1 - open_prob, open_prob]]),
        collision_probs=torch.tensor([[1.0, 0.0]]),
    )


def test_the_largest_group_wins_and_is_averaged_without_the_pass_that_went_elsewhere():
    out = consensus([_pass(0.30, 1.0), _pass(0.00, 0.0), _pass(0.01, 0.0)], radius=0.02)
    torch.testing.assert_close(out.point, torch.tensor([[0.005, 0.0, 1.0]]))
    torch.testing.assert_close(out.gripper_probs, torch.tensor([[1.0, 0.0]]))


def test_a_tie_goes_to_the_unturned_pass():
    out = consensus([_pass(0.30, 1.0), _pass(0.00, 0.0)], radius=0.02)
    torch.testing.assert_close(out.point, torch.tensor([[0.30, 0.0, 1.0]]))
    torch.testing.assert_close(out.gripper_probs, torch.tensor([[0.0, 1.0]]))
