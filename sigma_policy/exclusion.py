"""Places a keyframe must not go: vertical cylinders about points where a grasp already closed on nothing.

A keyframe policy asked again after an empty grasp (``sigma-eval --regrasps``, pipelines/regrasp.py) sees the
same scene and, being deterministic, answers the same: in the suite's evaluations the retried close came down
within about a centimetre of the failed one in most episodes (docs/learning.md, "Asking again somewhere else").
:meth:`SigmaPolicy.avoid <sigma_policy.modeling_sigma.SigmaPolicy.avoid>` names such points; from then on the
translation is the best voxel of the heatmaps *outside* a vertical cylinder of ``radius_m`` about each
(:func:`~sigma_policy.heatmap.heatmap_to_cube_point`'s ``exclude``), and the rotation, gripper and collision heads
are read at that voxel. A cylinder, not a ball: the approach above a failed close is as wrong as the close.

In cube coordinates (sigma_policy/pointcloud.py: one scale for every axis, ``2 / max extent``) a cylinder of
``radius_m`` metres has the radius ``radius_m * scale``.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from sigma_policy.pointcloud import world_to_cube

__all__ = ["Exclusion"]


@dataclass(frozen=True)
class Exclusion:
    """Vertical cylinders in cube coordinates, per sample: axes at ``centres`` (B, K, 2) (cube x, y) with the
    radius ``radii`` (B,) (cube units)."""

    centres: Tensor
    radii: Tensor

    @classmethod
    def around(cls, points: Tensor, radius_m: float, bounds: Tensor) -> Exclusion:
        """Cylinders of ``radius_m`` metres about world points ``points`` (B, K, 3), for boxes ``bounds`` (B, 6)."""
        if points.ndim != 3 or points.shape[-1] != 3:
            raise ValueError(f"points must be (B, K, 3) world metres, got {tuple(points.shape)}")
        if radius_m <= 0:
            raise ValueError(f"radius_m must be > 0, got {radius_m}")
        extent = (bounds[:, 3:] - bounds[:, :3]).amax(-1)
        return cls(world_to_cube(points, bounds)[..., :2], radius_m * 2 / extent)

    def covers(self, x: Tensor, y: Tensor) -> Tensor:
        """Whether cube points of x ``x`` and y ``y`` lie inside any cylinder: both broadcastable to one shape
        ``(1 or B, ...)`` whose first axis is the sample; returns a bool tensor ``(B, ...)``."""
        shape = torch.broadcast_shapes(x.shape, y.shape)
        lead = (-1,) + (1,) * (len(shape) - 1)
        inside = torch.zeros((), dtype=torch.bool, device=x.device)
        r2 = self.radii.square().view(lead)
        for k in range(self.centres.shape[1]):
            cx, cy = (self.centres[:, k, i].view(lead) for i in (0, 1))
            inside = inside | ((x - cx).square() + (y - cy).square() < r2)
        return inside.expand(self.radii.shape[0], *shape[1:])
