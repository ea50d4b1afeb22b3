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
   image tokens are first scaled and shifted by an ordered code of the tokens, and with ``proprio_film`` by a
   linear map of the proprio vector (:mod:`sigma_policy.conditioning`).
6. Decoder: image tokens -> Linear D -> c -> per view conv k at T x T, bilinear x patch_size, conv k, concat ``d0``
   (and, with ``local_in_decoder``, the local features of step 7), conv 3x3 -> ``u`` (BV, ``final_dim``, H, W)
   -> conv 3x3 -> translation logits (B, V, H, W).
7. Heads: [max over tokens (c*V, channel-major), heatmap-weighted sum of ``u`` (V*final_dim, view-major)] -> MLP
   -> 3 x ``num_rotation_bins`` Euler-bin logits, 2 gripper logits, 2 collision logits. Not in the paper, all
   off in ``paper``: ``local_channels`` adds a heatmap-weighted sum of full-resolution local features
   (:class:`~sigma_policy.layers.LocalEncoder`) and ``proprio_in_heads`` the proprio vector to the MLP's input;
   ``yaw_scan_px`` adds rotation-equivariant scores of a turned top-view crop to the yaw logits
   (:class:`~sigma_policy.yaw_scan.YawScanner`).
8. Goal branch (training, contrastive): the goal render shares steps 1-3 (own positional encoding), tokens are
   mean-pooled per view, concatenated over views and projected -> ``goal_feat`` (phi(g)).

Attention is ``F.scaled_dot_product_attention`` without masks (flash / memory-efficient kernels on GPU).
With the paper numbers (``NetworkConfig()``, sigma_policy/network_config.py, and 77 x 512 CLIP tokens) the module
has 38,259,614 parameters, of which 2,227,201 belong to the contrastive heads (``SigmaNetwork.contrastive``) and
are unused at inference.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn

from sigma_policy.conditioning import LanguageFiLM, ProprioFiLM
from sigma_policy.heatmap import gaussian_heatmaps, heatmap_pool, predicted_uv
from sigma_policy.layers import LRELU_SLOPE, ConvBlock, DenseBlock, LocalEncoder
from sigma_policy.network_config import NetworkConfig
from sigma_policy.transformer import TransformerLayer
from sigma_policy.upsample import BilinearUpsample
from sigma_policy.yaw_scan import YawScanner


def _stack(cfg: NetworkConfig, n: int, cross: bool = False) -> nn.ModuleList:
    return nn.ModuleList(
        TransformerLayer(cfg.attn_dim, cfg.attn_heads, cfg.attn_dim_head, cfg.attn_dropout, cross)
        for _ in range(n)
    )


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
        decoder_in = 2 * c + cfg.local_channels * cfg.local_in_decoder
        self.final = ConvBlock(decoder_in, cfg.final_dim, kernel=3)
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
        self.set_conv_layout(cfg.channels_last)

    # ------------------------------------------------------------------ helpers
    def set_conv_layout(self, channels_last: bool | None) -> None:
        """Every convolution's activation layout (``NetworkConfig.channels_last``; the same values either way)."""
        for module in self.modules():
            if isinstance(module, ConvBlock):
                module.channels_last = channels_last

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
        d0 = self.input_preprocess(images.reshape(b * v, ch, h, w))
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
        fusion: str = "sum",
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
            fusion: how the views' heatmaps fuse into that predicted point (``heatmap_to_cube_point``).
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
        local = (
            self.local_encoder(images.reshape(b * cfg.num_views, *images.shape[2:]))
            if self.local_encoder is not None
            else None
        )
        decoder_in = torch.cat([x, d0, local] if cfg.local_in_decoder else [x, d0], dim=1)
        u = self.final(decoder_in)  # (BV, final_dim, H, W)
        trans = self.trans_decoder(u).reshape(b, cfg.num_views, cfg.img_size, cfg.img_size)

        hm_logits = trans.detach() if cfg.detach_heatmap_for_features else trans
        hm = torch.softmax(hm_logits.flatten(2).float(), dim=-1).reshape(trans.shape)  # (B, V, H, W)
        head_in = [max_feat, heatmap_pool(hm, u.reshape(b, cfg.num_views, *u.shape[1:]))]  # (B, V*final_dim)
        # At inference the heads' pooling and the yaw scan both sit at the predicted point: lift it once.
        lifted = (self.local_encoder is not None and head_heatmap is None) or (
            self.yaw_scanner is not None and head_uv is None
        )
        pred_uv = predicted_uv(trans.detach(), cfg.side_tilt_deg, fusion, cfg.views) if lifted else None
        if local is not None:
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
