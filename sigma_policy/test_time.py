"""Test-time yaw ensemble (sigma addition, off in every preset; ``tta_yaw_deg`` in configuration_sigma.py).

Training turns every scene by a random yaw (``aug_yaw_range_deg``, sigma_policy/augmentation.py), so the network
has learned to predict in turned scenes. At inference the same observation can then be asked again, turned: each
angle ``phi`` of ``tta_yaw_deg`` turns the fused cloud (and the gripper's pose the proprio token reads) about the
vertical axis through the centre of the sample's box, the network predicts in that frame, and the prediction is
turned back. The passes are then combined (:func:`consensus`):

* position: the passes vote. The pass with the most others within ``radius`` metres of its point wins (the
  unturned pass on a tie), and the position is the mean of the winner's neighbours. A pass that went to another
  object is left out instead of averaged in, which a plain mean would do halfway between two objects.
* rotation, gripper and collision: the mean of the neighbours' probabilities. A yaw about world z only adds to the
  yaw angle of extrinsic-xyz Euler angles (``R = Rz(yaw) Ry(pitch) Rx(roll)``, sigma_policy/rotation.py), so a
  turned pass's yaw distribution is shifted back by ``phi`` in bins, exactly when ``phi`` is a multiple of the bin
  width (5° for 72 bins); roll and pitch are unchanged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

__all__ = [
    "EnsemblePass",
    "check_yaw_angles",
    "consensus",
    "roll_yaw_bins",
    "transform_points",
    "yaw_about_box_centre",
]

YAW_AXIS = 2  # the Euler axis of the rotation head's (B, 3, bins) distributions that a world yaw shifts


@dataclass
class EnsemblePass:
    """One pass's prediction, in the world frame of the observation (already turned back)."""

    point: Tensor  # (B, 3) metres
    rotation_probs: Tensor  # (B, 3, bins)
    gripper_probs: Tensor  # (B, 2)
    collision_probs: Tensor  # (B, 2)


def _off_bins(degrees: float, num_bins: int) -> bool:
    """Whether ``degrees`` is not a whole number of the ``360 / num_bins`` rotation bins."""
    shift = degrees * num_bins / 360.0
    return abs(shift - round(shift)) > 1e-6


def check_yaw_angles(degrees: list[float], num_bins: int) -> list[float]:
    """``degrees`` as floats when each is a non-zero multiple (mod 360) of the ``360 / num_bins`` rotation bins, else
    ValueError naming the others."""
    off = [a for a in degrees if _off_bins(a, num_bins) or a % 360 == 0]
    if off:
        raise ValueError(
            f"test-time yaws must be non-zero multiples of the {360 / num_bins:g}° rotation bins, got {off}"
        )
    return [float(a) for a in degrees]


def yaw_about_box_centre(bounds: Tensor, degrees: float) -> Tensor:
    """(B, 4, 4) rigid transforms turning the world by ``degrees`` about the vertical line through the centre of
    each box of ``bounds`` (B, 6) = (xmin, ymin, zmin, xmax, ymax, zmax): ``p' = Rz (p - c) + c``."""
    B = bounds.shape[0]
    theta = math.radians(degrees)
    c, s = math.cos(theta), math.sin(theta)
    R = torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], dtype=bounds.dtype, device=bounds.device)
    centre = (bounds[:, :3] + bounds[:, 3:]) / 2
    T = torch.eye(4, dtype=bounds.dtype, device=bounds.device).repeat(B, 1, 1)
    T[:, :3, :3] = R
    T[:, :3, 3] = centre - centre @ R.T
    return T


def transform_points(T: Tensor, points: Tensor, inverse: bool = False) -> Tensor:
    """Points ``(B, N, 3)`` or ``(B, 3)`` moved by the rigid transforms ``T`` (B, 4, 4), or by their inverses."""
    single = points.ndim == 2
    p = points[:, None] if single else points  # (B, N, 3) row vectors: p R^T is R p
    R, t = T[:, :3, :3].to(points), T[:, None, :3, 3].to(points)
    out = (p - t) @ R if inverse else p @ R.transpose(1, 2) + t
    return out[:, 0] if single else out


def roll_yaw_bins(rotation_probs: Tensor, degrees: float) -> Tensor:
    """The (B, 3, bins) Euler-bin distributions of a pass turned by ``degrees``, in the unturned frame: its yaw
    shifted back by ``degrees`` (a multiple of the bin width, else ValueError)."""
    bins = rotation_probs.shape[-1]
    if _off_bins(degrees, bins):
        raise ValueError(
            f"a test-time yaw of {degrees}° is not a multiple of the {360 / bins:g}° rotation bins"
        )
    out = rotation_probs.clone()
    out[:, YAW_AXIS] = torch.roll(rotation_probs[:, YAW_AXIS], shifts=-round(degrees * bins / 360.0), dims=-1)
    return out


def consensus(passes: list[EnsemblePass], radius: float) -> EnsemblePass:
    """One prediction from ``passes`` (the unturned one first): the point with the most others within ``radius``
    metres wins, ties to the earlier pass; the result averages the winner's neighbours (itself included)."""
    points = torch.stack([p.point for p in passes])  # (K, B, 3)
    near = (points[:, None] - points[None]).norm(dim=-1) <= radius  # (K, K, B): pass j near pass i
    votes = near.sum(1)  # (K, B)
    # argmax returns the first maximum: the unturned pass wins a tie.
    winner = votes.float().argmax(0)  # (B,)
    members = near[winner, :, torch.arange(points.shape[1], device=points.device)].T.float()  # (K, B)
    weight = members / members.sum(0)

    def mean(values: list[Tensor]) -> Tensor:
        stacked = torch.stack(values)
        return (stacked * weight.view(*weight.shape, *([1] * (stacked.ndim - 2))).to(stacked)).sum(0)

    return EnsemblePass(
        point=mean([p.point for p in passes]),
        rotation_probs=mean([p.rotation_probs for p in passes]),
        gripper_probs=mean([p.gripper_probs for p in passes]),
        collision_probs=mean([p.collision_probs for p in passes]),
    )
