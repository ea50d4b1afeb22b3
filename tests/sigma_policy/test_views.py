"""View geometry: RVT's axis-aligned table, and side views tilted down over a container's rim."""

from __future__ import annotations

import math

import pytest
import torch

from sigma_policy.renderer import VirtualViewRenderer
from sigma_policy.views import (
    VIEW_AXES,
    VIEW_NAMES,
    project_points,
    tilted_coordinates,
    view_axes,
    view_indices,
)


def test_no_tilt_is_rvts_table() -> None:
    pts = torch.rand(2, 7, 3) * 2 - 1
    assert view_axes(0.0) == VIEW_AXES
    assert tilted_coordinates(pts, 0.0) is pts
    assert torch.equal(project_points(pts, 64)[0], project_points(pts, 64, 0.0)[0])


def test_tilted_rows_read_the_coordinate_that_is_constant_along_each_ray() -> None:
    """At 45° (k = 1) the front view's rows read (z - y) / 2: moving a point one unit away from the front camera
    (-y) and one unit down (-z) keeps its pixel; columns, depths and the top view are RVT's."""
    S = 64
    p = torch.tensor([[[0.2, 0.3, -0.4], [0.2, -0.3, -1.0]]])
    uv, depth = project_points(p, S, 45.0)
    flat_uv, flat_depth = project_points(p, S)
    torch.testing.assert_close(uv[0, 0, 1], uv[0, 1, 1])  # the front view: one ray
    assert uv[0, 0, 1, 1] == pytest.approx((1 - (-0.4 - 0.3) / 2) * S / 2)
    assert uv[0, 0, 2, 1] == pytest.approx((1 - (-0.4 + 0.3) / 2) * S / 2)  # back: (z + y) / 2
    assert uv[0, 0, 3, 1] == pytest.approx((1 - (-0.4 - 0.2) / 2) * S / 2)  # left: (z - x) / 2
    assert uv[0, 0, 4, 1] == pytest.approx((1 - (-0.4 + 0.2) / 2) * S / 2)  # right: (z + x) / 2
    assert torch.equal(uv[..., 0], flat_uv[..., 0]) and torch.equal(uv[:, :, 0], flat_uv[:, :, 0])
    assert torch.equal(depth, flat_depth)
    # The whole cube stays in every image.
    corners = torch.tensor(
        [[[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]], dtype=torch.float
    )
    for tilt in (10.0, 45.0, 70.0):
        uv = project_points(corners, S, tilt)[0]
        assert uv.min() >= -1e-4 and uv.max() <= S + 1e-4


def _bin_with_a_low_object() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """A dense box-shaped bin (floor at z = -0.6, walls up to z = -0.2) with a low object inside (up to -0.4),
    as cube points; feature 1 marks the object."""
    g = torch.linspace(-0.5, 0.5, 81)
    h = torch.linspace(-0.6, -0.2, 33)
    a, b = torch.meshgrid(g, g, indexing="ij")
    floor = torch.stack([a.flatten(), b.flatten(), torch.full((a.numel(),), -0.6)], -1)
    walls = []
    for fixed in (0, 1):
        for side in (-0.5, 0.5):
            u, z = torch.meshgrid(g, h, indexing="ij")
            w = torch.stack([u.flatten(), u.flatten(), z.flatten()], -1)
            w[:, fixed] = side
            walls.append(w)
    o = torch.linspace(-0.08, 0.08, 9)
    oz = torch.linspace(-0.6, -0.4, 9)
    ox, oy, ozz = torch.meshgrid(o, o, oz, indexing="ij")
    obj = torch.stack([ox.flatten(), oy.flatten(), ozz.flatten()], -1)
    pts = torch.cat([floor, *walls, obj])[None]
    feats = torch.zeros(1, pts.shape[1], 3)
    feats[0, -obj.shape[0] :, 1] = 1.0
    return pts, feats, torch.ones(1, pts.shape[1], dtype=torch.bool)


@pytest.mark.parametrize("tilt", [0.0, 45.0])
def test_tilted_side_views_see_over_a_rim(tilt: float) -> None:
    """Horizontal side views see only the bin's walls; tilted by 45° every side view sees the object inside. The
    top view is the same either way."""
    pts, feats, mask = _bin_with_a_low_object()
    img = VirtualViewRenderer(img_size=48, side_tilt_deg=tilt)(pts, feats, mask)[0]
    object_pixels = (img[:, 4] == 1).sum((-2, -1))  # feature channel 1 (channels: xyz, features, ...)
    assert object_pixels[0] > 0
    if tilt == 0.0:
        assert (object_pixels[1:] == 0).all()
    else:
        assert (object_pixels[1:] > 0).all(), object_pixels
        flat = VirtualViewRenderer(img_size=48)(pts, feats, mask)[0]
        assert torch.equal(img[0], flat[0])


def test_bad_tilt_raises() -> None:
    with pytest.raises(ValueError, match="side_tilt_deg"):
        VirtualViewRenderer(side_tilt_deg=90.0)
    with pytest.raises(ValueError, match="side_tilt_deg"):
        project_points(torch.zeros(1, 1, 3), 8, -5.0)
    assert math.isfinite(project_points(torch.zeros(1, 1, 3), 8, 89.0)[0].sum())


def test_view_sets_are_ordered_and_must_lift_to_a_point() -> None:
    """A set of views is ordered as VIEW_NAMES (the top view first), and must see every axis pair."""
    assert view_indices(list(VIEW_NAMES)) == (0, 1, 2, 3, 4)
    assert view_indices(["left", "front", "top"]) == (0, 1, 3)
    assert view_indices(["right", "top", "back"]) == (0, 2, 4)
    with pytest.raises(ValueError, match=r"unknown view.*'side'"):
        view_indices(["top", "front", "side"])
    with pytest.raises(ValueError, match="twice"):
        view_indices(["top", "front", "left", "front"])
    with pytest.raises(ValueError, match="lacks 'top'"):
        view_indices(["front", "back", "left", "right"])
    with pytest.raises(ValueError, match="needs 'left' or 'right'"):
        view_indices(["top", "front", "back"])
    with pytest.raises(ValueError, match="needs 'front' or 'back' and 'left' or 'right'"):
        view_indices(["top"])


@pytest.mark.parametrize("tilt", [0.0, 45.0])
def test_projections_of_a_view_set_are_those_views_of_the_five(tilt: float) -> None:
    pts = torch.rand(2, 9, 3) * 2 - 1
    uv, z = project_points(pts, 40, tilt)
    uv3, z3 = project_points(pts, 40, tilt, views=(0, 2, 3))
    assert torch.equal(uv3, uv[:, :, [0, 2, 3]]) and torch.equal(z3, z[:, :, [0, 2, 3]])
