"""Training augmentation: SE(3) (docs/method.md §9, RVT ``apply_se3_aug_con`` version 2), applied consistently to
the point cloud and the action target, and the render noise on the rendered views (:func:`add_render_noise`).

Per sample: a translation ``t`` uniform in ``[-xyz_range, xyz_range]`` metres per axis (RVT scales its 0.125 by the
box extent, which the policy does with ``aug_translation_unit="box"``), clamped so that the target position
``a + t`` stays inside ``bounds`` (a target already outside on an axis may only move back towards the box there),
and a yaw ``theta`` uniform in ``[-yaw_range_deg, yaw_range_deg]`` about the world z axis through the target
(roll = pitch = 0).
With ``R = Rz(theta)`` the rigid transform is ``T(p) = R^T (p - a) + a + t``; points map by ``T``, the target
position to ``a + t`` and the target orientation to ``R^T R_a`` (quaternion xyzw, w >= 0).

RVT applies its gimbal fix to the action rotation before rotating; a yaw about world z leaves the extrinsic-xyz
pitch unchanged, so fixing before or after is the same, and sigma applies it once, in ``quat_to_bins``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import Tensor

from sigma_policy.rotation import matrix_to_quat, quat_to_matrix

__all__ = ["NOISY_CHANNELS", "add_render_noise", "se3_augment"]

NOISY_CHANNELS = 7  # xyz, rgb, depth get the render noise; the 3 pixel-location channels do not


def se3_augment(
    points: Tensor,
    pos: Tensor,
    quat: Tensor,
    bounds: Tensor | Sequence[float],
    xyz_range: float | Tensor = 0.125,
    yaw_range_deg: float = 45.0,
    generator: torch.Generator | None = None,
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Randomly translate and yaw each sample's world cloud ``(B, N, 3)`` and target ``pos (B, 3)``,
    ``quat (B, 4)`` (xyzw), inside ``bounds`` ((6,) shared or (B, 6) per sample); ``xyz_range`` is metres, one for
    every axis or per axis ((3,) or (B, 3)). Returns ``(points', pos', quat', transforms (B, 4, 4))`` where
    ``transforms`` maps old world coordinates to new ones. NaN points stay NaN. Random draws come from
    ``generator`` (on its device) when given."""
    if points.ndim != 3 or points.shape[-1] != 3:
        raise ValueError(f"points must be (B, N, 3), got {tuple(points.shape)}")
    B = points.shape[0]
    if pos.shape != (B, 3) or quat.shape != (B, 4):
        raise ValueError(
            f"pos must be ({B}, 3) and quat ({B}, 4), got {tuple(pos.shape)}, {tuple(quat.shape)}"
        )
    dev, dtype = points.device, points.dtype
    b = torch.as_tensor(bounds, dtype=dtype, device=dev)
    if b.shape not in ((6,), (B, 6)):
        raise ValueError(
            f"bounds must be (6,) or ({B}, 6) = (xmin, ymin, zmin, xmax, ymax, zmax), got {tuple(b.shape)}"
        )
    gen_dev = generator.device if generator is not None else dev
    u = torch.rand(B, 4, generator=generator, device=gen_dev).to(device=dev, dtype=dtype) * 2 - 1
    pos = pos.to(dtype)
    lo = torch.minimum(b[..., :3] - pos, torch.zeros_like(pos))
    hi = torch.maximum(b[..., 3:] - pos, torch.zeros_like(pos))
    if isinstance(xyz_range, Tensor):
        xyz_range = xyz_range.to(device=dev, dtype=dtype)
    t = torch.minimum(torch.maximum(u[:, :3] * xyz_range, lo), hi)
    theta = u[:, 3] * math.radians(yaw_range_deg)
    c, s = torch.cos(theta), torch.sin(theta)
    zero, one = torch.zeros_like(c), torch.ones_like(c)
    R = torch.stack([c, -s, zero, s, c, zero, zero, zero, one], -1).view(B, 3, 3)  # Rz(theta)
    Rt = R.transpose(1, 2)
    transforms = torch.eye(4, dtype=dtype, device=dev).repeat(B, 1, 1)
    transforms[:, :3, :3] = Rt
    transforms[:, :3, 3] = pos + t - (Rt @ pos[:, :, None])[..., 0]
    new_points = points @ R + transforms[:, None, :3, 3]  # row-vector form of R^T p + offset
    new_quat = matrix_to_quat(Rt @ quat_to_matrix(quat.to(dtype)))
    return new_points, pos + t, new_quat, transforms


def add_render_noise(views: Tensor, image_noise: float) -> Tensor:
    """Rendered views ``(B, V, C, H, W)`` with uniform noise U(-s, s), s = ``image_noise`` · U(0, 1) drawn once per
    batch, on channels 0-6 (docs/method.md §4.3), then clamped to [-1, 1]; unchanged when ``image_noise`` <= 0."""
    if image_noise <= 0:
        return views
    stdv = image_noise * torch.rand((), device=views.device)
    noisy = views[:, :, :NOISY_CHANNELS]
    noisy = (noisy + (torch.rand_like(noisy) * 2 - 1) * stdv).clamp(-1, 1)
    return torch.cat([noisy, views[:, :, NOISY_CHANNELS:]], dim=2)
