"""Zoomed second stage (sigma addition after RVT-2's coarse-to-fine, Goyal et al., RSS 2024,
https://arxiv.org/abs/2406.08545; off in every preset; ``zoom_box_m`` in configuration_sigma.py).

A task box rendered at 64² pixels gives 1.56 cm pixels on a 1 m box: PickPlace's bread and can are 3-6 pixels wide
in the top view (docs/learning.md, "Where the object's identity is lost"), and NutAssembly's 0.7 m box gives 1.1 cm
pixels. RVT-2 predicts a coarse point in the whole scene, then renders the views again in a small box around it and
predicts there. sigma does the same with one network that learns both scales:

* inference: the first pass renders the task box; the second renders a cube of ``side`` metres (at most the task
  box's x extent) centred on the first pass's point (:func:`cube_around`), and its prediction (position, rotation,
  gripper, collision) is the action;
* training: a share of the samples (:func:`training_boxes`) is rendered in such a cube, centred on the target moved
  by up to ``jitter`` metres per axis (uniform), the error the first pass leaves; the others in their task box. The
  network reads the box's side and where its centre is in the task box in its proprio token (:func:`box_code`,
  ``SigmaPolicy._proprio``), so it knows which scale it sees and where.

The cameras bound the useful zoom: a point is splatted over ``render_radius_px`` pixels whatever the box, so a cube
whose pixels are finer than the cameras' point spacing shows holes, not detail (docs/method.md §14.2). Measured on
the suite (docs/learning.md, "A zoomed second stage"): one network for both scales fitted the keyframes about three
times worse than without the zoom, so the option is off in every preset.
"""

from __future__ import annotations

import torch
from torch import Tensor

from sigma_policy.pointcloud import world_to_cube

__all__ = ["box_code", "box_side", "check_zoom", "cube_around", "training_boxes"]


def check_zoom(side: float, share: float, jitter: float) -> None:
    """ValueError unless ``side`` is 0 (off) or positive with ``share`` in (0, 1) and ``jitter`` in [0, side / 2)."""
    if side < 0:
        raise ValueError(f"policy.zoom_box_m must be >= 0 (0 = off), got {side}")
    if side == 0:
        return
    if not 0.0 < share < 1.0:
        raise ValueError(f"policy.zoom_share must be in (0, 1) with zoom_box_m > 0, got {share}")
    if not 0.0 <= jitter < side / 2:
        raise ValueError(
            f"policy.zoom_jitter_m must be in [0, zoom_box_m / 2) = [0, {side / 2:g}) so the target stays in the "
            f"zoomed box, got {jitter}"
        )


def cube_around(centre: Tensor, side: float, bounds: Tensor | None = None) -> Tensor:
    """(B, 6) boxes ``(xmin, ymin, zmin, xmax, ymax, zmax)``: cubes of ``side`` metres centred on ``centre`` (B, 3), or
    of the x extent of ``bounds`` (B, 6) where that is smaller (a second stage never sees coarser pixels than the
    first)."""
    half = torch.full_like(centre[:, :1], side / 2)
    if bounds is not None:
        half = torch.minimum(half, box_side(bounds).to(half) / 2)
    return torch.cat([centre - half, centre + half], dim=-1)


def box_side(bounds: Tensor) -> Tensor:
    """(B, 1) the x extent (metres) of boxes (B, 6)."""
    return bounds[:, 3:4] - bounds[:, 0:1]


def box_code(bounds: Tensor, task_bounds: Tensor) -> Tensor:
    """(B, 4) what the proprio token reads about the box a sample is rendered in: its side (metres) and its centre in
    the task box's cube coordinates (``pointcloud.world_to_cube``, as the grip site's; 0 for the task box itself).
    Without the centre a zoomed view of a target in free space (lift the cube, go to the bin's quadrant) shows nothing
    to find the target by, and the second stage falls back on the cube's centre: the first stage's error plus the
    training jitter."""
    centre = (bounds[:, :3] + bounds[:, 3:]) / 2
    return torch.cat([box_side(bounds), world_to_cube(centre, task_bounds.to(centre))], dim=-1)


def training_boxes(
    bounds: Tensor,
    target: Tensor,
    side: float,
    share: float,
    jitter: float,
    generator: torch.Generator | None = None,
) -> tuple[Tensor, Tensor]:
    """Each sample's training box: with probability ``share`` a cube of ``side`` metres (at most its box's x extent)
    centred on ``target`` (B, 3, after augmentation) moved by U(-jitter, jitter) per axis, else its ``bounds`` (B, 6).
    Returns ``(boxes (B, 6), zoomed (B,) bool)``."""
    B = target.shape[0]
    dev, dtype = target.device, target.dtype
    gen_dev = generator.device if generator is not None else dev
    u = torch.rand(B, 4, generator=generator, device=gen_dev).to(device=dev, dtype=dtype)
    zoomed = u[:, 0] < share
    centre = target + (u[:, 1:] * 2 - 1) * jitter
    bounds = bounds.to(dtype).expand(B, 6)
    boxes = torch.where(zoomed[:, None], cube_around(centre, side, bounds), bounds)
    return boxes, zoomed
