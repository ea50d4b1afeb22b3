"""Rotation geometry: quaternions (xyzw, w >= 0), matrices, extrinsic-xyz Euler angles and 72-bin labels.

Euler convention: scipy's ``"xyz"`` (lower case = extrinsic): rotate about the fixed world x by ``roll``, then y by
``pitch``, then z by ``yaw``, i.e. ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``. Angles are in **degrees** (as RVT's
``quaternion_to_discrete_euler``). Extraction returns roll, yaw in (-180, 180] and pitch in [-90, 90]; at the
gimbal lock (|pitch| = 90) yaw is set to 0 and roll absorbs it.

Rotation labels (docs/method.md §7): Euler angles with the **gimbal fix** (a pitch within 1 degree of +-90 is snapped
to exactly +-90 and the angles are re-derived, so yaw = 0 and roll carries the remaining freedom), then
``bin = round((angle + 180) / res) mod num_bins`` with ``res = 360 / num_bins`` (5 degrees for 72 bins); bin ``i``
decodes to ``i * res - 180`` degrees.
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = [
    "bins_to_quat",
    "euler_xyz_to_matrix",
    "euler_xyz_to_quat",
    "gimbal_fixed_euler",
    "matrix_to_quat",
    "normalize_quat",
    "quat_to_bins",
    "quat_to_euler_xyz",
    "quat_to_matrix",
]

GIMBAL_TOLERANCE_DEG = 1.0


def normalize_quat(q: Tensor) -> Tensor:
    """Unit quaternion ``(..., 4)`` xyzw with ``w >= 0`` (q and -q are the same rotation)."""
    if q.shape[-1] != 4:
        raise ValueError(f"quaternion must be (..., 4) xyzw, got {tuple(q.shape)}")
    norm = q.norm(dim=-1, keepdim=True)
    if not bool((norm > 1e-12).all()):
        raise ValueError("cannot normalise a zero quaternion")
    q = q / norm
    return torch.where(q[..., 3:4] < 0, -q, q)


def quat_to_matrix(q: Tensor) -> Tensor:
    """Rotation matrices ``(..., 3, 3)`` from quaternions ``(..., 4)`` xyzw (normalised first)."""
    x, y, z, w = normalize_quat(q).unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
            2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
            2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).unflatten(-1, (3, 3))  # fmt: skip


def matrix_to_quat(R: Tensor) -> Tensor:
    """Quaternions ``(..., 4)`` xyzw, ``w >= 0``, from rotation matrices ``(..., 3, 3)``.

    Numerically stable: all four candidate solutions are formed and the one with the largest denominator kept.
    """
    if R.shape[-2:] != (3, 3):
        raise ValueError(f"rotation matrices must be (..., 3, 3), got {tuple(R.shape)}")
    m = R.unbind(-1)
    m00, m10, m20 = m[0].unbind(-1)
    m01, m11, m21 = m[1].unbind(-1)
    m02, m12, m22 = m[2].unbind(-1)
    # 4 * (x^2, y^2, z^2, w^2), each from the diagonal.
    sq = torch.stack(
        [1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22, 1 + m00 + m11 + m22], dim=-1
    ).clamp_min(0)
    candidates = torch.stack(
        [
            torch.stack([sq[..., 0], m01 + m10, m02 + m20, m21 - m12], -1),  # from x
            torch.stack([m01 + m10, sq[..., 1], m12 + m21, m02 - m20], -1),  # from y
            torch.stack([m02 + m20, m12 + m21, sq[..., 2], m10 - m01], -1),  # from z
            torch.stack([m21 - m12, m02 - m20, m10 - m01, sq[..., 3]], -1),  # from w
        ],
        dim=-2,
    )  # (..., 4, 4): row k = 4 q_k * q
    best = sq.argmax(-1, keepdim=True)
    q = torch.gather(candidates, -2, best[..., None].expand(*best.shape, 4)).squeeze(-2)
    return normalize_quat(q)


def _axis_rotation(angle: Tensor, axis: int) -> Tensor:
    c, s = torch.cos(angle), torch.sin(angle)
    one, zero = torch.ones_like(angle), torch.zeros_like(angle)
    if axis == 0:
        rows = (one, zero, zero, zero, c, -s, zero, s, c)
    elif axis == 1:
        rows = (c, zero, s, zero, one, zero, -s, zero, c)
    else:
        rows = (c, -s, zero, s, c, zero, zero, zero, one)
    return torch.stack(rows, -1).unflatten(-1, (3, 3))


def euler_xyz_to_matrix(euler_deg: Tensor) -> Tensor:
    """``(..., 3)`` extrinsic xyz angles in degrees -> ``(..., 3, 3)`` = ``Rz @ Ry @ Rx``."""
    a = torch.deg2rad(euler_deg)
    return _axis_rotation(a[..., 2], 2) @ _axis_rotation(a[..., 1], 1) @ _axis_rotation(a[..., 0], 0)


def euler_xyz_to_quat(euler_deg: Tensor) -> Tensor:
    """``(..., 3)`` extrinsic xyz (roll, pitch, yaw) in degrees -> quaternions ``(..., 4)`` xyzw, ``w >= 0``."""
    return matrix_to_quat(euler_xyz_to_matrix(euler_deg))


def _matrix_to_euler_xyz(R: Tensor) -> Tensor:
    sin_pitch = (-R[..., 2, 0]).clamp(-1, 1)
    pitch = torch.asin(sin_pitch)
    cos_pitch = torch.sqrt(R[..., 2, 1] ** 2 + R[..., 2, 2] ** 2)
    locked = cos_pitch < 1e-6
    roll = torch.atan2(R[..., 2, 1], R[..., 2, 2])
    yaw = torch.atan2(R[..., 1, 0], R[..., 0, 0])
    # Gimbal lock: R = Rz(yaw) Ry(+-90) Rx(roll) depends on roll -+ yaw only; set yaw = 0 and solve roll.
    roll_locked = torch.where(
        sin_pitch > 0, torch.atan2(R[..., 0, 1], R[..., 1, 1]), -torch.atan2(R[..., 0, 1], R[..., 1, 1])
    )
    roll = torch.where(locked, roll_locked, roll)
    yaw = torch.where(locked, torch.zeros_like(yaw), yaw)
    return torch.rad2deg(torch.stack([roll, pitch, yaw], dim=-1))


def quat_to_euler_xyz(q: Tensor) -> Tensor:
    """Quaternions ``(..., 4)`` xyzw -> extrinsic xyz angles ``(..., 3)`` (roll, pitch, yaw) in degrees."""
    return _matrix_to_euler_xyz(quat_to_matrix(q))


def gimbal_fixed_euler(q: Tensor) -> Tensor:
    """:func:`quat_to_euler_xyz` (float64) with a pitch within ``GIMBAL_TOLERANCE_DEG`` of ±90° snapped to ±90° and
    roll and yaw re-derived there: the angles the rotation head classifies (:func:`quat_to_bins`)."""
    euler = quat_to_euler_xyz(q.double())
    pitch = euler[..., 1]
    near = (pitch.abs() > 90 - GIMBAL_TOLERANCE_DEG) & (pitch.abs() < 90 + GIMBAL_TOLERANCE_DEG)
    snapped = euler.clone()
    snapped[..., 1] = torch.where(near, torch.sign(pitch) * 90, pitch)
    # Re-derive: exact +-90 puts the rotation in gimbal lock, where extraction sets yaw = 0.
    rederived = _matrix_to_euler_xyz(euler_xyz_to_matrix(snapped))
    fixed = torch.where(near[..., None], rederived, euler)
    fixed[..., 1] = torch.where(near, torch.sign(pitch) * 90, fixed[..., 1])
    return fixed


def quat_to_bins(q: Tensor, num_bins: int = 72) -> Tensor:
    """Discretise quaternions ``(B, 4)`` xyzw into ``(B, 3)`` long Euler bins (roll, pitch, yaw), gimbal-fixed."""
    if 360 % num_bins:
        raise ValueError(f"num_bins must divide 360, got {num_bins}")
    res = 360 / num_bins
    euler = gimbal_fixed_euler(q)
    return (torch.round((euler + 180) / res).long() % num_bins).to(q.device)


def bins_to_quat(bins: Tensor, num_bins: int = 72) -> Tensor:
    """Decode ``(B, 3)`` Euler bins to quaternions ``(B, 4)`` xyzw, ``w >= 0``: angle = ``bin * res - 180``."""
    res = 360 / num_bins
    euler = bins.double() * res - 180
    return euler_xyz_to_quat(euler).float()
