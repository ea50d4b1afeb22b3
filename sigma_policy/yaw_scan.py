"""A rotation-equivariant yaw head: score every yaw bin by turning a top-view crop (not in the paper).

The rotation head's MLP has to turn an object's outline into an absolute yaw bin, a mapping it learns slowly from
a few dozen scenes: on NutAssembly the grasp yaw over the handle stayed at chance after 2000 steps, on the training
scenes too (docs/learning.md). :class:`YawScanner` asks an easier question, in the way Transporter networks choose a
grasp angle (Zeng et al., "Transporter Networks", CoRL 2020, https://arxiv.org/abs/2010.14406): a crop of the top
view around the keyframe position is turned by every bin's angle and one small CNN scores each turned crop ("does
the scene, seen from a hand at this yaw, look like a grasp?"). The score of bin ``k`` is added to the MLP's yaw
logit ``k``. Turning the scene by ``a`` about the vertical turns the target yaw by ``a`` and moves the best crop by
``a`` as well, so what is learned at one yaw holds at every yaw: the head is equivariant by construction, and yaw
augmentation costs it nothing. Only half a turn is scored and the scores repeat for the other half: a parallel
gripper grasps alike at yaws a half turn apart, and which of the two a demonstration used depends on the wrist's
range, which the crop cannot see and the MLP (given the gripper's orientation) can.

Geometry. The top view (``VIEW_AXES[0]``) has its columns along +x and its rows along -y of the scene box. Bin
``k`` is the yaw ``theta_k = k * 360 / K - 180`` degrees (:mod:`sigma_policy.rotation`), and a world turn by ``a``
about +z adds ``a`` to the gripper's yaw. The crop of bin ``k`` samples the view at ``c + R(theta_k) p`` for the
canonical offsets ``p`` (x, y), ``c`` the keyframe position; in (column, row) coordinates, where y is flipped,
that is ``R(-theta_k)``. So ``crop_k(turned scene) = crop_{k - a}(scene)``: ``test_yaw_scan.py`` checks it on a
rendered cloud. The scene box must have equal x and y extents (the suite's task boxes do), else a turn in the
world is not a turn in the view.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from sigma_policy.layers import ConvBlock, DenseBlock

__all__ = ["YawScanner", "crop_views", "turned_crops"]

TOP_VIEW = 0  # index of the top view in sigma_policy.renderer.VIEW_AXES


def crop_views(images: Tensor, uv: Tensor, size: int) -> Tensor:
    """Windows ``(B, V, C, size, size)`` of ``images`` (B, V, C, H, W) whose pixel ``size // 2`` (per axis) is the
    pixel holding ``uv`` (B, V, 2; u = column, continuous pixel coordinates). Outside the image they read zeros."""
    b, v, c, h, w = images.shape
    half = size // 2
    padded = F.pad(images.reshape(b * v, c, h, w), (half, half, half, half))
    # The pixel holding (u, v) is (floor v, floor u); in the padded image the window starts at that index.
    start = uv.reshape(b * v, 2).detach().floor().long()
    start = torch.stack([start[:, 0].clamp(0, w), start[:, 1].clamp(0, h)], dim=-1)
    offsets = torch.arange(size, device=images.device)
    cols = (start[:, 0:1] + offsets)[:, None, :]  # (BV, 1, size)
    rows = (start[:, 1:2] + offsets)[:, :, None]  # (BV, size, 1)
    index = torch.arange(b * v, device=images.device)[:, None, None]
    windows = padded.permute(0, 2, 3, 1)[index, rows, cols]  # (BV, size, size, C)
    return windows.permute(0, 3, 1, 2).reshape(b, v, c, size, size)


def turned_crops(view: Tensor, uv: Tensor, size: int, num_bins: int, count: int | None = None) -> Tensor:
    """``(B, count, C, size, size)`` crops of one view (B, C, H, W), centred exactly (bilinear) at ``uv`` (B, 2), the
    one of bin ``k`` turned to ``theta_k`` (module docstring) for the first ``count`` of ``num_bins`` bins (None:
    all of them)."""
    b, c = view.shape[:2]
    step, n = 2 * math.pi / num_bins, count or num_bins
    big = 2 * math.ceil(size * math.sqrt(2) / 2) + 2  # holds the turned window, even
    window = crop_views(view[:, None], uv[:, None], big)[:, 0]  # pixel big//2 holds uv
    # uv's place in the window, in grid_sample's normalised coordinates (align_corners=False).
    offset = 2 * (uv.detach().float() - uv.detach().float().floor()) / big  # (B, 2)
    theta = torch.arange(n, device=view.device, dtype=torch.float32) * step - math.pi
    cos, sin = theta.cos(), theta.sin()
    scale = size / big
    affine = torch.zeros(b, n, 2, 3, device=view.device)
    affine[..., 0, 0], affine[..., 0, 1] = scale * cos, scale * sin
    affine[..., 1, 0], affine[..., 1, 1] = -scale * sin, scale * cos
    affine[..., :, 2] = offset[:, None, :]
    grid = F.affine_grid(affine.reshape(b * n, 2, 3), [b * n, c, size, size], align_corners=False)
    source = window[:, None].expand(b, n, *window.shape[1:]).reshape(b * n, *window.shape[1:])
    turned = F.grid_sample(
        source, grid.to(source.dtype), mode="bilinear", padding_mode="zeros", align_corners=False
    )
    return turned.reshape(b, n, c, size, size)


class YawScanner(nn.Module):
    """Yaw-bin logits ``(B, K)`` from the top view: :func:`turned_crops` over half a turn, then one CNN for every
    crop (a 3x3 convolution, two stride-2 ones, the map flattened, since which side of the point an object lies on
    matters, into a scalar); the other half turn repeats the scores."""

    def __init__(self, c_in: int, channels: int, crop_px: int, num_bins: int):
        super().__init__()
        self.crop_px, self.num_bins = crop_px, num_bins
        self.convs = nn.Sequential(
            ConvBlock(c_in, channels, 3),
            ConvBlock(channels, channels, 3, stride=2),
            ConvBlock(channels, channels, 3, stride=2),
        )
        side = crop_px
        for _ in range(2):
            side = (side - 3) // 2 + 1
        self.score = DenseBlock(channels * side * side, 1, act=False)

    def forward(self, images: Tensor, uv: Tensor) -> Tensor:
        """``images`` (B, V, C, H, W) rendered views, ``uv`` (B, V, 2) the keyframe position in each. Bins ``k`` and
        ``k + K/2`` (a half turn apart) get the same score: the parallel gripper grasps the same way at both, and
        which of the two the hand takes depends on its wrist, which the MLP (with the gripper's orientation) knows."""
        half = self.num_bins // 2
        crops = turned_crops(images[:, TOP_VIEW], uv[:, TOP_VIEW], self.crop_px, self.num_bins, count=half)
        b = crops.shape[0]
        maps = self.convs(crops.flatten(0, 1))
        return self.score(maps.flatten(1)).reshape(b, half).repeat(1, 2)
