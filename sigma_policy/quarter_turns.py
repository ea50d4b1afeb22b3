"""Local features of the top view that an object's heading does not change, by quarter turns (not in the paper).

On NutAssembly the translation heatmap has to find the nut's handle, which robosuite turns uniformly about the
vertical: a few dozen demonstrations show it at a few dozen headings, and the decoder's local features
(:class:`~sigma_policy.layers.LocalEncoder`, ``local_in_decoder``) must learn the handle's outline at each of them.
Group averaging (Cohen & Welling, "Group Equivariant Convolutional Networks", ICML 2016,
https://arxiv.org/abs/1602.07576) makes the encoder answer alike at four headings by construction: the top view is
turned by each quarter turn, encoded, turned back, and the four maps are averaged. A handle then gives the same
features at its tip whether it points along +x, +y, -x or -y, and the network learns its outline over one quarter of
the headings instead of all of them.

Geometry. The top view (``VIEW_AXES[0]``) has its columns along +x and its rows along -y of the scene box, so with
pixel coordinates centred on the view, a point at (row r, column c) is at (x, y) = (c, -r). ``torch.rot90(view, 1,
dims=(-2, -1))`` moves (r, c) to (-c, r), which is (x, y) -> (-y, x): the scene turned by +90 degrees about the
vertical through the box's centre. A turned scene is not only moved pixels: each pixel's cube coordinates (channels
0 and 1, docs/method.md §4.3) turn with it, while the row and column channels (8 and 9) are a fixed grid. So
:func:`turn_top_view` turns the pixels, turns the (x, y) channels and keeps the grid: what the renderer gives for the
turned scene (``tests/sigma_policy/test_quarter_turns.py`` checks it on a rendered cloud). The box needs equal x
and y extents, as the yaw scan's does (docs/method.md §7.1).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

__all__ = ["QUARTER_TURNS", "quarter_turn_average", "turn_top_view"]

QUARTER_TURNS = 4
# Channels of a rendered view (docs/method.md §4.3): the cube x and y of the point, and the pixel grid's row and
# column coordinates.
X_CHANNEL, Y_CHANNEL = 0, 1
GRID_CHANNELS = slice(8, 10)


def turn_top_view(view: Tensor, k: int) -> Tensor:
    """The top view ``(N, C, H, W)`` of the scene turned by ``k`` quarter turns (+90 degrees each) about the vertical
    through the box's centre: pixels turned, cube (x, y) channels turned, the pixel grid channels kept."""
    k %= QUARTER_TURNS
    if k == 0:
        return view
    turned = torch.rot90(view, k, dims=(-2, -1))
    x, y = turned[:, X_CHANNEL], turned[:, Y_CHANNEL]
    # (x, y) -> (-y, x) per quarter turn.
    xy = {1: (-y, x), 2: (-x, -y), 3: (y, -x)}[k]
    grid = view[:, GRID_CHANNELS]
    return torch.cat([xy[0][:, None], xy[1][:, None], turned[:, 2:8], grid, turned[:, 10:]], dim=1)


def quarter_turn_average(encoder: nn.Module, view: Tensor) -> Tensor:
    """``encoder``'s features of the top view ``(N, C, H, W)``, averaged over the view's four quarter turns, each
    turned back: ``mean_k rot90(encoder(turn_top_view(view, k)), -k)``. Turning the scene by a quarter turn turns
    the result's map by the same quarter turn and leaves each pixel's features as they were."""
    turned = encoder(torch.cat([turn_top_view(view, k) for k in range(QUARTER_TURNS)])).chunk(QUARTER_TURNS)
    return torch.stack([torch.rot90(f, -k, dims=(-2, -1)) for k, f in enumerate(turned)]).mean(dim=0)
