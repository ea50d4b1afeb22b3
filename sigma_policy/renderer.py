"""Pure-PyTorch orthographic virtual-view renderer (replaces RVT-1's PyTorch3D point renderer).

Five fixed orthographic views of the canonical cube ``[-1, 1]^3`` (docs/method.md §4.1), or a subset of them
(``views``; RVT-2's three), each ``img_size`` x ``img_size`` pixels; which cube coordinates give each view's
columns, rows and depth is the table of
:mod:`sigma_policy.views` (RVT's axis-aligned views, or with ``side_tilt_deg`` side views that look down over a
container's rim).

Pixel convention (exact alignment). ``u, v`` are continuous image coordinates in which pixel index ``j`` covers
``[j, j + 1)`` and has its centre at ``j + 0.5``; the image spans exactly ``[-1, 1]`` of the cube.
:meth:`VirtualViewRenderer.project` returns these coordinates unchanged, so a point projects onto the pixel
that rasterises it (``floor(u), floor(v)``), and the heatmap module evaluates Gaussians at pixel centres
``j + 0.5``. RVT instead subtracts ``1/S`` from PyTorch3D's screen coordinates and treats integer indices as
centres, which places its labels about half a pixel off the rasterised pixels (docs/method.md §13, item 13);
sigma does not reproduce that quirk.

Splat semantics. Every point is a disc of radius ``radius_px`` pixels (default 1.32 px = PyTorch3D's 0.012 NDC
at 220 px, about 6 mm in a 1 m workspace). A point *covers* pixel ``(i, j)`` of a view when the squared distance
from its ``(u, v)`` to the pixel centre ``(j + 0.5, i + 0.5)`` is strictly below ``radius_px**2`` and its view
depth is >= 0. Each pixel shows the covering point of smallest view depth (float32 z-buffer; ties go to the lowest
point index) -- PyTorch3D's nearest point (K = 1) with hard, not weighted, compositing (RVT-2's choice).

Output channels for ``F`` feature channels (``F = 3``, RGB, gives the paper's 10):
``0-2`` cube xyz of the winning point, ``3 .. 3+F-1`` its features, then depth, then 3 pixel-location channels.
Depth is the winner's view depth ``z`` (in ``[0, 2]`` for points in the cube) minus the mean of ``z`` over the
non-empty pixels of that image; empty pixels get depth ``-1`` and zeros in the xyz/feature channels. The
location channels are the view id ``linspace(-1, 1, V)[view]`` (V rendered views), the row coordinate
``linspace(-1, 1, H)`` and the column coordinate ``linspace(-1, 1, W)``.

Implementation (no Python loop over points or pixels). Each view depends on two coordinates for its image
axes and one for its depth, and the 5 views use only 5 distinct image-axis quantities (``(1 +- x) S/2``,
``(1 +- y) S/2``, ``(1 - z) S/2``; 8 with tilted side views, each with its own row coordinate), so per point and
quantity the ``T = 2 ceil(r - 1/2) + 1`` candidate pixel rows/columns around ``floor(q)`` (3 for r = 1.32) and
their squared centre distances are computed once. A point's key packs its float32 view depth bits (monotonic for
z >= 0) above its point index into one int64, and per view the ``T x T`` candidates are scattered with
``scatter_reduce_(..., "amin")`` into a flat buffer -- the z-buffer.
The radius test ``d_row^2 + d_col^2 < r^2`` is evaluated in float32 exactly as written, but turned into the
scatter address with integer bit operations (the sign bit of ``d^2 - r^2``): candidates outside the disc, off the
image or of invalid points go to a dummy slot on CPU, where boolean masks and ``torch.where`` are several times
slower than integer arithmetic (they branch on every element, and the branch is mispredicted half the time); on
CUDA they are dropped with a boolean mask instead (one slot would serialise the atomics).

CPU specifics (measured on 2 cores; ``python -m benchmarks.bench_renderer``). Each sample has its own z-buffer
and point indices, and its output channels are gathered right after its scatter from a table of that sample's
points only, so the working set stays in cache; the samples of a batch are shared among
``torch.get_num_threads()`` Python threads (PyTorch kernels release the GIL; each thread has its own scratch
memory; intra-op threading is paused meanwhile). Scratch memory is reused across calls, and so is the output
tensor once the caller has dropped every reference to it (checked with its storage's use count): a fresh
multi-megabyte allocation is page-faulted in on first touch, which costs more than the arithmetic of a render
(sigma_policy/render_memory.py).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable

import torch
from torch import Tensor, nn

from sigma_policy.render_memory import Workspace, cpu_pool, output_pool, workspace
from sigma_policy.views import (
    ALL_VIEWS,
    SIDE_VIEWS,
    VIEW_AXES,
    VIEW_NAMES,
    check_views,
    project_points,
    tilt_slope,
    tilted_coordinates,
    view_axes,
)

__all__ = ["VIEW_AXES", "VIEW_NAMES", "VirtualViewRenderer", "project_points"]


def _quantity_tables(
    axes: tuple[tuple[int, int, int, int, int, int], ...],
) -> tuple[tuple[tuple[int, int], ...], tuple[tuple[int, int], ...]]:
    """The distinct image-axis quantities (axis, sign) -> q = (1 + sign * coordinate[axis]) * S / 2 of the views
    ``axes`` (5 for RVT's views, 8 with tilted side views), and per view the positions of its column (u) and row
    (v) quantities in that list."""
    quantities = tuple(dict.fromkeys(q for a in axes for q in ((a[0], a[1]), (a[2], a[3]))))
    per_view = tuple((quantities.index((a[0], a[1])), quantities.index((a[2], a[3]))) for a in axes)
    return quantities, per_view


_INF_BITS = 0x7F800000  # float32 +inf as int32 bits: the key's depth part for an empty pixel
_NEG_ONE_BITS = -0x40800000  # float32 -1.0 as int32 bits (0xBF800000): the depth channel of an empty pixel
_LOW32 = 0xFFFFFFFF
_SCATTER_MODES = ("auto", "dummy", "spread", "compact")
_OFF_IMAGE = (
    1e30  # added (times the squared pixel overshoot >= 1) to the squared distance of off-image pixels
)


def _one_plus(c: Tensor, sign: int, out: Tensor) -> Tensor:
    """``1 + sign * c`` (float32) into ``out``, bit-identical to the table's ``1 + c`` / ``1 - c``."""
    return torch.add(c, 1, out=out) if sign > 0 else torch.sub(1, c, out=out)


class VirtualViewRenderer(nn.Module):
    """Render cube-space point clouds into orthographic views (see the module docstring for conventions).

    Args:
        img_size: output height = width in pixels (220 in the paper).
        radius_px: splat radius in pixels (1.32 = RVT's 0.012 NDC at 220 px).
        scatter_mode: where the candidate pixels outside a point's disc go (the result is identical):
            ``"dummy"`` one dummy slot (cheapest on CPU, where the scatter is serial), ``"spread"`` a shadow copy
            of the buffer at the same pixel (CUDA: no atomic hot spot, no compaction), ``"compact"`` dropped with
            a boolean mask first (fewer atomics, but the compaction costs more on both devices), ``"auto"``
            (default) ``"dummy"`` on CPU and ``"spread"`` elsewhere.
        side_tilt_deg: the four side views look down by this angle (sigma_policy/views.py); 0 = RVT's views.
        views: which views to render, increasing indices into ``VIEW_NAMES`` (sigma_policy/views.py
            ``view_indices``); all five by default.
    """

    def __init__(
        self,
        img_size: int = 220,
        radius_px: float = 1.32,
        scatter_mode: str = "auto",
        side_tilt_deg: float = 0.0,
        views: tuple[int, ...] = ALL_VIEWS,
    ) -> None:
        super().__init__()
        if img_size < 1:
            raise ValueError(f"img_size must be positive, got {img_size}")
        if not radius_px > 0:
            raise ValueError(f"radius_px must be positive, got {radius_px}")
        self.img_size = int(img_size)
        self.radius_px = float(radius_px)
        if scatter_mode not in _SCATTER_MODES:
            raise ValueError(f"scatter_mode must be one of {_SCATTER_MODES}, got {scatter_mode!r}")
        self.scatter_mode = scatter_mode
        self.side_tilt_deg = float(side_tilt_deg)
        self.views = check_views(views, liftable=False)  # any set renders; the policy needs a liftable one
        every = view_axes(self.side_tilt_deg)  # validates the angle
        self._view_axes = tuple(every[v] for v in self.views)
        self._quantities, self._view_quantities = _quantity_tables(self._view_axes)
        # x, y, z (+ the 4 tilted side-view rows, tilted_coordinates writes them all)
        self._coord_rows = 3 + len(SIDE_VIEWS) * (tilt_slope(self.side_tilt_deg) > 0)
        # Candidate pixels per axis: floor(q) - reach .. floor(q) + reach (3 for r = 1.32). A pixel j more than
        # reach away has |j + 0.5 - q| >= reach + 1/2 >= r, so it cannot be covered.
        self._reach = max(0, math.ceil(self.radius_px - 0.5))
        # The coverage test is d^2 < r^2 in float32, like the brute-force reference.
        self._rr = float(torch.tensor(self.radius_px**2, dtype=torch.float32))
        S, V = self.img_size, len(self.views)
        lin = torch.linspace(-1, 1, S)
        loc = torch.stack(
            [
                torch.linspace(-1, 1, V)[:, None, None].expand(V, S, S),
                lin[None, :, None].expand(V, S, S),
                lin[None, None, :].expand(V, S, S),
            ],
            dim=1,
        )  # (V, 3, H, W)
        self.register_buffer("pixel_loc", loc, persistent=False)

    @property
    def num_views(self) -> int:
        return len(self.views)

    @property
    def view_names(self) -> list[str]:
        """The rendered views' names, in their order (``VIEW_NAMES``)."""
        return [VIEW_NAMES[v] for v in self.views]

    def project(self, points_cube: Tensor) -> Tensor:
        """Continuous pixel coordinates ``(B, N, V, 2)`` (u = column, v = row) of cube points ``(B, N, 3)``,
        consistent with :meth:`forward`: the point rasterises into pixel ``(floor(v), floor(u))``."""
        return project_points(points_cube, self.img_size, self.side_tilt_deg, self.views)[0]

    @torch.no_grad()
    def zbuffer(self, points_cube: Tensor, mask: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """Winning point per pixel: ``index (B, V, H, W)`` int64 into N (-1 where empty) and float32 ``depth``
        ``(B, V, H, W)`` (view z of the winner, +inf where empty)."""
        pts, ignore, mode = self._prepare(points_cube, mask)
        B, N, _ = points_cube.shape
        S, V, dev = self.img_size, self.num_views, points_cube.device
        if dev.type == "cpu":  # local point indices per sample; N marks an empty pixel
            win = torch.empty(B, V, S * S, dtype=torch.int64)
            self._run_samples_cpu(
                B, lambda b, ws: win[b].copy_(self._sample_keys_cpu(pts[b], ignore[b], mode, ws))
            )
            index = win & _LOW32
            empty = index == N
        else:  # flat indices b*N + n over the batch; B*N marks an empty pixel
            win = self._batch_keys(pts, ignore, mode, workspace(dev))[1:].view(B, V, S * S)
            flat = win & _LOW32
            empty = flat == B * N
            index = flat - (torch.arange(B, device=dev) * N).view(B, 1, 1)
        depth = (win >> 32).to(torch.int32).view(torch.float32)  # empty pixels hold +inf bits
        return torch.where(empty, -1, index).view(B, V, S, S), depth.view(B, V, S, S)

    def _prepare(self, points_cube: Tensor, mask: Tensor | None) -> tuple[Tensor, Tensor, str]:
        """Checks the inputs; returns float32 points, ``ignore (B, N)`` int32 (-1 = all bits set for points to
        ignore, 0 for the others) and the scatter mode for this device."""
        if points_cube.ndim != 3 or points_cube.shape[-1] != 3:
            raise ValueError(f"points_cube must be (B, N, 3), got {tuple(points_cube.shape)}")
        B, N, _ = points_cube.shape
        S, V, dev = self.img_size, self.num_views, points_cube.device
        if B * N >= 2**31 - 1:
            raise ValueError(f"batch too large for the packed z-buffer: B*N = {B * N} >= 2^31 - 1")
        if 1 + B * V * S * S >= 2**31:
            raise ValueError(f"batch too large for int32 pixel addresses: B*V*H*W = {B * V * S * S}")
        pts = points_cube.float()
        valid = torch.isfinite(pts).all(-1)
        if mask is not None:
            if mask.shape != (B, N):
                raise ValueError(f"mask must be (B, N) = {(B, N)}, got {tuple(mask.shape)}")
            valid &= mask.to(dev, torch.bool)
        mode = (
            self.scatter_mode if self.scatter_mode != "auto" else ("dummy" if dev.type == "cpu" else "spread")
        )
        return pts, valid.to(torch.int32).sub_(1), mode

    def _sample_keys_cpu(self, pts: Tensor, ignore: Tensor, mode: str, ws: Workspace) -> Tensor:
        """One sample's z-buffer (CPU) as packed keys ``(V, H*W)`` (memory of ``ws``): pixel ``(v, i, j)`` holds
        ``depth_bits << 32 | n`` of its winner ``n`` or, if empty, ``+inf bits << 32 | N``
        (larger than every real key). The buffer behind it starts with the dummy slot 0."""
        N = pts.shape[0]
        size = 1 + self.num_views * self.img_size**2  # "spread" appends a shadow copy of the pixels
        buf = ws.get("zbuf", (2 * size - 1 if mode == "spread" else size,), torch.int64, pts.device)
        empty = (_INF_BITS << 32) | N
        if N:
            self._scatter_chunk(buf, pts, ignore, 0, 1, mode, ws, fill=empty)
        else:
            buf.fill_(empty)
        return buf[1:size].view(self.num_views, -1)

    def _batch_keys(self, pts: Tensor, ignore: Tensor, mode: str, ws: Workspace) -> Tensor:
        """The whole batch's z-buffer in one pass (CUDA) as packed keys ``(1 + B*V*H*W,)``: slot 0 is a dummy,
        then pixel ``(b, v, i, j)`` at ``1 + ((b*V + v)*H + i)*W + j`` holds ``depth_bits << 32 |
        (b*N + n)`` of its winner ``n`` or, if empty, ``+inf bits << 32 | B*N``."""
        B, N, _ = pts.shape
        S, V, dev = self.img_size, self.num_views, pts.device
        size = 1 + B * V * S * S
        buf = ws.get("zbuf", (2 * size - 1 if mode == "spread" else size,), torch.int64, dev)
        buf.fill_((_INF_BITS << 32) | (B * N))
        if B * N:  # pixel0 = flat address of pixel (b, view 0, 0, 0), dummy slot included
            pixel0 = torch.arange(1, 1 + B * V * S * S, V * S * S, device=dev, dtype=torch.int32)
            self._scatter_chunk(
                buf, pts.view(-1, 3), ignore.view(-1), 0, pixel0.repeat_interleave(N), mode, ws
            )
        return buf[:size]

    def _run_samples_cpu(self, B: int, job: Callable[[int, Workspace], object]) -> None:
        """Runs ``job(b, workspace)`` for every sample: serially, or with ``torch.get_num_threads()`` > 1 and a
        batch, on that many threads (each with its own workspace; jobs write disjoint memory, so the result is
        identical to the serial one). Splitting one sample among threads was measured slower than one thread."""
        intra = torch.get_num_threads()
        threads = min(intra, B)
        inference = torch.is_inference_mode_enabled()

        def run(b: int) -> None:
            with torch.inference_mode(inference), torch.no_grad():
                job(b, workspace(torch.device("cpu")))

        if threads <= 1:
            for b in range(B):
                run(b)
            return
        # The render threads are the parallelism; intra-op threads on top of them would oversubscribe the cores.
        torch.set_num_threads(1)
        try:
            for future in [cpu_pool(threads).submit(run, b) for b in range(B)]:
                future.result()
        finally:
            torch.set_num_threads(intra)

    def _scatter_chunk(
        self,
        buf: Tensor,
        pts: Tensor,
        ignore: Tensor,
        first: int,
        pixel0: int | Tensor,
        mode: str,
        ws: Workspace,
        dummy: int = 0,
        fill: int | None = None,
    ) -> None:
        """Scatter-min the keys of ``m`` points ``pts (m, 3)`` (flat indices ``first ..``, ``ignore (m,)`` int32
        -1/0) into every pixel their disc covers, in every rendered view; ``pixel0`` (scalar or
        ``(m,)``) is the address of each point's pixel (view 0, 0, 0); ``dummy`` the slot that candidates
        outside a disc go to in ``"dummy"`` mode. ``fill``: with a scalar ``pixel0``, each view's pixels are set to
        this key right before its scatter (instead of by the caller up front), so they are still in cache."""
        coords, flat, tap_d2, tap_pix = self._taps(pts, first, ws)
        m, dev = pts.shape[0], pts.device
        S, T, f32, i32 = self.img_size, tap_d2.shape[1], torch.float32, torch.int32
        z = ws.get("z", (m,), f32, dev)
        z_bad = ws.get("z_bad", (m,), i32, dev)
        key = ws.get("key", (m,), torch.int64, dev)
        row_d2 = ws.get("row_d2", (T, m), f32, dev)
        row_addr = ws.get("row_addr", (T, m), i32, dev)
        for view, ((_, _, _, _, cz, sz), (iu, iv)) in enumerate(
            zip(self._view_axes, self._view_quantities, strict=True)
        ):
            _one_plus(coords[cz], sz, out=z)
            # Ignored points and points behind the camera (z < 0: sign bit set) get +inf added to the row distance.
            torch.bitwise_right_shift(z.view(i32), 31, out=z_bad).bitwise_or_(ignore).bitwise_and_(_INF_BITS)
            torch.add(tap_d2[iv], z_bad.view(f32), out=row_d2)
            # address of each row's pixel 0
            torch.mul(tap_pix[iv], S, out=row_addr).add_(pixel0 + view * S * S)
            key.copy_(z.view(i32)).bitwise_left_shift_(32).bitwise_or_(
                flat
            )  # z >= 0: float order = int order
            if fill is not None:  # this view's pixels, filled last so they are still in cache for the scatter
                start = pixel0 + view * S * S
                buf[start : start + S * S].fill_(fill)
            if mode == "dummy":
                self._scatter_via_dummy(buf, row_d2, row_addr, tap_d2[iu], tap_pix[iu], key, ws, dummy)
            elif mode == "spread":
                self._scatter_spread(buf, row_d2, row_addr, tap_d2[iu], tap_pix[iu], key)
            else:
                self._scatter_compact(buf, row_d2, row_addr, tap_d2[iu], tap_pix[iu], key)

    def _taps(self, pts: Tensor, first: int, ws: Workspace) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """What every view needs of ``pts (m, 3)`` (memory of ``ws``): cube coordinates ``(3, m)`` with NaN as 0
        (``(7, m)`` with tilted side views, :func:`~sigma_policy.views.tilted_coordinates`),
        flat point indices ``first ..`` ``(m,)``, and per image-axis quantity the ``T`` candidate pixel indices
        ``(Q, T, m)`` int32 (clamped to the image) and their squared centre distances ``(Q, T, m)`` (+1e30 or more
        for pixels off the image)."""
        m, dev = pts.shape[0], pts.device
        S, T, f32 = self.img_size, 2 * self._reach + 1, torch.float32
        coords = ws.get("coords", (self._coord_rows, m), f32, dev)
        torch.nan_to_num(pts.t(), 0.0, 0.0, 0.0, out=coords[:3])
        tilted_coordinates(coords[:3], self.side_tilt_deg, dim=0, out=coords)  # the tilted side-view rows
        flat = torch.arange(first, first + m, out=ws.get("flat", (m,), torch.int64, dev))
        tap_d2 = ws.get("tap_d2", (len(self._quantities), T, m), f32, dev)
        tap_pix = ws.get("tap_pix", (len(self._quantities), T, m), torch.int32, dev)
        q = ws.get("q", (m,), f32, dev)
        j = ws.get("j", (T, m), f32, dev)
        jc = ws.get("jc", (T, m), f32, dev)
        offsets = torch.arange(-self._reach, self._reach + 1, device=dev, dtype=f32)[:, None]
        for i, (axis, sign) in enumerate(self._quantities):
            # clamp: far points stay off the image
            _one_plus(coords[axis], sign, out=q).mul_(S / 2).clamp_(-2 * S, 3 * S)
            torch.add(q.floor()[None], offsets, out=j)  # pixel indices floor(q) - reach .. + reach (exact)
            d2 = torch.add(j, 0.5, out=tap_d2[i]).sub_(q).square_()  # (centre - q)^2 exactly as the reference
            torch.clamp(j, 0, S - 1, out=jc)
            d2.addcmul_(j.sub_(jc), j, value=_OFF_IMAGE)  # off-image pixels: +1e30 or more, never covered
            tap_pix[i].copy_(jc)
        return coords, flat, tap_d2, tap_pix

    def _scatter_via_dummy(
        self,
        buf: Tensor,
        row_d2: Tensor,
        row_addr: Tensor,
        col_d2: Tensor,
        col_pix: Tensor,
        key: Tensor,
        ws: Workspace,
        dummy: int = 0,
    ) -> None:
        """Scatter-min ``key (m,)`` into the ``T x T`` candidate pixels (rows ``row_d2, row_addr (T, m)`` x
        columns ``col_d2, col_pix (T, m)``); candidates outside the disc go to slot ``dummy``."""
        T, m = row_d2.shape
        d2 = torch.add(row_d2[:, None], col_d2[None], out=ws.get("d2", (T, T, m), torch.float32, buf.device))
        # Sign bit of d^2 - r^2 (exact: rounding keeps the sign) as an int32 mask: -1 inside the disc, else 0.
        inside = d2.sub_(self._rr).view(torch.int32).bitwise_right_shift_(31)
        addr = torch.add(
            row_addr[:, None], col_pix[None], out=ws.get("addr", (T, T, m), torch.int32, buf.device)
        )
        index = ws.get("index", (T * T, m), torch.int64, buf.device)
        if dummy:
            index.copy_(inside.bitwise_and_(addr.sub_(dummy)).add_(dummy).view(T * T, m))
        else:
            index.copy_(inside.bitwise_and_(addr).view(T * T, m))
        for t in range(T * T):
            buf.scatter_reduce_(0, index[t], key, reduce="amin", include_self=True)

    def _scatter_spread(
        self, buf: Tensor, row_d2: Tensor, row_addr: Tensor, col_d2: Tensor, col_pix: Tensor, key: Tensor
    ) -> None:
        """As :meth:`_scatter_via_dummy`, but candidates outside the disc go to the same pixel of a shadow copy
        of the buffer (its second half), so no address is hit more often than a real pixel."""
        T, m = row_d2.shape
        shadow = buf.numel() // 2
        inside = (row_d2[:, None] + col_d2[None]) < self._rr  # (T, T, m)
        # All candidates start in the shadow copy; those inside the disc move back (few, fused kernels on CUDA).
        addr = row_addr.to(torch.int64).add_(shadow)[:, None] + col_pix.to(torch.int64)[None]
        addr = addr.add_(inside, alpha=-shadow).view(T * T, m)
        for t in range(T * T):
            buf.scatter_reduce_(0, addr[t], key, reduce="amin", include_self=True)

    def _scatter_compact(
        self, buf: Tensor, row_d2: Tensor, row_addr: Tensor, col_d2: Tensor, col_pix: Tensor, key: Tensor
    ) -> None:
        """As :meth:`_scatter_via_dummy`, but the candidates outside the disc are dropped with a boolean mask."""
        T, m = row_d2.shape
        inside = (row_d2[:, None] + col_d2[None]) < self._rr  # (T, T, m)
        addr = (row_addr[:, None] + col_pix[None])[inside].to(torch.int64)
        buf.scatter_reduce_(0, addr, key.expand(T, T, m)[inside], reduce="amin", include_self=True)

    @torch.no_grad()
    def forward(self, points_cube: Tensor, feats: Tensor, mask: Tensor | None = None) -> Tensor:
        """Render ``(B, N, 3)`` cube points with features ``(B, N, F)`` into ``(B, V, 3 + F + 1 + 3, H, W)``.

        ``mask (B, N)``: False entries (padding, out-of-bounds points) are ignored. Non-finite points and points
        behind a view (view depth < 0, i.e. outside the cube on that view's axis) are ignored as well.
        """
        pts, ignore, mode = self._prepare(points_cube, mask)
        B, N, _ = points_cube.shape
        if feats.ndim != 3 or feats.shape[:2] != (B, N):
            raise ValueError(f"feats must be (B, N, F) = ({B}, {N}, F), got {tuple(feats.shape)}")
        S, V, C = self.img_size, self.num_views, 3 + feats.shape[-1]
        dev = points_cube.device
        if dev.type == "cpu":
            out = output_pool().get((B, V, C + 4, S, S))

            def job(b: int, ws: Workspace) -> None:
                win = self._sample_keys_cpu(pts[b], ignore[b], mode, ws)
                self._write_sample_cpu(out[b], win, self._src_table(points_cube[b], feats[b], ws), ws)

            self._run_samples_cpu(B, job)
            return out

        M, ws = B * N, workspace(dev)
        win = self._batch_keys(pts, ignore, mode, ws)[1:].view(B * V, S * S)
        out = torch.empty((B, V, C + 4, S, S), device=dev)
        # Winners' xyz and features: one gather for the batch (flat indices; column M is the empty pixel's zeros).
        src = self._src_table(points_cube.reshape(M, 3), feats.reshape(M, C - 3), ws)
        index = torch.bitwise_and(win, _LOW32, out=ws.get("index_out", (B * V, S * S), torch.int64, dev))
        out[:, :, :C] = src.index_select(1, index.view(-1)).view(C, B, V, S, S).permute(1, 2, 0, 3, 4)
        self._write_depth(win, out[:, :, C], ws)
        out[:, :, C + 1 :] = self.pixel_loc.to(dev, out.dtype)
        return out

    @staticmethod
    def _src_table(points: Tensor, feats: Tensor, ws: Workspace) -> Tensor:
        """Channel-major xyz + features ``(C, N + 1)`` of ``N`` points (one sample's, or a flattened batch's; memory
        of ``ws``); column N (the index an empty pixel unpacks to) is zero."""
        N, C = points.shape[0], 3 + feats.shape[-1]
        src = ws.get("src", (C, N + 1), torch.float32, points.device)
        src[:3, :N] = points.t()
        src[3:, :N] = feats.t()
        src[:, N] = 0
        return src

    def _write_sample_cpu(self, out: Tensor, win: Tensor, src: Tensor, ws: Workspace) -> None:
        """One sample's channels ``out (V, C + 4, H, W)`` from its keys ``win (V, H*W)``: the winners' xyz and
        features gathered from ``src`` (:meth:`_src_table`) straight into the output, image by image, then depth
        and the pixel-location channels."""
        C, P = src.shape[0], win.shape[-1]
        index = torch.bitwise_and(
            win, _LOW32, out=ws.get("index_out", tuple(win.shape), torch.int64, win.device)
        )
        for v in range(self.num_views):
            torch.index_select(src, 1, index[v], out=out[v, :C].view(C, P))
        self._write_depth(win, out[:, C], ws)
        out[:, C + 1 :] = self.pixel_loc

    @staticmethod
    def _write_depth(win: Tensor, depth: Tensor, ws: Workspace) -> None:
        """Depth channel ``depth (..., H, W)`` (a view into the output) from keys ``win (R, H*W)``: the winner's z
        minus the mean over the filled pixels of its image, -1 where empty, in integer bit arithmetic."""
        R, P = win.shape
        zbits = ws.get("zbits", (R, P), torch.int32, win.device)
        if sys.byteorder == "little":  # the high words of the keys are the depth bits
            zbits.copy_(win.view(torch.int32).view(R, P, 2)[..., 1])
        else:
            zbits.copy_(win >> 32)
        filled = torch.sub(zbits, _INF_BITS, out=ws.get("filled", (R, P), torch.int32, win.device))
        filled.bitwise_right_shift_(31)  # -1 where filled (depth bits below +inf), 0 where empty
        z = zbits.bitwise_and_(filled).view(torch.float32)  # 0.0 where empty
        # int32 counts (no int64 copy of the mask for the sum); mean of z over the filled pixels.
        mean = z.sum(-1, keepdim=True) / filled.sum(-1, keepdim=True, dtype=torch.int32).neg_().clamp_min_(1)
        grid = depth.shape
        torch.sub(z.view(grid), mean.view(*grid[:-2], 1, 1), out=depth)
        depth_bits = depth.view(torch.int32).bitwise_xor_(_NEG_ONE_BITS)
        depth_bits.bitwise_and_(filled.view(grid)).bitwise_xor_(_NEG_ONE_BITS)  # empty: -1.0
