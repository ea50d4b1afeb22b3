"""Gaussian heatmap targets and the factorised heatmap -> 3D point back-projection."""

from __future__ import annotations

import pytest
import torch

from sigma_policy.heatmap import gaussian_heatmaps, heatmap_to_cube_point, voxel_centres
from sigma_policy.renderer import VirtualViewRenderer


def test_gaussian_heatmap_properties() -> None:
    uv = torch.tensor([[[10.5, 20.5], [0.2, 219.9], [-30.0, 5.0], [110.0, 110.0], [3.7, 4.1]]])
    hm = gaussian_heatmaps(uv, 220, sigma=1.5)
    assert hm.shape == (1, 5, 220, 220)
    sums = hm.sum((-2, -1))[0]
    torch.testing.assert_close(sums[[0, 1, 3, 4]], torch.ones(4))
    assert sums[2] == 0  # more than 3 sigma outside the image
    assert hm[0, 0].argmax() == 20 * 220 + 10  # peak at the pixel whose centre is the target
    # Zero beyond 3 sigma of the target, positive within.
    rows, cols = torch.meshgrid(torch.arange(220) + 0.5, torch.arange(220) + 0.5, indexing="ij")
    d = ((cols - 10.5) ** 2 + (rows - 20.5) ** 2).sqrt()
    assert (hm[0, 0][d > 4.5] == 0).all() and (hm[0, 0][d <= 4.5] > 0).all()


@pytest.mark.parametrize("S", [220, 64])
def test_round_trip_point_heatmap_point_within_half_voxel(S: int) -> None:
    renderer = VirtualViewRenderer(img_size=S)
    g = torch.Generator().manual_seed(S)
    pts = torch.rand(12, 1, 3, generator=g) * 1.98 - 0.99
    uv = renderer.project(pts)[:, 0]  # (B, V, 2)
    logits = torch.log(gaussian_heatmaps(uv, S) + 1e-12)
    got = heatmap_to_cube_point(logits, S)
    err = (got - pts[:, 0]).abs().max()
    assert err <= 1 / S + 1e-5, err  # half a voxel = 1/S cube units


@pytest.mark.parametrize("S", [64, 32])
def test_subvoxel_refinement_recovers_points_between_voxel_centres(S: int) -> None:
    """Gaussian targets (the training labels) at random sub-voxel positions: the argmax voxel centre is up to
    half a voxel off per axis; the refined point is several times closer."""
    renderer = VirtualViewRenderer(img_size=S)
    pts = torch.rand(32, 1, 3, generator=torch.Generator().manual_seed(S)) * 1.8 - 0.9
    logits = torch.log(gaussian_heatmaps(renderer.project(pts)[:, 0], S) + 1e-12)
    coarse = (heatmap_to_cube_point(logits, S) - pts[:, 0]).norm(dim=-1)
    fine = (heatmap_to_cube_point(logits, S, refine_px=2) - pts[:, 0]).norm(dim=-1)
    voxel = 2 / S
    assert coarse.mean() > 0.3 * voxel and fine.mean() < 0.1 * voxel, (
        coarse.mean() / voxel,
        fine.mean() / voxel,
    )
    # At the grid border the window is clipped and the estimate stays finite and inside the cube.
    edge = torch.tensor([[[0.999, -0.999, 0.0]]])
    got = heatmap_to_cube_point(
        torch.log(gaussian_heatmaps(renderer.project(edge)[:, 0], S) + 1e-12), S, refine_px=2
    )
    assert torch.isfinite(got).all() and (got.abs() <= 1).all()


@pytest.mark.parametrize(("S", "tilt"), [(64, 45.0), (32, 30.0)])
def test_tilted_views_round_trip_and_refine(S: int, tilt: float) -> None:
    """With tilted side views (rows between voxel rows, read by interpolation) Gaussian targets at random points
    back-project to the argmax voxel within a voxel, and the refinement brings them to a small part of one."""
    renderer = VirtualViewRenderer(img_size=S, side_tilt_deg=tilt)
    pts = torch.rand(24, 1, 3, generator=torch.Generator().manual_seed(S)) * 1.8 - 0.9
    logits = torch.log(gaussian_heatmaps(renderer.project(pts)[:, 0], S) + 1e-12)
    voxel = 2 / S
    coarse = (heatmap_to_cube_point(logits, S, side_tilt_deg=tilt) - pts[:, 0]).abs().amax(-1)
    fine = (heatmap_to_cube_point(logits, S, refine_px=2, side_tilt_deg=tilt) - pts[:, 0]).norm(dim=-1)
    assert coarse.max() <= voxel, coarse.max() / voxel
    assert fine.mean() < 0.15 * voxel, fine.mean() / voxel
    # Untilted logits read as if tilted land elsewhere: the decoder follows the views' geometry.
    flat = torch.log(gaussian_heatmaps(VirtualViewRenderer(img_size=S).project(pts)[:, 0], S) + 1e-12)
    wrong = (heatmap_to_cube_point(flat, S, side_tilt_deg=tilt) - pts[:, 0]).norm(dim=-1)
    assert wrong.mean() > 2 * voxel


@pytest.mark.parametrize("fusion", ["sum", "product"])
def test_back_projection_matches_brute_force_grid(fusion: str) -> None:
    """Factorised argmax == argmax over the explicit S^3 voxel grid projected into every view, of the views'
    probabilities (sum) or log-probabilities (product)."""
    S = 24
    renderer = VirtualViewRenderer(img_size=S)
    logits = torch.randn(3, 5, S, S, generator=torch.Generator().manual_seed(0))
    normalise = torch.softmax if fusion == "sum" else torch.log_softmax
    per_view = normalise(logits.flatten(2), -1).view(3, 5, S, S)
    g = voxel_centres(S)
    grid = torch.stack(torch.meshgrid(g, g, g, indexing="ij"), -1).view(1, -1, 3)
    uv = renderer.project(grid)[0].floor().long()  # (S^3, V, 2) pixel (col, row) of each voxel centre
    score = sum(per_view[:, v, uv[:, v, 1], uv[:, v, 0]] for v in range(5))  # (B, S^3)
    want = grid[0][score.argmax(-1)]
    torch.testing.assert_close(heatmap_to_cube_point(logits, S, chunk=5, fusion=fusion), want)


@pytest.mark.parametrize("fusion", ["sum", "product"])
@pytest.mark.parametrize(("views", "tilt"), [((0, 1, 3), 0.0), ((0, 2, 4), 0.0), ((0, 1, 4), 30.0)])
def test_three_views_lift_to_the_point_and_refine(views: tuple[int, ...], tilt: float, fusion: str) -> None:
    """RVT-2's three views (the top and two side views at right angles) still see every axis pair: Gaussian
    targets back-project to the argmax voxel within a voxel and refine to a small part of one, like five views;
    the logits of the five views, read as three, are refused."""
    S = 48
    renderer = VirtualViewRenderer(img_size=S, side_tilt_deg=tilt, views=views)
    pts = torch.rand(24, 1, 3, generator=torch.Generator().manual_seed(3)) * 1.8 - 0.9
    logits = torch.log(gaussian_heatmaps(renderer.project(pts)[:, 0], S) + 1e-12)
    assert logits.shape == (24, 3, S, S)
    voxel = 2 / S
    kw = {"side_tilt_deg": tilt, "fusion": fusion, "views": views}
    coarse = (heatmap_to_cube_point(logits, S, **kw) - pts[:, 0]).abs().amax(-1)
    fine = (heatmap_to_cube_point(logits, S, refine_px=2, **kw) - pts[:, 0]).norm(dim=-1)
    assert coarse.max() <= voxel, coarse.max() / voxel
    # a tilted view's rows are read by interpolation: 0.16 voxel with three views at 30° (sum), 0.07 untilted
    assert fine.mean() < (0.15 if tilt == 0 else 0.2) * voxel, fine.mean() / voxel
    with pytest.raises(ValueError, match=r"\(B, 3, 48, 48\)"):
        heatmap_to_cube_point(torch.zeros(1, 5, S, S), S, views=views)


def test_bad_shape_raises() -> None:
    with pytest.raises(ValueError, match="logits"):
        heatmap_to_cube_point(torch.zeros(1, 4, 8, 8), 8)


@pytest.mark.parametrize("tilt", [0.0, 30.0])
def test_product_fusion_lets_a_sure_top_view_overrule_side_views(tilt: float) -> None:
    """The first grasp of NutAssembly (docs/method.md §14.6): the top view is sure of the handle, the four side
    views, which see the nut edge-on, are sure of a place on its ring 10 cm away, and each side view also gives the
    handle a little. Summed probabilities follow the four side views; their product takes the one place every view
    allows."""
    S = 48
    renderer = VirtualViewRenderer(img_size=S, side_tilt_deg=tilt)
    handle, ring = torch.tensor([[[0.2, 0.1, -0.5]]]), torch.tensor([[[0.2, -0.2, -0.5]]])
    at_handle = gaussian_heatmaps(renderer.project(handle)[:, 0], S)
    at_ring = gaussian_heatmaps(renderer.project(ring)[:, 0], S)
    views = 0.8 * at_ring + 0.2 * at_handle
    views[:, 0] = at_handle[:, 0]
    logits = torch.log(views + 1e-6)
    voxel = 2 / S

    def error(options: dict, target: torch.Tensor) -> float:
        return float(
            (
                heatmap_to_cube_point(logits, S, side_tilt_deg=tilt, refine_px=2, **options) - target[:, 0]
            ).norm()
        )

    assert error({}, ring) < voxel  # sum (RVT): the side views win
    assert error({"fusion": "product"}, handle) < voxel
    with pytest.raises(ValueError, match=r"^fusion must be one of \('sum', 'product'\), got 'mean'$"):
        heatmap_to_cube_point(logits, S, fusion="mean")
