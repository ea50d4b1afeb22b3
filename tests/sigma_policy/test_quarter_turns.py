"""Quarter turns of the top view: what the renderer gives for a turned scene, and features that turn with it."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch

from sigma_policy.layers import LocalEncoder
from sigma_policy.network import SigmaNetwork
from sigma_policy.quarter_turns import quarter_turn_average, turn_top_view
from sigma_policy.renderer import VirtualViewRenderer
from sigma_policy.yaw_scan import TOP_VIEW
from tests.sigma_policy.test_network import SMALL, inputs


def _top_view(yaw_deg: float) -> torch.Tensor:
    """The top view (1, 10, 64, 64) of an L of points (a long arm along +x, a short one along +y, coloured by arm)
    turned by ``yaw_deg`` about the vertical through the box's centre."""
    long_arm = torch.stack([torch.linspace(0.05, 0.6, 60), torch.zeros(60)], -1)
    short_arm = torch.stack([torch.zeros(30), torch.linspace(0.05, 0.3, 30)], -1)
    a = math.radians(yaw_deg)
    rot = torch.tensor([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    xy = torch.cat([long_arm, short_arm]) @ rot.T
    points = torch.cat([xy, torch.full((90, 1), -0.2)], -1)[None]
    colours = torch.cat(
        [torch.tensor([[1.0, 0.0, 0.0]]).expand(60, 3), torch.tensor([[0.0, 0.0, 1.0]]).expand(30, 3)]
    )
    views = VirtualViewRenderer(img_size=64)(points, colours[None], torch.ones(1, 90, dtype=torch.bool))
    return views[:, TOP_VIEW]


@pytest.mark.parametrize("k", [1, 2, 3])
def test_a_turned_top_view_is_the_render_of_the_turned_scene(k):
    """Every channel, pixels and cube coordinates alike, matches the render of the scene turned by k quarter turns;
    turning the other way (a sign error in the geometry) does not."""
    base, turned = _top_view(0.0), _top_view(90.0 * k)
    assert (turn_top_view(base, k) - turned).abs().amax() < 1e-4
    if k != 2:
        assert (turn_top_view(base, -k) - turned).abs().amax() > 0.5


def test_quarter_turn_average_turns_with_the_scene_and_keeps_each_pixels_features():
    encoder = LocalEncoder(10, 4, (1, 2))
    view = _top_view(20.0)
    with torch.no_grad():
        features = quarter_turn_average(encoder, view)
        turned = quarter_turn_average(encoder, turn_top_view(view, 1))
        plain = encoder(view)
    torch.testing.assert_close(turned, torch.rot90(features, 1, dims=(-2, -1)), atol=1e-5, rtol=1e-5)
    assert not torch.allclose(
        encoder(turn_top_view(view, 1)), torch.rot90(plain, 1, dims=(-2, -1)), atol=1e-3
    )


def test_the_quarter_turns_add_no_weights_and_change_the_top_views_heatmap_alone():
    with pytest.raises(ValueError, match="local_quarter_turns needs local_in_decoder"):
        dataclasses.replace(SMALL, local_channels=4, local_quarter_turns=True)
    cfg = dataclasses.replace(SMALL, local_channels=4, local_dilations=(1, 2), local_in_decoder=True)
    plain = SigmaNetwork(cfg, lang_token_dim=12, lang_sentence_dim=12)
    turns = SigmaNetwork(
        dataclasses.replace(cfg, local_quarter_turns=True), lang_token_dim=12, lang_sentence_dim=12
    )
    turns.load_state_dict(plain.state_dict())  # no new weights
    img, tok, *_ = inputs(cfg)
    head_heatmap = torch.zeros(2, 5, 32, 32)
    head_heatmap[..., 3, 5] = 1
    with torch.no_grad():
        a, b = plain(img, tok, head_heatmap=head_heatmap), turns(img, tok, head_heatmap=head_heatmap)
    assert not torch.allclose(a.trans[:, TOP_VIEW], b.trans[:, TOP_VIEW])
    torch.testing.assert_close(a.trans[:, TOP_VIEW + 1 :], b.trans[:, TOP_VIEW + 1 :])
