"""Translation heatmaps: Gaussian targets per view, the factorised heatmap -> 3D point back-projection, and the
heads' reads at a point: features pooled under a heatmap (:func:`heatmap_pool`) and the heads' inputs at the
predicted point (:func:`predicted_uv`, :func:`heads_at_point`).

Pixel convention: the renderer's exact alignment (``sigma_policy.renderer``): continuous coordinates ``(u, v)``,
pixel ``(row i, col j)`` centred at ``(j + 0.5, i + 0.5)``.

Back-projection (docs/method.md §6.2). Candidates are the ``S^3`` cube voxel centres
``g_k = -1 + (2k + 1) / S``. With exact alignment a voxel centre projects exactly onto a pixel centre in every
view (``(1 +- g_k) S / 2 = k + 0.5`` or ``S - k - 0.5``), so RVT's 4-neighbour interpolation reduces to reading
one pixel, and each view's score depends on only two of the three voxel indices. The score of voxel ``(a, b, c)``
is the mean over views of the per-view softmax probabilities at its pixels, evaluated by broadcasting
``top[a, b] + front[a, c] + back[a, c] + left[b, c] + right[b, c]`` in chunks (the rendered views' terms only,
when fewer are rendered: ``views``, sigma_policy/views.py "Fewer views"); the argmax voxel centre is the
prediction. Never a cached 10 M-point grid; peak memory about ``B * chunk * S^2`` floats. With
``fusion="product"`` the per-view maps are log-probabilities instead, so the same sum is the log of the product of
the views' probabilities (docs/method.md §14.6).

Sub-voxel refinement (``refine_px > 0``, not in RVT): the voxel centre quantises each axis to ``box / S`` (0.94 cm
for the ``small`` preset's 64² views of a 0.6 m box). Each axis is seen by two of the three view-pair score maps;
along that axis, through the argmax voxel, the score profile ``p(k)`` within ``refine_px`` voxels is reduced to its
centroid offset ``sum(k p) / sum(p)`` (profile minus its window minimum, so a flat background does not pull the
estimate to the window centre), and the two estimates are averaged.

Tilted side views (``side_tilt_deg`` > 0, sigma_policy/views.py): a side view's rows then read a mix of ``z`` and
the view's depth coordinate, so the score no longer splits into view pairs, and voxel centres no longer land on
pixel centres. Every voxel centre is projected instead (:func:`~sigma_policy.views.project_points`) and reads each
view by linear interpolation between the two pixel rows around it (its column is a pixel centre), ``chunk``
x-slices at a time; the refinement takes the same centroid of the summed score along each axis through the argmax
voxel. A voxel's column depends on one of its indices and its row on two, so the reads come from per-view tables
of ``S`` columns and ``S^2`` rows (cached per size and angle), not from a table over the whole ``S^3`` grid.
"""

from __future__ import annotations

import functools
import math

import torch
from torch import Tensor

from sigma_policy.views import ALL_VIEWS, VIEW_AXES, project_points, tilt_slope

__all__ = [
    "HEATMAP_FUSIONS",
    "check_heatmap_fusion",
    "gaussian_heatmaps",
    "heads_at_point",
    "heatmap_pool",
    "heatmap_to_cube_point",
    "predicted_uv",
    "voxel_centres",
]

# How the views' heatmaps are fused into one score per voxel: "sum" of probabilities (RVT) or "product" (the sum of
# log-probabilities; sigma addition, docs/method.md §14.6).
HEATMAP_FUSIONS: tuple[str, ...] = ("sum", "product")


def check_heatmap_fusion(fusion: str, name: str = "heatmap_fusion") -> str:
    """``fusion`` if it is one of :data:`HEATMAP_FUSIONS`, else a ``ValueError`` naming the option ``name`` (a
    config field, a CLI flag) and the value it got."""
    if fusion not in HEATMAP_FUSIONS:
        raise ValueError(f"{name} must be one of {HEATMAP_FUSIONS}, got '{fusion}'")
    return fusion


def gaussian_heatmaps(uv: Tensor, img_size: int, sigma: float = 1.5) -> Tensor:
    """Gaussian targets ``(B, V, H, W)`` centred at continuous pixel coordinates ``uv (B, V, 2)`` (u = column).

    ``exp(-d^2 / (2 sigma^2))`` with ``d`` the distance from ``(u, v)`` to each pixel centre, zero beyond 3 sigma,
    normalised to sum 1 per view (docs/method.md §6.1). A view whose target lies more than 3 sigma outside the image
    is all zeros.
    """
    if uv.ndim != 3 or uv.shape[-1] != 2:
        raise ValueError(f"uv must be (B, V, 2), got {tuple(uv.shape)}")
    centres = torch.arange(img_size, device=uv.device, dtype=torch.float32) + 0.5
    du2 = (centres - uv[..., 0:1].float()).square()  # (B, V, W)
    dv2 = (centres - uv[..., 1:2].float()).square()  # (B, V, H)
    d2 = dv2[..., :, None] + du2[..., None, :]
    hm = torch.exp(-d2 / (2 * sigma**2))
    hm = torch.where(d2 <= (3 * sigma) ** 2, hm, 0)
    return hm / hm.sum((-2, -1), keepdim=True).clamp_min(1e-12)


def voxel_centres(img_size: int, device: torch.device | str | None = None) -> Tensor:
    """Cube coordinates ``(S,)`` of the voxel centres along one axis: ``-1 + (2k + 1) / S``."""
    return -1 + (2 * torch.arange(img_size, device=device, dtype=torch.float32) + 1) / img_size


def _view_score(per_view: Tensor, view: int, S: int) -> tuple[Tensor, tuple[int, int]]:
    """One view's scores (probabilities, or their logs) re-indexed by voxel indices: returns ``(B, S, S)`` indexed
    ``[k_first, k_second]`` over the two cube axes (sorted) that the view sees, and those axes."""
    u_axis, u_sign, v_axis, v_sign, _, _ = VIEW_AXES[view]
    # Voxel index k along an axis lands on pixel k (sign +1) or S - 1 - k (sign -1).
    img = per_view  # (B, H=rows <- v axis, W=cols <- u axis)
    if v_sign < 0:
        img = img.flip(-2)
    if u_sign < 0:
        img = img.flip(-1)
    if v_axis < u_axis:
        return img, (v_axis, u_axis)
    return img.transpose(-2, -1), (u_axis, v_axis)


def _centroid_offset(profile: Tensor, centre: Tensor, radius: int) -> Tensor:
    """Centroid offset (voxels) of 1D profiles ``(B, S)`` in the window ``centre +- radius`` (clipped to the grid),
    after subtracting each window's minimum; 0 where the window is flat."""
    S = profile.shape[-1]
    offsets = torch.arange(-radius, radius + 1, device=profile.device)
    idx = centre[:, None] + offsets  # (B, 2r + 1)
    inside = (idx >= 0) & (idx < S)
    vals = profile.gather(1, idx.clamp(0, S - 1))
    vals = torch.where(inside, vals, vals.new_full((), math.inf))
    vals = torch.where(inside, vals - vals.min(1, keepdim=True).values, 0)
    total = vals.sum(1)
    return torch.where(total > 0, (vals * offsets).sum(1) / total.clamp_min(1e-12), 0)


def heatmap_to_cube_point(
    logits: Tensor,
    img_size: int,
    chunk: int = 16,
    refine_px: int = 0,
    side_tilt_deg: float = 0.0,
    fusion: str = "sum",
    views: tuple[int, ...] = ALL_VIEWS,
) -> Tensor:
    """Factorised argmax over the ``S^3`` voxel grid of the views' fused score: logits ``(B, V, H, W)`` -> cube
    point ``(B, 3)``: the argmax voxel centre, refined below a voxel when ``refine_px > 0`` (module docstring).
    ``fusion`` (:data:`HEATMAP_FUSIONS`): ``"sum"`` scores a voxel by the sum of its projections' softmax
    probabilities (RVT), ``"product"`` by the sum of their log-probabilities, i.e. their product: every view must
    agree, so four side views sure of a wrong place no longer outvote a top view sure of the right one.
    ``chunk`` x-slices are scored at a time; ``side_tilt_deg`` is the views' tilt; ``views`` the indices into
    :data:`~sigma_policy.views.VIEW_AXES` of the logits' views."""
    B, V, H, W = logits.shape
    S = img_size
    if (len(views), S, S) != (V, H, W):
        raise ValueError(f"logits must be (B, {len(views)}, {S}, {S}), got {tuple(logits.shape)}")
    normalise = torch.softmax if check_heatmap_fusion(fusion, "fusion") == "sum" else torch.log_softmax
    per_view = normalise(logits.float().flatten(2), dim=-1).view(B, V, S, S)  # probabilities, or their logs
    if tilt_slope(side_tilt_deg) > 0.0:
        return _projected_grid_point(per_view, chunk, refine_px, side_tilt_deg, views)
    pair_sum: dict[tuple[int, int], Tensor] = {}
    for i, view in enumerate(views):
        score, axes = _view_score(per_view[:, i], view, S)
        pair_sum[axes] = pair_sum[axes] + score if axes in pair_sum else score
    zeros = torch.zeros(B, S, S, device=logits.device)
    xy, xz, yz = (pair_sum.get(k, zeros) for k in ((0, 1), (0, 2), (1, 2)))
    best_val = torch.full((B,), -math.inf, device=logits.device)
    best_idx = torch.zeros(B, dtype=torch.long, device=logits.device)
    for a0 in range(0, S, chunk):
        a1 = min(S, a0 + chunk)
        score = xy[:, a0:a1, :, None] + xz[:, a0:a1, None, :] + yz[:, None, :, :]  # (B, a, S, S)
        val, idx = score.flatten(1).max(1)
        better = val > best_val
        best_val = torch.where(better, val, best_val)
        best_idx = torch.where(better, idx + a0 * S * S, best_idx)
    a, rem = best_idx // (S * S), best_idx % (S * S)
    b_, c = rem // S, rem % S
    g = voxel_centres(S, logits.device)
    point = torch.stack([g[a], g[b_], g[c]], dim=-1)
    if refine_px <= 0:
        return point
    rows = torch.arange(B, device=logits.device)
    # 1D profiles through the peak: x from xy[:, :, b] and xz[:, :, c]; y from xy[:, a, :] and yz[:, :, c];
    # z from xz[:, a, :] and yz[:, b, :].
    profiles = (
        ((xy[rows, :, b_], a), (xz[rows, :, c], a)),
        ((xy[rows, a, :], b_), (yz[rows, :, c], b_)),
        ((xz[rows, a, :], c), (yz[rows, b_, :], c)),
    )
    shift = torch.stack(
        [sum(_centroid_offset(p, k, refine_px) for p, k in pair) / 2 for pair in profiles], dim=-1
    )
    return point + shift * (2 / S)  # one voxel is 2 / S in cube coordinates


@functools.lru_cache(maxsize=8)
def _view_reads(
    S: int, side_tilt_deg: float, device: torch.device, views: tuple[int, ...]
) -> tuple[Tensor, Tensor, Tensor]:
    """Per view, where a voxel centre reads it: its column ``(V, S)`` by its index along the view's u axis (a
    pixel centre), and the upper of the two pixel rows around its projection with the weight of the lower one,
    ``(V, S * S)`` each, by its indices along the view's v and depth axes (a tilted side view's row mixes the
    two; the top view's ignores the depth). ``V * S^2`` numbers, not a table over the ``S^3`` grid."""
    g = voxel_centres(S, device)
    cols, rows = [], []
    for view in views:
        u_axis, _, v_axis, _, d_axis, _ = VIEW_AXES[view]
        line = torch.zeros(S, 3, device=device)
        line[:, u_axis] = g
        cols.append(project_points(line[None], S, side_tilt_deg)[0][0, :, view, 0].floor().long())
        plane = torch.zeros(S, S, 3, device=device)
        plane[..., v_axis] = g[:, None]
        plane[..., d_axis] = g[None, :]
        rows.append(project_points(plane.reshape(1, -1, 3), S, side_tilt_deg)[0][0, :, view, 1])
    row = (torch.stack(rows) - 0.5).clamp(0, S - 1)
    r0 = row.floor().long().clamp(max=S - 2)
    return torch.stack(cols).clamp(0, S - 1), r0, row - r0


def _voxel_taps(
    voxels: Tensor, S: int, side_tilt_deg: float, views: tuple[int, ...]
) -> tuple[Tensor, Tensor, Tensor]:
    """Where voxel centres (flat x-major indices, any shape ``(...)``) read each view ``(V, ...)``: the flat
    indices of the two pixels in their column that straddle their projection, and the weight of the second
    (linear interpolation along the rows; a voxel centre lands on a pixel centre in columns, and in rows too when
    a view is not tilted)."""
    cols, upper, weight = _view_reads(S, float(side_tilt_deg), voxels.device, views)
    cell = (voxels // (S * S), voxels // S % S, voxels % S)
    i0, w = [], []
    for i, view in enumerate(views):
        u_axis, _, v_axis, _, d_axis, _ = VIEW_AXES[view]
        plane = cell[v_axis] * S + cell[d_axis]
        i0.append(upper[i][plane] * S + cols[i][cell[u_axis]])
        w.append(weight[i][plane])
    i0 = torch.stack(i0)
    return i0, i0 + S, torch.stack(w)


def _projected_grid_point(
    per_view: Tensor, chunk: int, refine_px: int, side_tilt_deg: float, views: tuple[int, ...]
) -> Tensor:
    """:func:`heatmap_to_cube_point` for tilted side views: every voxel centre projected (module docstring)."""
    B, S = per_view.shape[0], per_view.shape[-1]
    flat = per_view.flatten(2)

    def score(voxels: Tensor) -> Tensor:
        """The views' interpolated scores (probabilities, or their logs under product fusion) summed, ``(B, M)``,
        at flat voxel indices ``(M,)``, or ``(B, M)`` per sample."""
        i0, i1, ww = _voxel_taps(voxels, S, float(side_tilt_deg), views)
        if voxels.ndim == 1:
            i0, i1, ww = (t.expand(B, -1, -1) for t in (i0, i1, ww))
        else:
            i0, i1, ww = (t.transpose(0, 1) for t in (i0, i1, ww))
        lo, hi = flat.gather(2, i0), flat.gather(2, i1)
        return (lo + (hi - lo) * ww).sum(1)

    best_val = torch.full((B,), -math.inf, device=per_view.device)
    best_idx = torch.zeros(B, dtype=torch.long, device=per_view.device)
    for a0 in range(0, S, chunk):
        voxels = torch.arange(a0 * S * S, min(S, a0 + chunk) * S * S, device=per_view.device)
        val, idx = score(voxels).max(1)
        better = val > best_val
        best_val = torch.where(better, val, best_val)
        best_idx = torch.where(better, idx + a0 * S * S, best_idx)
    cell = torch.stack([best_idx // (S * S), best_idx // S % S, best_idx % S], -1)  # (B, 3) voxel indices
    point = voxel_centres(S, per_view.device)[cell]
    if refine_px <= 0:
        return point
    steps = torch.arange(S, device=per_view.device)
    shifts = []
    for axis, stride in enumerate((S * S, S, 1)):  # the summed score along each axis through the argmax voxel
        line = (best_idx - cell[:, axis] * stride)[:, None] + steps * stride  # (B, S) flat voxel indices
        shifts.append(_centroid_offset(score(line), cell[:, axis], refine_px))
    return point + torch.stack(shifts, -1) * (2 / S)


def predicted_uv(
    logits: Tensor, side_tilt_deg: float = 0.0, fusion: str = "sum", views: tuple[int, ...] = ALL_VIEWS
) -> Tensor:
    """Pixel coordinates ``(B, V, 2)`` of the projections of the 3D point the translation logits ``(B, V, H, W)``
    predict (:func:`heatmap_to_cube_point` with ``fusion``): the views agree on one point, as the training
    target's projections do, even where one view's own peak lies elsewhere; ``views`` as there."""
    size = logits.shape[-1]
    point = heatmap_to_cube_point(logits, size, side_tilt_deg=side_tilt_deg, fusion=fusion, views=views)
    return project_points(point[:, None].to(logits.dtype), size, side_tilt_deg, views)[0][:, 0]


def heads_at_point(
    logits: Tensor,
    side_tilt_deg: float,
    sigma_px: float,
    fusion: str = "sum",
    views: tuple[int, ...] = ALL_VIEWS,
) -> dict[str, Tensor]:
    """The network's ``head_heatmap`` and ``head_uv`` arguments that run its heads at the point the translation
    logits ``(B, V, H, W)`` predict (:func:`predicted_uv`): pooled there with a Gaussian of ``sigma_px`` pixels, as
    training pools them at the target, and the yaw scan centred there. For a second run of the heads after the
    logits were changed (instruction contrast, ensembles); ``fusion`` and ``views`` as in
    :func:`heatmap_to_cube_point`."""
    uv = predicted_uv(logits, side_tilt_deg, fusion, views)
    return {"head_heatmap": gaussian_heatmaps(uv, logits.shape[-1], sigma=sigma_px), "head_uv": uv}


def heatmap_pool(heatmap: Tensor, features: Tensor) -> Tensor:
    """Per-view sum of ``features`` (B, V, C, H, W) weighted by ``heatmap`` (B, V, H, W) -> (B, V*C), view-major."""
    b, v = heatmap.shape[:2]
    weights = heatmap.reshape(b, v, -1).to(features.dtype)
    return torch.einsum("bvn,bvcn->bvc", weights, features.reshape(b, v, features.shape[2], -1)).flatten(1)
