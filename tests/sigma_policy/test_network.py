"""The Σ-agent network: parameter counts of the paper configuration, shapes, gradient routing, variants."""

from __future__ import annotations

import dataclasses

import pytest
import torch
import torch.nn.functional as F

from sigma_policy.configuration_sigma import SigmaConfig
from sigma_policy.network import SigmaNetwork
from sigma_policy.network_config import NetworkConfig
from sigma_policy.upsample import BilinearUpsample

SMALL = NetworkConfig(
    img_size=32,
    patch_size=8,
    im_channels=8,
    final_dim=8,
    attn_dim=32,
    attn_heads=2,
    attn_dim_head=16,
    num_view_layers=1,
    num_query_layers=1,
    num_fusion_layers=1,
    decoder_kernel=3,
    attn_dropout=0.0,
)


def inputs(cfg: NetworkConfig, b: int = 2, lang_len: int = 6, lang_dim: int = 12):
    g = torch.Generator().manual_seed(0)
    img = torch.rand(b, cfg.num_views, cfg.in_channels, cfg.img_size, cfg.img_size, generator=g)
    goal = torch.rand(img.shape, generator=g)
    return img, torch.randn(b, lang_len, lang_dim, generator=g), torch.randn(b, lang_dim, generator=g), goal


def test_paper_parameter_count_matches_the_paper_within_one_percent():
    # CLIP token / sentence width 512 as in Σ-agent; docs/method.md §5.6 gives 38,259,614 and 36.03 M.
    net = SigmaNetwork(NetworkConfig(), lang_token_dim=512, lang_sentence_dim=512)
    total, inference = net.num_parameters(), net.num_parameters(inference_only=True)
    assert abs(total - 38.26e6) / 38.26e6 < 0.01, total
    assert abs(inference - 36.0e6) / 36.0e6 < 0.01, inference
    assert total == 38_259_614 and inference == 36_032_413


def test_gpu_preset_is_the_suite_network_widened_to_the_measured_size():
    # docs/gpu.md "The gpu preset": lerobot-train counted 7,597,415 learnable parameters, suite's network 1.6 M.
    sizes = {}
    for preset in ("suite", "gpu"):
        cfg = SigmaConfig(preset=preset, device="cpu")
        sizes[preset] = SigmaNetwork(
            cfg.network_config(), lang_token_dim=384, lang_sentence_dim=384
        ).num_parameters()
    assert sizes == {"suite": 1_561_383, "gpu": 7_597_415}


def test_paper_preset_with_default_minilm_dimensions_is_within_one_percent():
    cfg = SigmaConfig(preset="paper", device="cpu")
    net = SigmaNetwork(cfg.network_config(), lang_token_dim=384, lang_sentence_dim=384)
    assert abs(net.num_parameters() - 38.26e6) / 38.26e6 < 0.01
    assert abs(net.num_parameters(inference_only=True) - 36.0e6) / 36.0e6 < 0.01


def test_forward_shapes_and_every_parameter_gets_a_gradient():
    net = SigmaNetwork(SMALL, lang_token_dim=12, lang_sentence_dim=12)
    img, tok, sent, goal = inputs(SMALL)
    out = net(img, tok, sent, goal)
    assert out.trans.shape == (2, 5, 32, 32)
    assert out.rot_logits.shape == (2, 3, 72)
    assert out.grip_logits.shape == out.collision_logits.shape == (2, 2)
    for feat in (out.state_feat, out.fused_feat, out.lang_feat, out.goal_feat):
        assert feat.shape == (2, 32)
    loss = (
        out.trans.logsumexp((-2, -1)).sum()
        + out.rot_logits.sum()
        + out.grip_logits.sum()
        + out.collision_logits.sum()
        + sum(
            (f * out.logit_scale).sum()
            for f in (out.state_feat, out.fused_feat, out.lang_feat, out.goal_feat)
        )
    )
    loss.backward()
    missing = {n for n, p in net.named_parameters() if p.grad is None or not p.grad.abs().sum() > 0}
    # The query tokens are zero-initialised (as in Σ-agent), so the first step cannot move the weight that
    # reads them; the tokens themselves do get a gradient.
    assert missing == {"fc_query.linear.weight"}, missing
    assert net.query_tokens.grad.abs().sum() > 0


def test_inference_skips_contrastive_features():
    net = SigmaNetwork(SMALL, 12, 12).eval()
    img, tok, _, _ = inputs(SMALL)
    out = net(img, tok)
    assert out.state_feat is None and out.goal_feat is None and out.logit_scale is None


@pytest.mark.parametrize("detach", [True, False])
def test_heatmap_feature_stop_gradient(detach: bool):
    cfg = dataclasses.replace(SMALL, detach_heatmap_for_features=detach)
    net = SigmaNetwork(cfg, 12, 12)
    img, tok, _, _ = inputs(cfg)
    net(img, tok).rot_logits.sum().backward()
    grad = net.trans_decoder[0].weight.grad
    reached = grad is not None and bool(grad.abs().sum() > 0)
    assert reached is (not detach)


def test_paper_query_variant_and_proprio_token():
    cfg = dataclasses.replace(SMALL, num_queries=5, query_attention="cross", use_proprio=True)
    net = SigmaNetwork(cfg, 12, 12)
    img, tok, sent, goal = inputs(cfg)
    out = net(img, tok, sent, goal, proprio=torch.rand(2, 3))
    assert out.fused_feat.shape == (2, 32) and out.trans.shape == (2, 5, 32, 32)
    with pytest.raises(ValueError, match="proprio"):
        net(img, tok)


def test_rvt_baseline_has_no_contrastive_heads():
    net = SigmaNetwork(dataclasses.replace(SMALL, use_contrastive=False), 12, 12)
    assert net.contrastive is None
    assert net.num_parameters() == net.num_parameters(inference_only=True)


def test_bad_image_shape_is_reported():
    net = SigmaNetwork(SMALL, 12, 12)
    img, tok, _, _ = inputs(SMALL)
    with pytest.raises(ValueError, match="expected images"):
        net(img[:, :3], tok)


@pytest.mark.parametrize("activation", ["relu", "leaky_relu"])
def test_head_units_below_zero_for_every_input_learn_only_when_leaky(activation: str):
    """A head unit whose pre-activation is negative for every input is dead under ReLU (no gradient reaches its
    weights: seen as a collapsed gripper/rotation head in a lift+stack run at lr 1e-2); LeakyReLU keeps it alive."""
    net = SigmaNetwork(dataclasses.replace(SMALL, head_activation=activation), 12, 12)
    first = net.feat_fc[0]
    with torch.no_grad():
        first.bias.fill_(-1e3)  # every unit below zero for any input
    img, tok, _, _ = inputs(SMALL)
    out = net(img, tok)
    (out.rot_logits.sum() + out.grip_logits.sum()).backward()
    grad = first.weight.grad.abs().sum().item()
    assert (grad > 0) == (activation == "leaky_relu"), grad


@pytest.mark.parametrize(("size", "scale", "pad"), [(20, 11, 5), (8, 8, 1), (5, 3, 0), (1, 4, 2)])
def test_matrix_upsample_equals_interpolate_then_replicate_pad(size: int, scale: int, pad: int):
    x = torch.randn(2, 3, size, size, dtype=torch.float64, requires_grad=True)
    ref = F.pad(
        F.interpolate(x, scale_factor=scale, mode="bilinear", align_corners=False), (pad,) * 4, "replicate"
    )
    out = BilinearUpsample(size, scale, pad)(x)
    torch.testing.assert_close(out, ref, rtol=0, atol=1e-12)
    g = torch.randn_like(ref)
    (grad_ref,) = torch.autograd.grad(ref, x, g)
    (grad_out,) = torch.autograd.grad(out, x, g)
    torch.testing.assert_close(grad_out, grad_ref, rtol=0, atol=1e-12)


def test_language_film_tells_word_order_apart_and_conditions_every_image_token():
    """Fusion attends over language tokens without positions, so without FiLM the network cannot see token
    order at all (only what the text encoder's contextual states carry); FiLM codes the tokens in order."""
    cfg = dataclasses.replace(SMALL, lang_film=True)
    net = SigmaNetwork(cfg, lang_token_dim=12, lang_sentence_dim=12, lang_length=6).eval()
    img, tok, _, _ = inputs(cfg, b=1)
    swapped = tok[:, [0, 2, 1, 3, 4, 5]]  # same tokens, two of them swapped: same mean
    torch.testing.assert_close(tok.mean(1), swapped.mean(1))
    with torch.no_grad():
        a, b = net(img, tok).trans, net(img, swapped).trans
    assert (a - b).abs().max() > 1e-3
    no_film = SigmaNetwork(SMALL, lang_token_dim=12, lang_sentence_dim=12, lang_length=6).eval()
    assert no_film.lang_film is None
    with torch.no_grad():
        torch.testing.assert_close(no_film(img, tok).trans, no_film(img, swapped).trans)
    extra = sum(p.numel() for p in net.lang_film.parameters())
    assert net.num_parameters() - no_film.num_parameters() == extra == (12 * 8 + 8) + (6 * 8 * 64 + 64)
    with pytest.raises(ValueError, match="expects 6 language tokens, got 5"):
        net(img, tok[:, :5])


def test_local_features_see_an_outline_wherever_it_lies_and_are_pooled_where_the_heatmap_says():
    """The heads' local encoder is convolutional: the same square drawn at two places of a view gives the same
    pooled features when the pooling heatmap follows it, and other features when the square is turned; its
    weights get gradients and a given heatmap (the target's, in training) replaces the predicted one."""
    from sigma_policy.heatmap import heatmap_pool
    from sigma_policy.layers import LocalEncoder

    enc = LocalEncoder(1, 8, (1, 2, 4)).eval()  # receptive field 15 px
    size = 48

    def square(cx: int, cy: int, turned: bool) -> torch.Tensor:
        yy, xx = torch.meshgrid(torch.arange(size), torch.arange(size), indexing="ij")
        dx, dy = (xx - cx).float(), (yy - cy).float()
        if turned:  # 45 degrees: a diamond
            dx, dy = (dx - dy) / 2**0.5, (dx + dy) / 2**0.5
        return ((dx.abs() <= 4) & (dy.abs() <= 4)).float()[None, None]

    def pooled(img: torch.Tensor, cx: int, cy: int) -> torch.Tensor:
        hm = torch.zeros(1, 1, size, size)
        hm[0, 0, cy, cx] = 1
        return heatmap_pool(hm, enc(img)[:, None])

    with torch.no_grad():
        a = pooled(square(14, 16, False), 14, 16)
        b = pooled(square(30, 27, False), 30, 27)
        turned = pooled(square(30, 27, True), 30, 27)
    torch.testing.assert_close(a, b)
    assert (a - turned).abs().max() > 1e-3

    cfg = dataclasses.replace(SMALL, local_channels=4, local_dilations=(1, 2))
    net = SigmaNetwork(cfg, lang_token_dim=12, lang_sentence_dim=12)
    img, tok, *_ = inputs(cfg)
    target = torch.zeros(2, 5, 32, 32)
    target[..., 3, 5] = 1
    out = net(img, tok, head_heatmap=target)
    assert not torch.allclose(out.rot_logits, net(img, tok).rot_logits)  # predicted heatmap elsewhere
    out.rot_logits.sum().backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in net.local_encoder.parameters())


def test_local_in_decoder_trains_the_local_encoder_through_the_heatmap():
    """With ``local_in_decoder`` the translation logits read the local features, so the translation loss alone
    trains the local encoder; without it only the heads do."""
    with pytest.raises(ValueError, match="local_in_decoder needs local_channels"):
        dataclasses.replace(SMALL, local_channels=0, local_in_decoder=True)
    for on in (False, True):
        cfg = dataclasses.replace(SMALL, local_channels=4, local_dilations=(1, 2), local_in_decoder=on)
        net = SigmaNetwork(cfg, lang_token_dim=12, lang_sentence_dim=12)
        img, tok, *_ = inputs(cfg)
        net(img, tok).trans.logsumexp((-2, -1)).sum().backward()
        grads = [p.grad for p in net.local_encoder.parameters()]
        assert (
            all(g is not None and g.abs().sum() > 0 for g in grads) if on else all(g is None for g in grads)
        )


def test_proprio_in_heads_widens_the_head_input():
    cfg = dataclasses.replace(SMALL, use_proprio=True, proprio_dim=12, proprio_in_heads=True)
    net = SigmaNetwork(cfg, lang_token_dim=12, lang_sentence_dim=12)
    assert net.feat_fc[0].in_features == 5 * (8 + 8) + 12
    img, tok, *_ = inputs(cfg)
    proprio = torch.randn(2, 12, requires_grad=True)
    net(img, tok, proprio=proprio).rot_logits.sum().backward()
    assert proprio.grad.abs().sum() > 0


def test_patch_channels_widen_the_patch_token_alone_and_every_new_weight_learns():
    cfg = dataclasses.replace(SMALL, patch_channels=24)
    net = SigmaNetwork(cfg, lang_token_dim=12, lang_sentence_dim=12)
    assert net.patchify[0].out_channels == 24 and net.fc_bef_attn.linear.in_features == 24
    assert net.pos_encoding.shape[-1] == net.contrastive.goal_pos_encoding.shape[-1] == 24
    # The decoder, the skip and the heads keep im_channels.
    assert net.up_conv0[0].in_channels == 8 and net.feat_fc[0].in_features == 5 * (8 + 8)
    img, tok, sent, goal = inputs(cfg)
    out = net(img, tok, sent, goal)
    (
        out.trans.logsumexp((-2, -1)).sum() + out.rot_logits.sum() + (out.goal_feat * out.state_feat).sum()
    ).backward()
    for param in (net.patchify[0].weight, net.pos_encoding, net.contrastive.goal_pos_encoding):
        assert param.grad.abs().sum() > 0
    # 0 is RVT's width; the suite preset with the option, as lerobot-train builds it.
    assert SMALL.patch_width == 8 and dataclasses.replace(SMALL, patch_channels=0).patch_width == 8
    sigma = SigmaConfig(preset="suite", device="cpu", patch_channels=128)
    assert sigma.network_config().patch_width == 128
    with pytest.raises(ValueError, match="patch_channels"):
        dataclasses.replace(SMALL, patch_channels=10)


def test_proprio_film_starts_as_identity_then_lets_the_heatmap_read_the_proprio():
    """Zero-initialised, the proprio FiLM leaves the network as it was; its weights get gradients from the
    translation loss alone, and once they are non-zero the heatmap changes with the proprio vector."""
    base = dataclasses.replace(SMALL, use_proprio=True, proprio_dim=3)
    film = SigmaNetwork(dataclasses.replace(base, proprio_film=True), lang_token_dim=12, lang_sentence_dim=12)
    plain = SigmaNetwork(base, lang_token_dim=12, lang_sentence_dim=12)
    plain.load_state_dict({k: v for k, v in film.state_dict().items() if not k.startswith("proprio_film.")})
    assert plain.proprio_film is None
    img, tok, *_ = inputs(base)
    proprio = torch.tensor([[1.0, 0.04, -0.04], [0.0, 0.0, 0.0]])
    with torch.no_grad():
        assert torch.allclose(film(img, tok, proprio=proprio).trans, plain(img, tok, proprio=proprio).trans)
    film(img, tok, proprio=proprio).trans.square().sum().backward()
    assert film.proprio_film.out.weight.grad.abs().sum() > 0
    with torch.no_grad():
        film.proprio_film.out.weight.normal_()
        swapped = proprio.flip(0)
        a, b = film(img, tok, proprio=proprio).trans, film(img, tok, proprio=swapped).trans
    assert not torch.allclose(a, b, atol=1e-4)


def test_yaw_scan_adds_to_the_yaw_logits_only_and_follows_the_given_centre():
    """The scanner's scores join the yaw logits (roll and pitch are the MLP's alone); a given centre (the target's, in
    training) replaces the predicted one, and the scanner's weights get gradients."""
    cfg = dataclasses.replace(SMALL, yaw_scan_px=8, yaw_scan_channels=4)
    net = SigmaNetwork(cfg, lang_token_dim=12, lang_sentence_dim=12)
    img, tok, *_ = inputs(cfg)
    plain = SigmaNetwork(SMALL, lang_token_dim=12, lang_sentence_dim=12)
    plain.load_state_dict(net.state_dict(), strict=False)
    with torch.no_grad():
        with_scan, without = net(img, tok).rot_logits, plain(img, tok).rot_logits
    torch.testing.assert_close(with_scan[:, :2], without[:, :2])
    assert (with_scan[:, 2] - without[:, 2]).abs().max() > 1e-4
    out = net(img, tok, head_uv=torch.full((2, 5, 2), 3.5))
    assert not torch.allclose(
        out.rot_logits[:, 2], net(img, tok).rot_logits[:, 2]
    )  # predicted point elsewhere
    out.rot_logits.sum().backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in net.yaw_scanner.parameters())
    with pytest.raises(ValueError, match="yaw_scan_px"):
        dataclasses.replace(SMALL, yaw_scan_px=7)
    with pytest.raises(ValueError, match="even num_rotation_bins"):
        dataclasses.replace(SMALL, yaw_scan_px=8, num_rotation_bins=45)


def test_a_pixels_skip_features_are_a_function_of_that_pixel_alone():
    """``d0`` (the patch embedding's input and the decoder's skip) is the 1x1 input convolution's: a pixel's
    features do not change when a neighbour's do (the 3 x 3 stem that widened them is retired, docs/learning.md)."""
    net = SigmaNetwork(SMALL, lang_token_dim=12, lang_sentence_dim=12)
    img = torch.rand(1, 5, 10, 32, 32, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        base = net._encode_views(img, net.pos_encoding)[1]
        for shift in (0, 1):
            moved = img.clone()
            moved[0, 0, :, 16, 16 + shift] += 1.0
            d0 = net._encode_views(moved, net.pos_encoding)[1]
            changed = (d0[0, :, 16, 16] - base[0, :, 16, 16]).abs().max() > 1e-6
            assert changed == (shift == 0), shift


def test_activation_layout_leaves_every_output_and_gradient_as_it_was():
    # ConvBlock's NHWC default on the CPU is a speed choice: the network computes the same function.
    cfg = dataclasses.replace(SMALL, local_channels=4, yaw_scan_px=12, use_proprio=True)
    grads = {}
    for layout in (False, None):
        torch.manual_seed(0)
        net = SigmaNetwork(dataclasses.replace(cfg, channels_last=layout), 12, 12, lang_length=6)
        img, tok, sent, goal = inputs(cfg)
        out = net(
            img, tok, sent, goal, torch.rand(2, cfg.proprio_dim, generator=torch.Generator().manual_seed(1))
        )
        loss = out.trans.square().mean() + out.rot_logits.square().mean() + out.goal_feat.square().mean()
        loss.backward()
        grads[layout] = [out.trans, out.rot_logits] + [p.grad for p in net.parameters()]
    for nchw, auto in zip(grads[False], grads[None], strict=True):
        torch.testing.assert_close(auto, nchw, rtol=1e-4, atol=1e-5)
