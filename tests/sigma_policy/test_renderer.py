"""Virtual-view renderer: exactness against a brute-force reference, projection, channels and batching."""

from __future__ import annotations

import math

import pytest
import torch

from sigma_policy.renderer import VIEW_NAMES, VirtualViewRenderer, project_points


def _reference_uvz(
    p: torch.Tensor, view: str, S: int, k: float = 0.0
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The docs/method.md §4.1 camera table, written out view by view (float32, same arithmetic as documented);
    ``k`` = tan of the side views' tilt: their rows read ``(z + k * depth sign * depth coordinate) / (1 + k)``
    (sigma_policy/views.py)."""
    x, y, z = p.unbind(-1)
    half = S / 2
    if k:
        zf, zb, zl, zr = ((z + k * s * c) / (1 + k) for s, c in ((-1, y), (1, y), (-1, x), (1, x)))
    else:
        zf = zb = zl = zr = z
    table = {
        "top": ((1 + x) * half, (1 - y) * half, 1 - z),
        "front": ((1 - x) * half, (1 - zf) * half, 1 - y),
        "back": ((1 + x) * half, (1 - zb) * half, 1 + y),
        "left": ((1 + y) * half, (1 - zl) * half, 1 - x),
        "right": ((1 - y) * half, (1 - zr) * half, 1 + x),
    }
    return table[view]


def reference_render(
    points: torch.Tensor, feats: torch.Tensor, mask: torch.Tensor, S: int, r: float, k: float = 0.0
) -> torch.Tensor:
    """Brute force: for every pixel test every point (disc of radius r around (u, v) covers the pixel centre,
    view depth >= 0), keep the smallest depth, ties to the lowest index. O(V H W N) per sample; rows are
    processed in chunks to bound memory. Runs on the device of ``points``."""
    B, N, _ = points.shape
    dev = points.device
    F = feats.shape[-1]
    out = torch.zeros(B, 5, 3 + F + 4, S, S, device=dev)
    centres = torch.arange(S, dtype=torch.float32, device=dev) + 0.5
    rr = torch.tensor(r * r, dtype=torch.float32, device=dev)
    inf = torch.tensor(float("inf"), device=dev)
    rows = max(1, 2**24 // max(1, S * N))
    for b in range(B):
        for vi, view in enumerate(VIEW_NAMES):
            u, v, z = _reference_uvz(points[b], view, S, k)
            du = centres[:, None] - u[None, :]  # (W, N)
            zmin = torch.empty(S, S, device=dev)
            winner = torch.empty(S, S, dtype=torch.long, device=dev)
            for r0 in range(0, S, rows):
                dv = centres[r0 : r0 + rows, None] - v[None, :]  # (h, N)
                d2 = dv[:, None, :] ** 2 + du[None, :, :] ** 2  # (h, W, N)
                cover = (d2 < rr) & (z >= 0) & mask[b]
                zc = torch.where(cover, z.expand_as(d2), inf)
                zm = zc.min(-1).values
                idx = torch.arange(N, device=dev).expand_as(d2)
                zmin[r0 : r0 + rows] = zm
                winner[r0 : r0 + rows] = torch.where(cover & (zc == zm[..., None]), idx, N).min(-1).values
            filled = winner < N
            w = winner.clamp(max=N - 1)
            out[b, vi, 0:3] = torch.where(filled, points[b][w].permute(2, 0, 1), 0)
            out[b, vi, 3 : 3 + F] = torch.where(filled, feats[b][w].permute(2, 0, 1), 0)
            depth = torch.where(filled, zmin, 0)
            mean = depth.sum() / filled.sum().clamp(min=1)
            out[b, vi, -4] = torch.where(filled, zmin - mean, -1.0)
            out[b, vi, -3] = torch.linspace(-1, 1, 5, device=dev)[vi]
            out[b, vi, -2] = torch.linspace(-1, 1, S, device=dev)[:, None].expand(S, S)
            out[b, vi, -1] = torch.linspace(-1, 1, S, device=dev)[None, :].expand(S, S)
    return out


def _random_cloud(B: int, N: int, seed: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    pts = torch.rand(B, N, 3, generator=g) * 2 - 1
    # A few exact duplicates and points on the cube faces exercise ties and the z >= 0 boundary.
    pts[:, 1] = pts[:, 0]
    pts[:, 2, 2] = 1.0
    pts[:, 3, 0] = -1.0
    # Points slightly outside the cube (not cropped) are drawn in the views that see them from the front.
    pts[:, 4] = torch.tensor([1.02, 0.3, -0.4])
    feats = torch.rand(B, N, 3, generator=g)
    mask = torch.rand(B, N, generator=g) > 0.1
    return pts, feats, mask


@pytest.mark.parametrize(("S", "r"), [(48, 1.32), (31, 0.5), (40, 2.3), (32, 1.0)])
def test_matches_brute_force_reference(S: int, r: float) -> None:
    pts, feats, mask = _random_cloud(B=2, N=1500, seed=S)
    renderer = VirtualViewRenderer(img_size=S, radius_px=r)
    got = renderer(pts, feats, mask)
    want = reference_render(pts, feats, mask, S, r)
    assert got.shape == (2, 5, 10, S, S)
    torch.testing.assert_close(got, want, rtol=0, atol=1e-6)
    # The default 220 px / 1.32 px geometry leaves few pixels empty at this density, so the check is not vacuous.
    assert (got[:, :, 6] != -1).float().mean() > 0.3


@pytest.mark.parametrize(("S", "tilt"), [(48, 45.0), (33, 30.0)])
def test_tilted_side_views_match_brute_force_reference(S: int, tilt: float) -> None:
    pts, feats, mask = _random_cloud(B=2, N=1500, seed=S + 7)
    got = VirtualViewRenderer(img_size=S, side_tilt_deg=tilt)(pts, feats, mask)
    want = reference_render(pts, feats, mask, S, 1.32, k=math.tan(math.radians(tilt)))
    torch.testing.assert_close(got, want, rtol=0, atol=1e-6)
    assert not torch.equal(got[:, 1:], reference_render(pts, feats, mask, S, 1.32)[:, 1:])  # the tilt shows


@pytest.mark.parametrize("tilt", [0.0, 30.0])
@pytest.mark.parametrize("views", [(0, 1, 3), (0, 2, 4), (0, 1, 2, 4)])
def test_fewer_views_are_those_views_of_the_five(views: tuple[int, ...], tilt: float) -> None:
    """RVT-2's three views (or any set with the top view): each rendered view is the same view of the five-view
    render, pixel for pixel, except the view-id channel, which spans [-1, 1] over the views rendered; projections
    agree too."""
    pts, feats, mask = _random_cloud(B=2, N=1200, seed=len(views) + int(tilt))
    S = 36
    five = VirtualViewRenderer(img_size=S, side_tilt_deg=tilt)(pts, feats, mask).clone()
    renderer = VirtualViewRenderer(img_size=S, side_tilt_deg=tilt, views=views)
    got = renderer(pts, feats, mask)
    assert got.shape == (2, len(views), 10, S, S) and renderer.num_views == len(views)
    keep = [c for c in range(10) if c != 7]
    torch.testing.assert_close(got[:, :, keep], five[:, list(views)][:, :, keep], rtol=0, atol=0)
    ids = torch.linspace(-1, 1, len(views))
    assert torch.equal(got[0, :, 7, 0, 0], ids)
    torch.testing.assert_close(renderer.project(pts), project_points(pts, S, tilt)[0][:, :, list(views)])


@pytest.mark.parametrize("views", [(0, 0, 1, 3), (0, 3, 1), (0, 5), ()])
def test_bad_view_sets_raise(views: tuple[int, ...]) -> None:
    with pytest.raises(ValueError, match="views"):
        VirtualViewRenderer(img_size=8, views=views)


@pytest.mark.parametrize("scatter_mode", ["dummy", "spread", "compact"])
@pytest.mark.parametrize(("S", "r"), [(40, 1.32), (29, 0.6)])
def test_scatter_modes_match_brute_force_reference(scatter_mode: str, S: int, r: float) -> None:
    """Every strategy for the candidates outside a disc (CPU default, CUDA default, masked) renders the same."""
    pts, feats, mask = _random_cloud(B=2, N=700, seed=S + 1)
    pts[0, 5:9] = float("nan")  # non-finite points are ignored even where the mask keeps them
    pts[1, 5] = torch.tensor([40.0, -35.0, 1e30])  # far outside every image
    got = VirtualViewRenderer(img_size=S, radius_px=r, scatter_mode=scatter_mode)(pts, feats, mask)
    torch.testing.assert_close(
        got, reference_render(pts, feats, mask & pts.isfinite().all(-1), S, r), rtol=0, atol=1e-6
    )


def test_zbuffer_index_and_depth_match_forward() -> None:
    """zbuffer(): winners index into N (-1 where empty) and carry their own view depth (+inf where empty)."""
    pts, feats, mask = _random_cloud(B=2, N=600, seed=11)
    renderer = VirtualViewRenderer(img_size=36)
    index, depth = renderer.zbuffer(pts, mask)
    img = renderer(pts, feats, mask)
    empty = index < 0
    assert torch.equal(empty, img[:, :, 6] == -1) and bool(depth[empty].isinf().all())
    assert bool(mask.gather(1, index.clamp_min(0).flatten(1)).view_as(index)[~empty].all())
    _, z = project_points(pts, 36)  # (B, N, V) view depths
    for b in range(2):
        for v in range(5):
            win = index[b, v][~empty[b, v]]
            assert torch.equal(depth[b, v][~empty[b, v]], z[b, win, v])
            torch.testing.assert_close(img[b, v, 0:3][:, ~empty[b, v]], pts[b, win].t(), rtol=0, atol=0)


def test_matches_reference_at_paper_resolution_sparse() -> None:
    pts, feats, mask = _random_cloud(B=1, N=300, seed=0)
    got = VirtualViewRenderer()(pts, feats, mask)
    want = reference_render(pts, feats, mask, 220, 1.32)
    torch.testing.assert_close(got, want, rtol=0, atol=1e-6)


def test_batch_is_independent_and_padding_is_ignored() -> None:
    pts, feats, mask = _random_cloud(B=3, N=800, seed=7)
    renderer = VirtualViewRenderer(img_size=40)
    batched = renderer(pts, feats, mask)
    for b in range(3):
        keep = mask[b]
        single = renderer(pts[b : b + 1, keep], feats[b : b + 1, keep], None)
        torch.testing.assert_close(batched[b : b + 1], single, rtol=0, atol=1e-6)
    # Garbage (NaN) in masked-out rows changes nothing.
    pts2 = pts.clone()
    pts2[~mask] = float("nan")
    torch.testing.assert_close(renderer(pts2, feats, mask), batched, rtol=0, atol=0)


def test_project_lands_in_rasterised_pixel() -> None:
    """A lone point shows up exactly in pixel (floor(v), floor(u)) of every view, with its own xyz and depth."""
    S = 220
    renderer = VirtualViewRenderer(
        img_size=S, radius_px=0.5
    )  # r = 0.5: only the point's own pixel can be hit
    g = torch.Generator().manual_seed(3)
    for _ in range(20):
        p = torch.rand(1, 1, 3, generator=g) * 1.9 - 0.95
        uv = renderer.project(p)[0, 0]  # (V, 2)
        img = renderer(p, torch.ones(1, 1, 3), None)[0]
        for v in range(5):
            filled = (img[v, 6] != -1).nonzero()
            col, row = int(uv[v, 0].floor()), int(uv[v, 1].floor())
            # r = 0.5 covers only the own pixel (or nothing if the point sits exactly on a pixel corner region).
            if len(filled):
                assert filled.tolist() == [[row, col]], VIEW_NAMES[v]
                torch.testing.assert_close(img[v, 0:3, row, col], p[0, 0])
                assert img[v, 6, row, col] == 0  # single point: depth minus its own mean


def test_view_geometry_matches_spec_table() -> None:
    """Hard-coded camera table of docs/method.md §4.1 at the cube's corners and centre."""
    renderer = VirtualViewRenderer(img_size=220)
    p = torch.tensor([[[0.0, 0.0, 0.0], [1.0, -1.0, 0.5]]])
    uv = renderer.project(p)[0]
    assert torch.equal(uv[0], torch.full((5, 2), 110.0))
    x, y, z = 1.0, -1.0, 0.5
    expected = [
        (110 * (1 + x), 110 * (1 - y)),
        (110 * (1 - x), 110 * (1 - z)),
        (110 * (1 + x), 110 * (1 - z)),
        (110 * (1 + y), 110 * (1 - z)),
        (110 * (1 - y), 110 * (1 - z)),
    ]
    torch.testing.assert_close(uv[1], torch.tensor(expected))


def test_nearer_point_occludes_and_channels() -> None:
    """Two points on the top view's ray: the higher (nearer to the +z camera) wins there; the side views see both."""
    renderer = VirtualViewRenderer(img_size=64)
    pts = torch.tensor([[[0.1, 0.2, -0.5], [0.1, 0.2, 0.5]]])
    feats = torch.tensor([[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])
    img = renderer(pts, feats, None)[0]
    u, v = renderer.project(pts)[0, 1, 0]
    assert torch.equal(img[0, 3:6, int(v), int(u)], feats[0, 1])
    assert int((img[1, 6] != -1).sum()) > int((img[0, 6] != -1).sum())  # front view sees two discs
    # Location channels.
    assert torch.equal(img[:, 7, 0, 0], torch.linspace(-1, 1, 5))
    assert img[0, 8, 0, 5] == -1 and img[0, 8, -1, 5] == 1 and img[0, 9, 5, 0] == -1 and img[0, 9, 5, -1] == 1
    # Depth channel: winners' z minus the image mean over filled pixels has zero mean; empty = -1.
    filled = img[:, 6] != -1
    for v in range(5):
        assert abs(float(img[v, 6][filled[v]].mean())) < 1e-6


def test_splat_footprint_is_a_disc() -> None:
    renderer = VirtualViewRenderer(img_size=100, radius_px=2.6)
    img = renderer(torch.zeros(1, 1, 3) + 0.013, torch.ones(1, 1, 3), None)
    count = int((img[0, 0, 6] != -1).sum())
    assert abs(count - math.pi * 2.6**2) < 6  # about pi r^2 pixel centres within the radius


def test_bad_shapes_raise() -> None:
    renderer = VirtualViewRenderer(img_size=16)
    with pytest.raises(ValueError, match="points_cube"):
        renderer(torch.zeros(2, 3), torch.zeros(2, 3), None)
    with pytest.raises(ValueError, match="mask"):
        renderer(torch.zeros(1, 4, 3), torch.zeros(1, 4, 3), torch.ones(1, 5, dtype=torch.bool))
    with pytest.raises(ValueError, match="radius_px"):
        VirtualViewRenderer(radius_px=0)
    with pytest.raises(ValueError, match="scatter_mode"):
        VirtualViewRenderer(scatter_mode="fast")


def test_renders_alternate_between_inference_mode_and_no_grad():
    """Reused CPU scratch memory must not cross torch.inference_mode() boundaries (eval, then a viewer)."""
    gen = torch.Generator().manual_seed(0)
    points = torch.rand(1, 500, 3, generator=gen) * 2 - 1
    feats = torch.rand(1, 500, 3, generator=gen)
    renderer = VirtualViewRenderer(img_size=32)
    with torch.inference_mode():
        first = renderer(points, feats, None).clone()
    with torch.no_grad():
        second = renderer(points, feats, None)
    with torch.inference_mode():
        third = renderer(points, feats, None)
    assert torch.equal(first, second) and torch.equal(second, third)


@pytest.mark.parametrize("batch", [1, 2, 5])
@pytest.mark.parametrize("threads", [2, 3])
def test_threaded_cpu_render_is_identical_to_serial(batch: int, threads: int):
    """CPU renders split samples among threads; same bits as one thread."""
    gen = torch.Generator().manual_seed(batch)
    points = torch.rand(batch, 3000, 3, generator=gen) * 2.2 - 1.1  # some outside the cube
    points[:, ::7] = points[:, :1]  # many exact depth ties
    feats = torch.rand(batch, 3000, 3, generator=gen)
    renderer = VirtualViewRenderer(img_size=48)
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        serial = renderer(points, feats)
        torch.set_num_threads(threads)
        with torch.inference_mode():
            threaded = renderer(points, feats)
        assert torch.get_num_threads() == threads  # restored after the render
    finally:
        torch.set_num_threads(before)
    assert torch.equal(serial, threaded)


def test_cpu_output_memory_is_reused_only_once_released() -> None:
    """The CPU renderer recycles an output's memory, but never while a view, a NumPy array or autograd holds it."""
    renderer = VirtualViewRenderer(img_size=24)
    pts, feats, mask = _random_cloud(B=1, N=300, seed=5)
    other = pts.flip(-1)
    first = renderer(pts, feats, mask)
    address, want = first.data_ptr(), first.clone()

    view, array = first[:, :, :3], first.numpy()
    del first
    second = renderer(other, feats, mask)
    assert second.data_ptr() != address
    assert torch.equal(view, want[:, :, :3]) and torch.equal(torch.from_numpy(array), want)
    del view, array, second

    third = renderer(pts, feats, mask)  # nothing refers to the first output's memory any more: reused
    assert third.data_ptr() == address and torch.equal(third, want)

    weight = torch.ones((), requires_grad=True)
    loss = (third * weight).sum()  # autograd saves `third` for the weight's gradient
    del third
    renderer(other, feats, mask)
    loss.backward()
    assert weight.grad == want.sum()
