"""The Σ-agent network: an RVT-style multi-view transformer with an MVQ-Former query stage.

Shapes (B = batch, V = virtual views, C_in = rendered channels (10), H = W = ``img_size``,
T = ``img_size // patch_size`` patches per side, D = ``attn_dim``, L = language tokens):

1. ``input_preprocess`` 1x1 conv C_in -> ``im_channels`` on every view -> ``d0`` (BV, c, H, W) (kept as a skip).
2. ``patchify`` conv k = stride = ``patch_size`` -> (BV, p, T, T) -> V*T*T tokens + learnable positional encoding
   -> Linear p -> D; p = ``patch_channels``, by default ``im_channels`` (RVT's).
3. Intra-view encoder (``num_view_layers``): self-attention inside each view (sequence T*T).
4. MVQ-Former (``num_query_layers``): ``num_queries`` learnable query tokens (zero-init, c -> D) with either full
   self-attention over [queries, all image tokens] (released code) or cross-attention queries -> image tokens
   (paper text). Query output -> ``img_feat`` (state feature phi(s_t) for the contrastive loss).
5. Fusion (``num_fusion_layers``): Linear D -> D on [language, (proprio), queries, image tokens], then full
   self-attention. Query output -> ``fused_feat`` (delta(s_t, l)). Language tokens carry no position here, so
   fusion sees the instruction as a set of contextual token states; with ``lang_film`` (not in the paper) the
   image tokens are first scaled and shifted by an ordered code of the tokens (:class:`LanguageFiLM`), and with
   ``proprio_film`` by a linear map of the proprio vector (:class:`ProprioFiLM`).
6. Decoder: image tokens -> Linear D -> c -> per view conv k at T x T, bilinear x patch_size, conv k, concat ``d0``,
   conv 3x3 -> ``u`` (BV, ``final_dim``, H, W) -> conv 3x3 -> translation logits (B, V, H, W).
7. Heads: [max over tokens (c*V, channel-major), heatmap-weighted sum of ``u`` (V*final_dim, view-major)] -> MLP
   -> 3 x ``num_rotation_bins`` Euler-bin logits, 2 gripper logits, 2 collision logits. Not in the paper, all
   off in ``paper``: ``local_channels`` adds a heatmap-weighted sum of full-resolution local features
   (:class:`LocalEncoder`) and ``proprio_in_heads`` the proprio vector to the MLP's input; ``yaw_scan_px`` adds
   rotation-equivariant scores of a turned top-view crop to the yaw logits (:class:`~sigma_policy.yaw_scan.YawScanner`).
8. Goal branch (training, contrastive): the goal render shares steps 1-3 (own positional encoding), tokens are
   mean-pooled per view, concatenated over views and projected -> ``goal_feat`` (phi(g)).

Attention is ``F.scaled_dot_product_attention`` without masks (flash / memory-efficient kernels on GPU).
With the paper numbers (``NetworkConfig()`` and 77 x 512 CLIP tokens) the module has 38,259,614 parameters, of
which 2,227,201 belong to the contrastive heads (``SigmaNetwork.contrastive``) and are unused at inference.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import torch
from torch import Tensor, nn

from sigma_policy.heatmap import gaussian_heatmaps, heatmap_to_cube_point
from sigma_policy.layers import LRELU_SLOPE, ConvBlock, DenseBlock
from sigma_policy.transformer import TransformerLayer
from sigma_policy.upsample import BilinearUpsample
from sigma_policy.views import project_points, tilt_slope
from sigma_policy.yaw_scan import YawScanner

VIEW_CHANNELS = 10  # a rendered view: xyz, rgb, depth, view id, row, col (sigma_policy/renderer.py)


@dataclass(frozen=True)
class NetworkConfig:
    """Architecture numbers; the defaults are the paper / released-code configuration (docs/method.md §5, §12)."""

    num_views: int = 5
    in_channels: int = VIEW_CHANNELS
    img_size: int = 220
    patch_size: int = 11
    im_channels: int = 64
    # Width of a patch token before its Linear to ``attn_dim`` (not in the paper); 0 = ``im_channels``, RVT's. The
    # patch convolution maps patch_size² x im_channels numbers to it: at ``small``'s 8-pixel patches of 16 channels
    # that is 1024 -> 16, where ViT's embedding keeps a patch's width (docs/learning.md "A wider patch token").
    patch_channels: int = 0
    attn_dim: int = 512
    attn_heads: int = 8
    attn_dim_head: int = 64
    attn_dropout: float = 0.1
    num_view_layers: int = 2
    num_query_layers: int = 2
    num_fusion_layers: int = 4
    num_queries: int = 1
    query_attention: Literal["self", "cross"] = "self"
    decoder_kernel: int = 11
    final_dim: int = 64
    head_hidden_dims: tuple[int, int] = (128, 64)
    num_rotation_bins: int = 72
    use_contrastive: bool = True
    projection_activation: bool = True
    detach_heatmap_for_features: bool = True
    use_proprio: bool = False
    # Activation of the rotation/gripper/collision MLP: "relu" (RVT and the released code) or "leaky_relu"
    # (slope LRELU_SLOPE, like the rest of the network: a unit pushed below zero for every input still learns).
    head_activation: Literal["relu", "leaky_relu"] = "relu"
    # Instruction FiLM (not in the paper): every image token entering fusion is scaled and shifted per channel by
    # a code of the instruction's tokens taken in order (:class:`LanguageFiLM`). Instructions that differ only in
    # word order ("red on green" / "green on red") get sentence features 0.994 apart (cosine) but distinct codes.
    lang_film: bool = False
    lang_film_code_dim: int = 8
    proprio_dim: int = 3
    # The proprio vector also enters the rotation/gripper/collision MLP directly (not only as a fusion token).
    proprio_in_heads: bool = False
    # Proprio FiLM (not in the paper): every image token entering fusion is also scaled and shifted per channel by
    # a linear map of the proprio vector (:class:`ProprioFiLM`), so the decoder that draws the heatmap reads the
    # gripper state directly, not only through attention to the proprio token; RVT-1 concatenates its proprio to
    # every patch for the same reason (docs/method.md §13).
    proprio_film: bool = False
    # Local features for the heads (not in the paper; RVT-2 reads rotation at the predicted location of a zoomed
    # stage): ``local_channels`` > 0 adds a full-resolution dilated CNN on each rendered view
    # (:class:`LocalEncoder`), pooled per view by a heatmap (the target's in training, the same Gaussian at the
    # predicted point at inference), so the heads see the object's outline around the keyframe position, e.g. a cube's edges.
    local_channels: int = 0
    local_dilations: tuple[int, ...] = (1, 2, 4, 8)
    # Width (pixels) of the Gaussian that pools the local features: in training the target heatmap has it, at
    # inference the same Gaussian sits at the predicted 3D point's projections, so the heads see the same pooling.
    head_pool_sigma: float = 1.5
    # Rotation-equivariant yaw scores (not in the paper; sigma_policy/yaw_scan.py): ``yaw_scan_px`` > 0 turns a
    # top-view crop of this many pixels, centred at the keyframe position (the target's in training, the predicted
    # point's at inference), to every yaw bin, scores each with one CNN of ``yaw_scan_channels`` channels and adds
    # the scores to the yaw logits.
    yaw_scan_px: int = 0
    yaw_scan_channels: int = 16
    # Side views tilted down by this angle (not in the paper; sigma_policy/views.py), so they see over a container's
    # rim: the network only needs it to back-project its own heatmaps at inference (the local features' pooling and
    # the yaw scan's crop centre). 0 = RVT's horizontal side views.
    side_tilt_deg: float = 0.0
    logit_scale_init: float = math.log(1 / 0.07)
    channels_last: bool = False  # NHWC conv activations: the layout tensor-core convolutions want on GPUs

    def __post_init__(self) -> None:
        if self.img_size % self.patch_size:
            raise ValueError(f"img_size {self.img_size} must be a multiple of patch_size {self.patch_size}")
        if self.query_attention not in ("self", "cross"):
            raise ValueError(f"query_attention must be 'self' or 'cross', got {self.query_attention!r}")
        if self.head_activation not in ("relu", "leaky_relu"):
            raise ValueError(f"head_activation must be 'relu' or 'leaky_relu', got {self.head_activation!r}")
        if self.num_queries < 1:
            raise ValueError(f"num_queries must be >= 1, got {self.num_queries}")
        tilt_slope(self.side_tilt_deg)  # 0 <= angle < 90
        if self.local_channels < 0 or (self.local_channels and not self.local_dilations):
            raise ValueError("local_channels must be >= 0, with at least one dilation when > 0")
        if self.yaw_scan_px < 0 or (self.yaw_scan_px and (self.yaw_scan_px % 2 or self.yaw_scan_px < 8)):
            raise ValueError(f"yaw_scan_px must be 0 (off) or an even number >= 8, got {self.yaw_scan_px}")
        if self.yaw_scan_px and self.num_rotation_bins % 2:
            raise ValueError(
                f"yaw_scan_px needs an even num_rotation_bins (half a turn), got {self.num_rotation_bins}"
            )
        if self.im_channels % 4 or self.attn_dim % 4 or self.patch_channels % 4 or self.patch_channels < 0:
            raise ValueError(
                "im_channels, patch_channels and attn_dim must be multiples of 4 (GroupNorm(4, .)), "
                f"patch_channels 0 (im_channels) or more; got {self.im_channels}, {self.patch_channels}, "
                f"{self.attn_dim}"
            )

    @property
    def patch_width(self) -> int:
        """Channels of a patch token before the Linear to ``attn_dim``: ``patch_channels``, else ``im_channels``."""
        return self.patch_channels or self.im_channels

    @property
    def tokens_per_side(self) -> int:
        return self.img_size // self.patch_size


def _stack(cfg: NetworkConfig, n: int, cross: bool = False) -> nn.ModuleList:
    return nn.ModuleList(
        TransformerLayer(cfg.attn_dim, cfg.attn_heads, cfg.attn_dim_head, cfg.attn_dropout, cross)
        for _ in range(n)
    )


class LanguageFiLM(nn.Module):
    """Instruction -> per-channel scale and shift of image tokens: ``img * (1 + gamma) + beta``.

    Each token state (L, D_tok) is projected to ``code_dim`` numbers and the L codes are concatenated in order, so
    the result depends on which word sits where (a mean over tokens would not tell the stacking orders apart).
    """

    def __init__(self, token_dim: int, length: int, dim: int, code_dim: int):
        super().__init__()
        self.length = length
        self.token_proj = DenseBlock(token_dim, code_dim)
        self.out = DenseBlock(length * code_dim, 2 * dim, act=False)

    def forward(self, lang_tokens: Tensor, img: Tensor) -> Tensor:
        if lang_tokens.shape[1] != self.length:
            raise ValueError(
                f"LanguageFiLM expects {self.length} language tokens, got {lang_tokens.shape[1]}"
            )
        gamma, beta = self.out(self.token_proj(lang_tokens).flatten(1)).unsqueeze(1).chunk(2, dim=-1)
        return img * (1 + gamma) + beta


class ProprioFiLM(nn.Module):
    """Proprio vector (B, P) -> per-channel scale and shift of image tokens: ``img * (1 + gamma) + beta``. Zero
    initialised, so it starts as the identity and the proprio token's route is unchanged at step 0."""

    def __init__(self, proprio_dim: int, dim: int):
        super().__init__()
        self.out = nn.Linear(proprio_dim, 2 * dim)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def forward(self, proprio: Tensor, img: Tensor) -> Tensor:
        gamma, beta = self.out(proprio.to(img.dtype)).unsqueeze(1).chunk(2, dim=-1)
        return img * (1 + gamma) + beta


class LocalEncoder(nn.Sequential):
    """Full-resolution 3x3 convolutions with growing dilation on a rendered view: (BV, C_in, H, W) ->
    (BV, channels, H, W). With dilations (1, 2, 4, 8) each output pixel sees 31 x 31 input pixels, a 4 cm cube
    and its surroundings in the ``small`` preset's 5.6 mm pixels; being convolutional, the same outline gives the
    same features wherever it lies in the view."""

    def __init__(self, c_in: int, channels: int, dilations: tuple[int, ...]):
        super().__init__(
            *(
                ConvBlock(c_in if i == 0 else channels, channels, 3, dilation=d)
                for i, d in enumerate(dilations)
            )
        )


def predicted_uv(logits: Tensor, side_tilt_deg: float = 0.0) -> Tensor:
    """Pixel coordinates ``(B, V, 2)`` of the projections of the 3D point the translation logits ``(B, V, H, W)``
    predict (:func:`~sigma_policy.heatmap.heatmap_to_cube_point`): the views agree on one point, as the training
    target's projections do, even where one view's own peak lies elsewhere."""
    size = logits.shape[-1]
    point = heatmap_to_cube_point(logits, size, side_tilt_deg=side_tilt_deg)
    return project_points(point[:, None].to(logits.dtype), size, side_tilt_deg)[0][:, 0]


def heads_at_point(logits: Tensor, side_tilt_deg: float, sigma_px: float) -> dict[str, Tensor]:
    """The network's ``head_heatmap`` and ``head_uv`` arguments that run its heads at the point the translation
    logits ``(B, V, H, W)`` predict (:func:`predicted_uv`): pooled there with a Gaussian of ``sigma_px`` pixels, as
    training pools them at the target, and the yaw scan centred there. For a second run of the heads after the
    logits were changed (instruction contrast, ensembles)."""
    uv = predicted_uv(logits, side_tilt_deg)
    return {"head_heatmap": gaussian_heatmaps(uv, logits.shape[-1], sigma=sigma_px), "head_uv": uv}


def heatmap_pool(heatmap: Tensor, features: Tensor) -> Tensor:
    """Per-view sum of ``features`` (B, V, C, H, W) weighted by ``heatmap`` (B, V, H, W) -> (B, V*C), view-major."""
    b, v = heatmap.shape[:2]
    weights = heatmap.reshape(b, v, -1).to(features.dtype)
    return torch.einsum("bvn,bvcn->bvc", weights, features.reshape(b, v, features.shape[2], -1)).flatten(1)


class ContrastiveHeads(nn.Module):
    """Everything only the contrastive loss needs (dropped from the inference parameter count)."""

    def __init__(self, cfg: NetworkConfig, lang_sentence_dim: int):
        super().__init__()
        d, n_tok = cfg.attn_dim, cfg.num_views * cfg.tokens_per_side**2
        act = cfg.projection_activation
        self.goal_pos_encoding = nn.Parameter(torch.randn(1, n_tok, cfg.patch_width))
        self.state_proj = DenseBlock(d, d, act=act)  # phi(s_t): query after the MVQ-Former
        self.fused_proj = DenseBlock(d, d, act=act)  # delta(s_t, l): query after fusion
        self.lang_proj = DenseBlock(lang_sentence_dim, d, act=act)  # psi(l)
        self.goal_proj = DenseBlock(cfg.num_views * d, d, act=act)  # phi(g)
        self.logit_scale = nn.Parameter(torch.tensor(cfg.logit_scale_init))


@dataclass
class NetworkOutput:
    """Raw network outputs. Logits are unnormalised; features are not L2-normalised."""

    trans: Tensor  # (B, V, H, W) translation heatmap logits (softmax per view)
    rot_logits: Tensor  # (B, 3, num_rotation_bins) Euler x, y, z bins
    grip_logits: Tensor  # (B, 2), class 1 = open
    collision_logits: Tensor  # (B, 2), class 1 = ignore collisions
    state_feat: Tensor | None = None  # (B, D) phi(s_t)
    fused_feat: Tensor | None = None  # (B, D) delta(s_t, l)
    lang_feat: Tensor | None = None  # (B, D) psi(l)
    goal_feat: Tensor | None = None  # (B, D) phi(g)
    logit_scale: Tensor | None = None  # scalar, exp of the learnable log-scale (1 / temperature)


class SigmaNetwork(nn.Module):
    """Σ-agent MVQ-Former network. See the module docstring for the data flow."""

    def __init__(
        self, cfg: NetworkConfig, lang_token_dim: int, lang_sentence_dim: int, lang_length: int = 77
    ):
        super().__init__()
        self.cfg = cfg
        c, d, t = cfg.im_channels, cfg.attn_dim, cfg.tokens_per_side
        n_tok = cfg.num_views * t * t

        self.input_preprocess = ConvBlock(cfg.in_channels, c, kernel=1)
        p = cfg.patch_width
        self.patchify = ConvBlock(c, p, kernel=cfg.patch_size, stride=cfg.patch_size, norm=True)
        self.pos_encoding = nn.Parameter(torch.randn(1, n_tok, p))
        self.fc_bef_attn = DenseBlock(p, d, act=False)
        self.view_layers = _stack(cfg, cfg.num_view_layers)

        self.query_tokens = nn.Parameter(torch.zeros(1, cfg.num_queries, c))
        self.fc_query = DenseBlock(c, d, act=False)
        self.query_layers = _stack(cfg, cfg.num_query_layers, cross=cfg.query_attention == "cross")

        self.lang_preprocess = DenseBlock(lang_token_dim, d, norm=True)
        self.proprio_preprocess = DenseBlock(cfg.proprio_dim, d) if cfg.use_proprio else None
        self.proprio_film = ProprioFiLM(cfg.proprio_dim, d) if cfg.use_proprio and cfg.proprio_film else None
        self.lang_film = (
            LanguageFiLM(lang_token_dim, lang_length, d, cfg.lang_film_code_dim) if cfg.lang_film else None
        )
        self.fc_bef_fusion = DenseBlock(d, d, act=False)
        self.fusion_layers = _stack(cfg, cfg.num_fusion_layers)
        self.fc_aft_attn = DenseBlock(d, c, act=False)

        k = cfg.decoder_kernel
        self.up_conv0 = ConvBlock(c, c, kernel=k)
        # Bilinear x patch_size, with up_conv1's replicate border built in (k // 2 pixels).
        self.upsample = BilinearUpsample(t, cfg.patch_size, pad=k // 2)
        self.up_conv1 = ConvBlock(c, c, kernel=k, pre_padded=True)
        self.final = ConvBlock(2 * c, cfg.final_dim, kernel=3)
        self.trans_decoder = ConvBlock(cfg.final_dim, 1, kernel=3, act=False)

        h1, h2 = cfg.head_hidden_dims

        def act() -> nn.Module:
            return nn.ReLU() if cfg.head_activation == "relu" else nn.LeakyReLU(LRELU_SLOPE)

        self.local_encoder = (
            LocalEncoder(cfg.in_channels, cfg.local_channels, cfg.local_dilations)
            if cfg.local_channels
            else None
        )
        self.yaw_scanner = (
            YawScanner(cfg.in_channels, cfg.yaw_scan_channels, cfg.yaw_scan_px, cfg.num_rotation_bins)
            if cfg.yaw_scan_px
            else None
        )
        head_in = cfg.num_views * (c + cfg.final_dim + cfg.local_channels)
        head_in += cfg.proprio_dim if cfg.use_proprio and cfg.proprio_in_heads else 0
        self.feat_fc = nn.Sequential(
            nn.Linear(head_in, h1),
            act(),
            nn.Linear(h1, h2),
            act(),
            nn.Linear(h2, 3 * cfg.num_rotation_bins + 4),
        )
        self.contrastive = ContrastiveHeads(cfg, lang_sentence_dim) if cfg.use_contrastive else None

    # ------------------------------------------------------------------ helpers
    def num_parameters(self, inference_only: bool = False) -> int:
        """Parameter count; ``inference_only`` leaves out the contrastive heads."""
        total = sum(p.numel() for p in self.parameters())
        if inference_only and self.contrastive is not None:
            total -= sum(p.numel() for p in self.contrastive.parameters())
        return total

    def _encode_views(self, images: Tensor, pos_encoding: Tensor) -> tuple[Tensor, Tensor]:
        """(B, V, C_in, H, W) -> view-encoded tokens (B, V, T*T, D) and the full-resolution skip d0."""
        b, v, ch, h, w = images.shape
        if (v, ch, h) != (self.cfg.num_views, self.cfg.in_channels, self.cfg.img_size) or h != w:
            raise ValueError(
                f"expected images (B, {self.cfg.num_views}, {self.cfg.in_channels}, {self.cfg.img_size}, "
                f"{self.cfg.img_size}), got {tuple(images.shape)}"
            )
        x = images.reshape(b * v, ch, h, w)
        if self.cfg.channels_last:
            x = x.contiguous(memory_format=torch.channels_last)
        d0 = self.input_preprocess(x)
        patches = self.patchify(d0)  # (BV, c, T, T)
        c, t = patches.shape[1], patches.shape[-1]
        tokens = patches.reshape(b, v, c, t * t).transpose(2, 3).reshape(b, v * t * t, c)
        tokens = self.fc_bef_attn(tokens + pos_encoding).reshape(b * v, t * t, -1)
        for layer in self.view_layers:
            tokens = layer(tokens)
        return tokens.reshape(b, v, t * t, -1), d0

    def encode_goal(self, goal_images: Tensor) -> Tensor:
        """Goal render (B, V, C_in, H, W) -> phi(g) (B, D): shared encoder, own PE, per-view mean, projection."""
        if self.contrastive is None:
            raise RuntimeError("encode_goal needs use_contrastive=True")
        tokens, _ = self._encode_views(goal_images, self.contrastive.goal_pos_encoding)
        return self.contrastive.goal_proj(tokens.mean(dim=2).flatten(1))

    # ------------------------------------------------------------------ forward
    def forward(
        self,
        images: Tensor,
        lang_tokens: Tensor,
        lang_sentence: Tensor | None = None,
        goal_images: Tensor | None = None,
        proprio: Tensor | None = None,
        head_heatmap: Tensor | None = None,
        head_uv: Tensor | None = None,
    ) -> NetworkOutput:
        """Run the network.

        Args:
            images: (B, V, C_in, H, W) rendered virtual views of the current state.
            lang_tokens: (B, L, lang_token_dim) frozen text-encoder token embeddings.
            lang_sentence: (B, lang_sentence_dim) sentence feature; with ``goal_images`` it enables the
                contrastive features (training only).
            goal_images: (B, V, C_in, H, W) rendered goal state (training only).
            proprio: (B, proprio_dim), only with ``use_proprio``.
            head_heatmap: (B, V, H, W) weights that pool the local features for the heads (training: the target
                heatmap); None = the same Gaussian at the predicted 3D point's projections (inference). Only with
                ``local_channels``.
            head_uv: (B, V, 2) pixel of the keyframe position where the yaw scan's crop is centred (training: the
                target's projections); None = the predicted 3D point's projections (inference). Only with
                ``yaw_scan_px``.
        """
        cfg = self.cfg
        b = images.shape[0]
        view_tokens, d0 = self._encode_views(images, self.pos_encoding)
        t = cfg.tokens_per_side
        img = view_tokens.reshape(b, cfg.num_views * t * t, -1)

        query = self.fc_query(self.query_tokens).expand(b, -1, -1)
        nq = query.shape[1]
        if cfg.query_attention == "self":
            seq = torch.cat([query, img], dim=1)
            for layer in self.query_layers:
                seq = layer(seq)
            query, img = seq[:, :nq], seq[:, nq:]
        else:
            for layer in self.query_layers:
                query = layer(query, context=img)
        state_query = query.mean(dim=1)

        prefix = [self.lang_preprocess(lang_tokens)]
        if self.proprio_preprocess is not None:
            if proprio is None:
                raise ValueError("use_proprio=True needs a proprio tensor (B, proprio_dim)")
            prefix.append(self.proprio_preprocess(proprio).unsqueeze(1))
        n_prefix = sum(p.shape[1] for p in prefix)
        if self.lang_film is not None:
            img = self.lang_film(lang_tokens, img)
        if self.proprio_film is not None:
            img = self.proprio_film(proprio, img)
        seq = self.fc_bef_fusion(torch.cat([*prefix, query, img], dim=1))
        for layer in self.fusion_layers:
            seq = layer(seq)
        fused_query = seq[:, n_prefix : n_prefix + nq].mean(dim=1)
        img = seq[:, n_prefix + nq :]

        feat_tokens = self.fc_aft_attn(img)  # (B, V*T*T, c)
        c = feat_tokens.shape[-1]
        feat_maps = feat_tokens.reshape(b, cfg.num_views, t, t, c).permute(0, 1, 4, 2, 3)  # (B, V, c, T, T)
        max_feat = feat_maps.amax(dim=(-2, -1)).transpose(1, 2).flatten(1)  # (B, c*V), channel-major

        x = self.up_conv1(self.upsample(self.up_conv0(feat_maps.reshape(b * cfg.num_views, c, t, t))))
        u = self.final(torch.cat([x, d0], dim=1))  # (BV, final_dim, H, W)
        trans = self.trans_decoder(u).reshape(b, cfg.num_views, cfg.img_size, cfg.img_size)

        hm_logits = trans.detach() if cfg.detach_heatmap_for_features else trans
        hm = torch.softmax(hm_logits.flatten(2).float(), dim=-1).reshape(trans.shape)  # (B, V, H, W)
        head_in = [max_feat, heatmap_pool(hm, u.reshape(b, cfg.num_views, *u.shape[1:]))]  # (B, V*final_dim)
        # At inference the heads' pooling and the yaw scan both sit at the predicted point: lift it once.
        lifted = (self.local_encoder is not None and head_heatmap is None) or (
            self.yaw_scanner is not None and head_uv is None
        )
        pred_uv = predicted_uv(trans.detach(), cfg.side_tilt_deg) if lifted else None
        if self.local_encoder is not None:
            local = self.local_encoder(images.reshape(b * cfg.num_views, *images.shape[2:]))
            weights = (
                gaussian_heatmaps(pred_uv, cfg.img_size, sigma=cfg.head_pool_sigma)
                if head_heatmap is None
                else head_heatmap
            )
            head_in.append(heatmap_pool(weights, local.reshape(b, cfg.num_views, *local.shape[1:])))
        if self.proprio_preprocess is not None and cfg.proprio_in_heads:
            head_in.append(proprio.to(max_feat.dtype))

        head = self.feat_fc(torch.cat(head_in, dim=1))
        nb = cfg.num_rotation_bins
        rot_logits = head[:, : 3 * nb].reshape(b, 3, nb)
        if self.yaw_scanner is not None:
            uv = pred_uv if head_uv is None else head_uv
            scan = self.yaw_scanner(images, uv).to(rot_logits.dtype)
            rot_logits = torch.cat([rot_logits[:, :2], (rot_logits[:, 2] + scan)[:, None]], dim=1)
        out = NetworkOutput(
            trans=trans,
            rot_logits=rot_logits,
            grip_logits=head[:, 3 * nb : 3 * nb + 2],
            collision_logits=head[:, 3 * nb + 2 : 3 * nb + 4],
        )
        if self.contrastive is not None and lang_sentence is not None and goal_images is not None:
            heads = self.contrastive
            out.state_feat = heads.state_proj(state_query)
            out.fused_feat = heads.fused_proj(fused_query)
            out.lang_feat = heads.lang_proj(lang_sentence)
            out.goal_feat = self.encode_goal(goal_images)
            out.logit_scale = heads.logit_scale.exp()
        return out
