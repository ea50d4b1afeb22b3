"""SE(3) augmentation: ranges, bounds clamping, inverse, and consistency between cloud and action; render noise."""

from __future__ import annotations

import math

import pytest
import torch

from sigma_policy.augmentation import NOISY_CHANNELS, add_render_noise, se3_augment
from sigma_policy.rotation import normalize_quat, quat_to_euler_xyz, quat_to_matrix

BOUNDS = torch.tensor([-0.4, -0.5, 0.75, 0.4, 0.5, 1.35])


def _sample(B: int, seed: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    lo, hi = BOUNDS[:3], BOUNDS[3:]
    pos = lo + (hi - lo) * torch.rand(B, 3, generator=g)
    quat = normalize_quat(torch.randn(B, 4, generator=g))
    points = lo + (hi - lo) * torch.rand(B, 500, 3, generator=g)
    return points, pos, quat


def test_transform_is_consistent_for_cloud_and_action() -> None:
    points, pos, quat = _sample(16, 0)
    # A point rigidly attached to the gripper (offset in the gripper frame) must follow the gripper.
    offset = torch.tensor([0.03, -0.02, 0.1])
    attached = pos + (quat_to_matrix(quat) @ offset)
    cloud = torch.cat([points, attached[:, None]], 1)
    g = torch.Generator().manual_seed(1)
    new_cloud, new_pos, new_quat, T = se3_augment(cloud, pos, quat, BOUNDS, generator=g)
    torch.testing.assert_close(
        new_cloud[:, -1], new_pos + quat_to_matrix(new_quat) @ offset, atol=1e-5, rtol=0
    )
    # Transforms map old to new points; the inverse recovers the original cloud.
    homog = torch.cat([cloud, torch.ones_like(cloud[..., :1])], -1)
    torch.testing.assert_close((homog @ T.transpose(1, 2))[..., :3], new_cloud, atol=1e-5, rtol=0)
    back = torch.cat([new_cloud, torch.ones_like(cloud[..., :1])], -1) @ torch.linalg.inv(T).transpose(1, 2)
    torch.testing.assert_close(back[..., :3], cloud, atol=1e-5, rtol=0)
    # Pivot: the target position only translates.
    torch.testing.assert_close(
        (T[:, :3, :3] @ pos[..., None])[..., 0] + T[:, :3, 3], new_pos, atol=1e-6, rtol=0
    )
    assert (new_quat[:, 3] >= 0).all()


def test_ranges_and_bounds_clamp() -> None:
    points, pos, quat = _sample(400, 2)
    pos[:5] = BOUNDS[3:] - 0.01  # near the upper corner: the shift must keep it inside
    _, new_pos, new_quat, T = se3_augment(
        points, pos, quat, BOUNDS, generator=torch.Generator().manual_seed(3)
    )
    t = new_pos - pos
    assert t.abs().max() <= 0.125 + 1e-6 and t.abs().max() > 0.1
    assert ((new_pos >= BOUNDS[:3] - 1e-6) & (new_pos <= BOUNDS[3:] + 1e-6)).all()
    yaw = torch.atan2(T[:, 1, 0], T[:, 0, 0])  # T's rotation is Rz(-theta)
    assert yaw.abs().max() <= math.radians(45) + 1e-6 and yaw.abs().max() > math.radians(40)
    assert torch.allclose(T[:, 2, :3], torch.tensor([0.0, 0.0, 1.0]))  # a pure yaw
    # Yaw changes only the extrinsic-xyz yaw of the target orientation (pitch unchanged).
    torch.testing.assert_close(
        quat_to_euler_xyz(new_quat)[:, 1], quat_to_euler_xyz(quat)[:, 1], atol=1e-3, rtol=0
    )


def test_a_range_per_axis_and_per_sample_bounds_each_axis() -> None:
    points, pos, quat = _sample(400, 4)
    per_axis = torch.tensor([0.1, 0.0, 0.02])  # the box unit's share of an extent, say: y held still
    _, new_pos, _, _ = se3_augment(
        points, pos, quat, BOUNDS, xyz_range=per_axis, generator=torch.Generator().manual_seed(5)
    )
    t = (new_pos - pos).abs().amax(0)
    assert t[1] == 0 and 0.08 < t[0] <= 0.1 + 1e-6 and 0.015 < t[2] <= 0.02 + 1e-6
    per_sample = torch.zeros(400, 3)
    per_sample[:200] = 0.05  # half the batch still, half moved by up to 5 cm on every axis
    _, new_pos, _, _ = se3_augment(points, pos, quat, BOUNDS, xyz_range=per_sample)
    moved = (new_pos - pos).abs()
    assert moved[200:].max() == 0 and 0.04 < moved[:200].max() <= 0.05 + 1e-6


def test_generator_makes_it_reproducible_and_nan_stays_nan() -> None:
    points, pos, quat = _sample(4, 4)
    points[0, 0] = float("nan")
    a = se3_augment(points, pos, quat, BOUNDS, generator=torch.Generator().manual_seed(5))
    b = se3_augment(points, pos, quat, BOUNDS, generator=torch.Generator().manual_seed(5))
    for x, y in zip(a, b, strict=True):
        torch.testing.assert_close(x, y, equal_nan=True)
    assert torch.isnan(a[0][0, 0]).all() and torch.isfinite(a[0][0, 1:]).all()


def test_bad_shapes_raise() -> None:
    with pytest.raises(ValueError, match="pos"):
        se3_augment(torch.zeros(2, 5, 3), torch.zeros(3, 3), torch.zeros(2, 4), BOUNDS)


def test_render_noise_moves_the_seven_rendered_channels_within_its_range_and_leaves_the_pixel_ids() -> None:
    torch.manual_seed(0)
    views = torch.rand(3, 5, 10, 8, 8) * 1.8 - 0.9
    noisy = add_render_noise(views, 0.1)
    assert torch.equal(noisy[:, :, NOISY_CHANNELS:], views[:, :, NOISY_CHANNELS:])
    change = (noisy[:, :, :NOISY_CHANNELS] - views[:, :, :NOISY_CHANNELS]).abs()
    assert 0 < change.max() <= 0.1 and noisy.abs().max() <= 1.0
    assert add_render_noise(views, 0.0) is views
