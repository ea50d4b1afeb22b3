"""``sigma_policy/behaviour_cloning.py``: each BC term is the cross-entropy it claims, per sample, and a prediction
that puts its mass on the target scores lower than one beside it."""

from __future__ import annotations

import math

import torch

from sigma_policy.behaviour_cloning import bc_losses
from sigma_policy.heatmap import gaussian_heatmaps
from sigma_policy.rotation import euler_xyz_to_quat, quat_to_bins

B, V, S, BINS = 3, 5, 16, 72


def _batch(open_flag: float = 1.0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    action = torch.zeros(B, 9)
    quat = euler_xyz_to_quat(torch.tensor([[180.0, 0.0, 30.0 * i] for i in range(B)]))
    action[:, 3:7], action[:, 7], action[:, 8] = quat, open_flag, 0.0
    uv = torch.full((B, V, 2), 8.0)
    return action, quat, gaussian_heatmaps(uv, S, sigma=1.5)


def test_uniform_logits_cost_the_log_of_the_class_counts() -> None:
    action, quat, target = _batch()
    terms = bc_losses(
        torch.zeros(B, V, S, S),
        target,
        torch.zeros(B, 3, BINS),
        torch.zeros(B, 2),
        torch.zeros(B, 2),
        action,
        quat,
    )
    assert terms.translation.shape == (B,)
    torch.testing.assert_close(terms.translation, torch.full((B,), math.log(S * S)))
    torch.testing.assert_close(terms.rotation, torch.full((B,), 3 * math.log(BINS)))
    torch.testing.assert_close(terms.gripper, torch.full((B,), math.log(2)))
    torch.testing.assert_close(
        terms.total, terms.translation + terms.rotation + terms.gripper + terms.collision
    )
    assert set(terms.info()) == {"trans_loss", "rot_loss", "grip_loss", "collision_loss", "bc_loss"}


def test_the_right_bins_flags_and_pixel_score_lower_than_wrong_ones() -> None:
    action, quat, target = _batch(open_flag=0.0)
    bins = quat_to_bins(quat, BINS)  # (B, 3)
    right_rot = torch.full((B, 3, BINS), -5.0).scatter(2, bins[..., None], 5.0)
    wrong_rot = torch.full((B, 3, BINS), -5.0).scatter(2, ((bins + 7) % BINS)[..., None], 5.0)
    closed = torch.tensor([[5.0, -5.0]]).expand(B, 2)  # class 0: gripper closed, as the action says
    on_target, beside = torch.zeros(B, V, S, S), torch.zeros(B, V, S, S)
    on_target[..., 8, 8] = 10.0
    beside[..., 2, 2] = 10.0
    right = bc_losses(on_target, target, right_rot, closed, closed, action, quat)
    wrong = bc_losses(beside, target, wrong_rot, closed.flip(-1), closed.flip(-1), action, quat)
    assert (right.translation < wrong.translation).all() and (right.rotation < wrong.rotation).all()
    assert (right.gripper < 1e-3).all() and (wrong.gripper > 5).all() and (wrong.collision > 5).all()
