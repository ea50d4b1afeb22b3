"""World-frame point clouds from metric depth, workspace cropping and the canonical cube.

Conventions
- Depth is metric z-depth along the optical axis, in metres (robosuite's ``get_real_depth_map`` output).
- Intrinsics ``K`` are 3x3 pinhole matrices in pixels. Pixel index ``(row v, col u)`` has its centre at
  continuous image coordinates ``(u + 0.5, v + 0.5)``: this is robosuite's convention (its ``cx = W / 2``),
  see docs/robosuite.md §3.5. Back-projection: ``x = (u + 0.5 - cx) z / fx``, ``y = (v + 0.5 - cy) z / fy``.
- Extrinsics are camera-to-world 4x4 matrices in OpenCV camera axes (x right, y down, z forward).
- Invalid depth (<= 0, NaN or inf) gives NaN points, which :func:`bounds_mask` rejects.
- Scene bounds are ``(xmin, ymin, zmin, xmax, ymax, zmax)`` in metres. The canonical cube is ``[-1, 1]^3``:
  ``p_cube = (p - mid) * scale`` with ``mid`` the box centre and ``scale = 2 / max extent`` (docs/method.md §3,
  ``place_with_mean=False``), so the longest box axis spans the cube exactly and the others lie inside it.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from sigma_data.contract import STATE_QUAT
from sigma_policy.rotation import quat_to_matrix

__all__ = [
    "PANDA_HAND_BOX",
    "bounds_mask",
    "cloud_box",
    "crop_to_cube",
    "cube_to_world",
    "depth_to_camera_points",
    "depth_to_world_points",
    "drop_points",
    "fuse_cameras",
    "hand_points",
    "in_frame_box",
    "world_to_cube",
]


def depth_to_camera_points(depth: Tensor, intrinsics: Tensor) -> Tensor:
    """Back-project metric depth ``(..., H, W)`` with intrinsics ``(..., 3, 3)`` to camera-frame points.

    Returns ``(..., H, W, 3)`` in metres, OpenCV camera axes; pixels with invalid depth give NaN.
    """
    if depth.ndim < 2:
        raise ValueError(f"depth must be (..., H, W), got shape {tuple(depth.shape)}")
    if intrinsics.shape[-2:] != (3, 3):
        raise ValueError(f"intrinsics must be (..., 3, 3), got shape {tuple(intrinsics.shape)}")
    if not depth.is_floating_point():
        raise TypeError(f"depth must be a floating-point tensor in metres, got {depth.dtype}")
    H, W = depth.shape[-2:]
    K = intrinsics.to(depth.dtype)
    fx, fy = K[..., 0, 0, None, None], K[..., 1, 1, None, None]
    cx, cy = K[..., 0, 2, None, None], K[..., 1, 2, None, None]
    u = torch.arange(W, device=depth.device, dtype=depth.dtype) + 0.5
    v = torch.arange(H, device=depth.device, dtype=depth.dtype)[:, None] + 0.5
    valid = torch.isfinite(depth) & (depth > 0)
    z = torch.where(valid, depth, torch.full_like(depth, float("nan")))
    x = (u - cx) * z / fx
    y = (v - cy) * z / fy
    return torch.stack(torch.broadcast_tensors(x, y, z), dim=-1)


def depth_to_world_points(depth: Tensor, intrinsics: Tensor, extrinsics: Tensor) -> Tensor:
    """World-frame points ``(..., H, W, 3)`` from depth ``(..., H, W)``, K ``(..., 3, 3)`` and camera-to-world
    extrinsics ``(..., 4, 4)`` (OpenCV axes). Invalid depth gives NaN points."""
    if extrinsics.shape[-2:] != (4, 4):
        raise ValueError(f"extrinsics must be (..., 4, 4), got shape {tuple(extrinsics.shape)}")
    cam = depth_to_camera_points(depth, intrinsics)
    E = extrinsics.to(cam.dtype)
    R = E[..., None, :3, :3]  # (..., 1, 3, 3) broadcasts over rows
    t = E[..., None, None, :3, 3]  # (..., 1, 1, 3)
    return torch.einsum("...ij,...wj->...wi", R, cam) + t


def fuse_cameras(points: Tensor, rgb: Tensor) -> tuple[Tensor, Tensor]:
    """Concatenate per-camera clouds: points ``(B, C, H, W, 3)`` and RGB ``(B, C, 3, H, W)`` in [0, 1] give
    ``(B, C*H*W, 3)`` points and ``(B, C*H*W, 3)`` colours, ordered camera-major then row-major."""
    if points.ndim != 5 or points.shape[-1] != 3:
        raise ValueError(f"points must be (B, C, H, W, 3), got {tuple(points.shape)}")
    B, C, H, W, _ = points.shape
    if rgb.shape != (B, C, 3, H, W):
        raise ValueError(f"rgb must be (B, C, 3, H, W) = {(B, C, 3, H, W)}, got {tuple(rgb.shape)}")
    return points.reshape(B, C * H * W, 3), rgb.permute(0, 1, 3, 4, 2).reshape(B, C * H * W, 3)


def in_frame_box(points: Tensor, origin: Tensor, axes: Tensor, box: Sequence[float]) -> Tensor:
    """``(B, N)`` mask of the points ``(B, N, 3)`` inside ``box`` = ``(x_lo, y_lo, z_lo, x_hi, y_hi, z_hi)`` of a
    per-sample frame (origin ``(B, 3)``, axes the columns of ``(B, 3, 3)``)."""
    if len(box) != 6:
        raise ValueError(f"box must be (x_lo, y_lo, z_lo, x_hi, y_hi, z_hi), got {list(box)}")
    b = torch.as_tensor(box, dtype=points.dtype, device=points.device)
    local = torch.einsum("bnj,bji->bni", points - origin[:, None].to(points), axes.to(points))  # R^T (p - o)
    return ((local >= b[:3]) & (local <= b[3:])).all(-1)


def drop_points(points: Tensor, drop: Tensor) -> Tensor:
    """Points ``(B, N, 3)`` with those where ``drop (B, N)`` set to NaN, which :func:`bounds_mask` rejects."""
    return torch.where(drop[..., None], torch.full_like(points, float("nan")), points)


# robosuite's Panda in its grip site's frame (z from the palm to the fingertips, x the closing axis): the hand body
# (22 cm along x, 6.4 cm across, its underside 2.5 cm behind the site) and link 7 (12.4 cm across), from 3 cm
# behind the site to 1 m behind it. benchmarks/bench_visibility.py counts what the views show without it.
PANDA_HAND_BOX = (-0.11, -0.065, -1.0, 0.11, 0.065, -0.03)


def hand_points(points: Tensor, state: Tensor, box: Sequence[float]) -> Tensor:
    """``(B, N)`` mask of the points ``(B, N, 3)`` inside ``box`` of the grip site's frame, read from
    ``observation.state`` rows ``(B, D)``: the site's position ``[:3]`` and its xyzw quaternion (``STATE_QUAT``,
    sigma_data/contract.py)."""
    return in_frame_box(points, state[:, :3], quat_to_matrix(state[:, STATE_QUAT]), box)


def _bounds_tensor(bounds: Tensor | Sequence[float], like: Tensor) -> Tensor:
    b = torch.as_tensor(bounds, dtype=like.dtype, device=like.device)
    if b.shape[-1] != 6 or b.ndim > 2:
        raise ValueError(
            f"bounds must be (6,) or (B, 6) = (xmin, ymin, zmin, xmax, ymax, zmax), got {tuple(b.shape)}"
        )
    if not bool((b[..., 3:] > b[..., :3]).all()):
        raise ValueError(f"bounds must have max > min on every axis, got {b.tolist()}")
    return b


def _expand_per_sample(b: Tensor, pts: Tensor) -> Tensor:
    """(6,) -> broadcastable over pts (..., 3); (B, 6) -> (B, 1, ..., 1, 6) aligned with pts' leading dim."""
    if b.ndim == 1:
        return b
    if pts.ndim < 2 or pts.shape[0] != b.shape[0]:
        raise ValueError(
            f"per-sample bounds {tuple(b.shape)} need points (B, ..., 3), got {tuple(pts.shape)}"
        )
    return b.reshape(b.shape[0], *([1] * (pts.ndim - 2)), 6)


def bounds_mask(pts: Tensor, bounds: Tensor | Sequence[float]) -> Tensor:
    """Boolean ``(B, N)`` mask of points ``(B, N, 3)`` that are finite and inside the closed box ``bounds``
    (``(6,)`` shared or ``(B, 6)`` per sample)."""
    b = _expand_per_sample(_bounds_tensor(bounds, pts), pts)
    inside = (pts >= b[..., :3]) & (pts <= b[..., 3:])
    return inside.all(-1) & torch.isfinite(pts).all(-1)


def _mid_scale(bounds: Tensor | Sequence[float], pts: Tensor) -> tuple[Tensor, Tensor]:
    b = _expand_per_sample(_bounds_tensor(bounds, pts), pts)
    mid = (b[..., :3] + b[..., 3:]) / 2
    scale = 2 / (b[..., 3:] - b[..., :3]).amax(-1, keepdim=True)
    return mid, scale


def world_to_cube(pts: Tensor, bounds: Tensor | Sequence[float]) -> Tensor:
    """Map world points ``(..., 3)`` in metres to the canonical cube: ``(p - mid) * scale``."""
    mid, scale = _mid_scale(bounds, pts)
    return (pts - mid) * scale


def cube_to_world(pts_cube: Tensor, bounds: Tensor | Sequence[float]) -> Tensor:
    """Inverse of :func:`world_to_cube`: ``p / scale + mid`` (metres)."""
    mid, scale = _mid_scale(bounds, pts_cube)
    return pts_cube / scale + mid


def crop_to_cube(
    points: Tensor, colors: Tensor, bounds: Tensor | Sequence[float]
) -> tuple[Tensor, Tensor, Tensor]:
    """The points ``(B, N, 3)`` inside ``bounds`` in cube coordinates, with their colours ``(B, N, C)`` and mask:
    ``(cube (B, M, 3), colors (B, M, C), mask (B, M))``. Only in-bounds points are kept, each sample padded (mask
    False, cube point 0) to the largest count in the batch, so what consumes them costs what the box holds."""
    mask = bounds_mask(points, bounds)
    keep = int(mask.sum(1).max())
    order = torch.argsort(mask.to(torch.int8), dim=1, descending=True, stable=True)[:, :keep]
    points = points.gather(1, order[..., None].expand(-1, -1, 3))
    colors = colors.gather(1, order[..., None].expand(-1, -1, colors.shape[-1]))
    mask = mask.gather(1, order)
    cube = torch.where(mask[..., None], world_to_cube(points, bounds), torch.zeros_like(points))
    return cube, colors, mask


def cloud_box(points: Tensor, bounds: Tensor | Sequence[float]) -> Tensor:
    """``(B, 6)`` per-sample axis-aligned box of the points ``(B, N, 3)`` inside ``bounds`` (RVT-1's evaluation
    centring, ``place_with_mean``)."""
    mask = bounds_mask(points, bounds)
    inf = torch.tensor(float("inf"), device=points.device)
    lo = torch.where(mask[..., None], points, inf).amin(1)
    hi = torch.where(mask[..., None], points, -inf).amax(1)
    if not torch.isfinite(lo).all():
        raise ValueError("place_with_mean_at_eval: a sample has no points inside scene_bounds")
    return torch.cat([lo, hi], -1)
