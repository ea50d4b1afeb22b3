"""Where the virtual views look: which cube coordinates give each view's columns, rows and depth.

RVT's five orthographic views of the canonical cube ``[-1, 1]^3`` (docs/method.md §4.1) look along the cube's
axes: the top view down, the four side views horizontally. For a cube point ``(x, y, z)`` and ``S = img_size``
each image coordinate is ``(1 + sign * coordinate) * S / 2`` and the view depth ``1 + sign * coordinate``:

==========  ==================  ==================  ================
view (idx)  u (column, right)   v (row, down)       view depth
==========  ==================  ==================  ================
top (0)     (1 + x) S/2         (1 - y) S/2         1 - z
front (1)   (1 - x) S/2         (1 - z) S/2         1 - y
back (2)    (1 + x) S/2         (1 - z) S/2         1 + y
left (3)    (1 + y) S/2         (1 - z) S/2         1 - x
right (4)   (1 - y) S/2         (1 - z) S/2         1 + x
==========  ==================  ==================  ================

**Tilted side views** (``side_tilt_deg`` > 0; not in RVT or the paper). A horizontal side view cannot see into a
container: in robosuite's PickPlace the bins' walls rise 8 cm above their floor, and the bread (4.8 cm tall) and
the can (8 cm) stand below the rim, so in all four side views they cover 0-2 pixels against 13-27 for the milk
carton and the cereal box (docs/learning.md "PickPlace: the side views cannot see the bread or the can"). A side
view tilted down by ``θ`` sees over a rim. Its rays descend by ``k = tan θ`` per unit of horizontal travel, so
along a ray ``z + k * depth`` is constant and the view's rows read the coordinate

    ``z_t = (z + k * s_d * c_d) / (1 + k)``

(``c_d`` the view's depth coordinate and ``s_d`` its sign, e.g. ``z_t = (z - k y) / (1 + k)`` for the front view,
whose depth is ``1 - y``), in place of ``z``. The division keeps the whole cube in the image, at the cost of a
``1 + k`` times coarser row direction (2 at 45°). The z-buffer still orders points by the horizontal depth, which
grows along every tilted ray. Such a view is an orthographic camera elevated by ``θ`` whose image is stretched
by ``1 / cos θ`` along its rows; the renderer, the heatmap targets and the back-projection all use this table, so
they stay consistent. The columns and the top view are unchanged, and ``side_tilt_deg = 0`` is exactly RVT's
geometry.

**Fewer views** (``SigmaConfig.virtual_views``). RVT-2 (Goyal et al. 2024, arXiv 2406.08545) renders three of the
five views, the top and two side views at right angles, for fewer renders and tokens. Every image axis pair must
still be seen for the heatmaps to lift to one 3D point (sigma_policy/heatmap.py): the top view sees (x, y), the front
or back view (x, z), the left or right view (y, z). :func:`view_indices` checks a chosen set and orders it as
:data:`VIEW_NAMES`, so the top view is always index 0 (the yaw scan reads it, sigma_policy/yaw_scan.py). Every
function here that returns per-view values takes ``views``, the chosen indices into :data:`VIEW_AXES`.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

__all__ = [
    "ALL_VIEWS",
    "SIDE_VIEWS",
    "VIEW_AXES",
    "VIEW_NAMES",
    "check_views",
    "project_points",
    "tilted_coordinates",
    "view_axes",
    "view_indices",
]

VIEW_NAMES: tuple[str, ...] = ("top", "front", "back", "left", "right")

# Per view: (u axis, u sign, v axis, v sign, depth axis, depth sign); quantity = 1 + sign * coordinate[axis].
VIEW_AXES: tuple[tuple[int, int, int, int, int, int], ...] = (
    (0, +1, 1, -1, 2, -1),  # top: camera at +z
    (0, -1, 2, -1, 1, -1),  # front: camera at +y
    (0, +1, 2, -1, 1, +1),  # back: camera at -y
    (1, +1, 2, -1, 0, -1),  # left: camera at +x
    (1, -1, 2, -1, 0, +1),  # right: camera at -x
)
SIDE_VIEWS: tuple[int, ...] = (1, 2, 3, 4)
ALL_VIEWS: tuple[int, ...] = (0, 1, 2, 3, 4)
# The image-axis pair each view sees, (u axis, v axis) sorted: top (x, y), front/back (x, z), left/right (y, z).
_AXIS_PAIRS: tuple[tuple[int, int], ...] = tuple(tuple(sorted((a[0], a[2]))) for a in VIEW_AXES)


def check_views(
    views: tuple[int, ...] | list[int], liftable: bool = True, name: str = "views"
) -> tuple[int, ...]:
    """``views`` as a tuple if they are increasing indices into :data:`VIEW_NAMES` and, with ``liftable``, a set
    the heatmaps lift to one 3D point from: the top view and every axis pair (module docstring, "Fewer views");
    else a ``ValueError`` that names the problem, prefixed by ``name`` (the option)."""
    views = tuple(views)
    if not views or list(views) != sorted(set(views)) or not set(views) <= set(ALL_VIEWS):
        raise ValueError(f"{name} must be increasing indices into {VIEW_NAMES}, got {views}")
    if not liftable:
        return views
    names = [VIEW_NAMES[v] for v in views]
    if 0 not in views:
        raise ValueError(f"{name}: {names} lacks 'top' (the yaw scan and the (x, y) heatmap read it)")
    unseen = [pair for pair in ((0, 2), (1, 2)) if pair not in {_AXIS_PAIRS[v] for v in views}]
    if unseen:
        need = " and ".join({(0, 2): "'front' or 'back'", (1, 2): "'left' or 'right'"}[p] for p in unseen)
        raise ValueError(f"{name}: {names} needs {need}, or the heatmaps cannot lift to a 3D point")
    return views


def view_indices(names: list[str] | tuple[str, ...]) -> tuple[int, ...]:
    """Indices into :data:`VIEW_NAMES` of the views ``names``, in that table's order (the top view first); a
    ``ValueError`` naming the problem for an unknown or repeated name, or a set :func:`check_views` refuses."""
    unknown = [n for n in names if n not in VIEW_NAMES]
    if unknown:
        raise ValueError(f"virtual_views: unknown view(s) {unknown}; the views are {list(VIEW_NAMES)}")
    if len(set(names)) != len(names):
        raise ValueError(f"virtual_views: {list(names)} names a view twice")
    return check_views(tuple(i for i, n in enumerate(VIEW_NAMES) if n in names), name="virtual_views")


def tilt_slope(side_tilt_deg: float) -> float:
    """``k = tan θ`` of a side-view tilt in degrees (0 <= θ < 90)."""
    if not 0.0 <= side_tilt_deg < 90.0:
        raise ValueError(f"side_tilt_deg must be in [0, 90), got {side_tilt_deg}")
    return math.tan(math.radians(side_tilt_deg))


def view_axes(side_tilt_deg: float = 0.0) -> tuple[tuple[int, int, int, int, int, int], ...]:
    """:data:`VIEW_AXES`, with each side view's row axis replaced by its tilted coordinate when tilted: index
    ``3 + i`` for the i-th side view, a row of :func:`tilted_coordinates`."""
    if tilt_slope(side_tilt_deg) == 0.0:
        return VIEW_AXES
    axes = list(VIEW_AXES)
    for i, view in enumerate(SIDE_VIEWS):
        u, su, _, sv, d, sd = axes[view]
        axes[view] = (u, su, 3 + i, sv, d, sd)
    return tuple(axes)


def tilted_coordinates(
    coords: Tensor, side_tilt_deg: float, dim: int = -1, out: Tensor | None = None
) -> Tensor:
    """``coords`` with 3 entries along ``dim`` (x, y, z), extended by the four side views' tilted row coordinates
    ``z_t`` (module docstring) when tilted; unchanged when not. ``out``: where to write the 7 entries (the renderer
    passes its reused scratch memory; ``coords`` may be its first 3)."""
    k = tilt_slope(side_tilt_deg)
    if k == 0.0:
        return coords
    if out is None:
        shape = list(coords.shape)
        shape[dim] = 3 + len(SIDE_VIEWS)
        out = coords.new_empty(shape)
    out.narrow(dim, 0, 3).copy_(coords)  # a no-op where coords is that memory
    x, y, z = coords.unbind(dim)
    for i, view in enumerate(SIDE_VIEWS):
        _, _, _, _, depth_axis, depth_sign = VIEW_AXES[view]
        # (z + k * s_d * c_d) / (1 + k), with the product first, as the brute-force reference computes it
        row = out.select(dim, 3 + i)
        torch.mul((x, y)[depth_axis], k * depth_sign, out=row).add_(z).div_(1 + k)
    return out


def project_points(
    points_cube: Tensor, img_size: int, side_tilt_deg: float = 0.0, views: tuple[int, ...] = ALL_VIEWS
) -> tuple[Tensor, Tensor]:
    """Continuous pixel coordinates and view depths of cube points ``(B, N, 3)`` in the views ``views``.

    Returns ``uv (B, N, V, 2)`` (u = column, v = row; pixel j covers [j, j+1)) and ``z (B, N, V)``.
    """
    every = view_axes(side_tilt_deg)
    axes = [every[v] for v in views]
    index = torch.tensor([[a[0], a[2], a[4]] for a in axes], device=points_cube.device).flatten()
    signs = torch.tensor([[a[1], a[3], a[5]] for a in axes], device=points_cube.device).flatten()
    coords = tilted_coordinates(points_cube, side_tilt_deg)
    # (1 + s * c) * (S / 2): multiplication by +-1 is exact, so every path computes bit-identical values.
    q = (1 + coords[..., index] * signs.to(points_cube.dtype)).unflatten(-1, (len(axes), 3))
    uv = q[..., :2] * (img_size / 2)
    return uv, q[..., 2]
