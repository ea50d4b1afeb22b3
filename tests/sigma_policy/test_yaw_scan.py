"""The rotation-equivariant yaw scan: exact crops, and turned crops that follow a turn of the scene."""

from __future__ import annotations

import math

import torch

from sigma_policy.renderer import VirtualViewRenderer, project_points
from sigma_policy.yaw_scan import TOP_VIEW, YawScanner, crop_views, turned_crops


def test_view_crops_are_centred_on_the_pixel_holding_the_point_and_read_zeros_outside():
    img = torch.arange(2 * 8 * 8, dtype=torch.float32).reshape(2, 1, 1, 8, 8)
    uv = torch.tensor([[[3.5, 2.5]], [[0.2, 7.9]]])  # u = column: pixels (row 2, col 3) and (row 7, col 0)
    windows = crop_views(img, uv, 4)
    torch.testing.assert_close(windows[0, 0, 0], img[0, 0, 0, 0:4, 1:5])  # the pixel sits at window index 2
    torch.testing.assert_close(windows[1, 0, 0, :3, 2:], img[1, 0, 0, 5:8, 0:2])
    assert windows[1, 0, 0, 3].abs().sum() == 0 and windows[1, 0, 0, :, :2].abs().sum() == 0


def _scene(yaw_deg: float) -> torch.Tensor:
    """An L of points on a plane (a long arm along +x and a short one along +y from the centre), turned by
    ``yaw_deg`` about the vertical through the centre, in cube coordinates (1, N, 3)."""
    long_arm = torch.stack([torch.linspace(0.0, 0.4, 120), torch.zeros(120)], -1)
    short_arm = torch.stack([torch.zeros(60), torch.linspace(0.0, 0.2, 60)], -1)
    xy = torch.cat([long_arm, short_arm]) + 0.01 * torch.randn(
        180, 2, generator=torch.Generator().manual_seed(0)
    )
    a = math.radians(yaw_deg)
    rot = torch.tensor([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    xy = xy @ rot.T
    return torch.cat([xy, torch.full((180, 1), -0.2)], -1)[None]


def test_turning_the_scene_by_a_turns_the_best_crop_by_a():
    """crop_k(scene turned by a) = crop_{k - a}(scene), on views of a real render: with 72 bins and a = 30 degrees the
    crops 6 bins apart match, and those 6 bins the other way (a sign error in the geometry) do not."""
    renderer = VirtualViewRenderer(img_size=64)
    centre = torch.tensor([[[0.0, 0.0, -0.2]]])
    uv = project_points(centre, 64)[0][:, 0]  # (1, V, 2)

    def crops(yaw: float) -> torch.Tensor:
        points = _scene(yaw)
        views = renderer(points, torch.ones_like(points), torch.ones(points.shape[:2], dtype=torch.bool))
        return turned_crops(views[:, TOP_VIEW], uv[:, TOP_VIEW], 24, 72)[0, :, 3:6]  # RGB channels

    base, turned = crops(0.0), crops(30.0)
    matched = (turned.roll(-6, dims=0) - base).abs().mean()
    wrong_way = (turned.roll(6, dims=0) - base).abs().mean()
    assert matched < 0.4 * wrong_way, (matched, wrong_way)


def test_scanner_scores_half_a_turn_from_the_top_view_only():
    scanner = YawScanner(10, 4, 12, 72)
    views = torch.rand(2, 5, 10, 32, 32)
    uv = torch.full((2, 5, 2), 16.0)
    logits = scanner(views, uv)
    assert logits.shape == (2, 72)
    torch.testing.assert_close(logits[:, :36], logits[:, 36:])  # a half turn: the same parallel grasp
    side_views_changed = views.clone()
    side_views_changed[:, 1:] = torch.rand(2, 4, 10, 32, 32)
    torch.testing.assert_close(scanner(side_views_changed, uv), logits)
