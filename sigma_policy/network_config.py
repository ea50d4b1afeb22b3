"""The Σ-agent network's architecture numbers (:class:`NetworkConfig`). The policy config's ``network_config()``
(sigma_policy/configuration_sigma.py) fills them from its preset; the data flow they shape is in
:mod:`sigma_policy.network`."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from sigma_policy.views import ALL_VIEWS, check_views, tilt_slope

__all__ = ["VIEW_CHANNELS", "NetworkConfig"]

VIEW_CHANNELS = 10  # a rendered view: xyz, rgb, depth, view id, row, col (sigma_policy/renderer.py)


@dataclass(frozen=True)
class NetworkConfig:
    """Architecture numbers; the defaults are the paper / released-code configuration (docs/method.md §5, §12)."""

    # The rendered views, indices into sigma_policy/views.py VIEW_NAMES: RVT's five, or a subset with the top view
    # (RVT-2's three; the policy config's ``virtual_views``).
    views: tuple[int, ...] = ALL_VIEWS
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
    # a code of the instruction's tokens taken in order (:class:`~sigma_policy.conditioning.LanguageFiLM`).
    # Instructions that differ only in word order ("red on green" / "green on red") get sentence features 0.994
    # apart (cosine) but distinct codes.
    lang_film: bool = False
    lang_film_code_dim: int = 8
    proprio_dim: int = 3
    # The proprio vector also enters the rotation/gripper/collision MLP directly (not only as a fusion token).
    proprio_in_heads: bool = False
    # Proprio FiLM (not in the paper): every image token entering fusion is also scaled and shifted per channel by
    # a linear map of the proprio vector (:class:`~sigma_policy.conditioning.ProprioFiLM`), so the decoder that
    # draws the heatmap reads the gripper state directly, not only through attention to the proprio token; RVT-1
    # concatenates its proprio to every patch for the same reason (docs/method.md §13).
    proprio_film: bool = False
    # Local features for the heads (not in the paper; RVT-2 reads rotation at the predicted location of a zoomed
    # stage): ``local_channels`` > 0 adds a full-resolution dilated CNN on each rendered view
    # (:class:`~sigma_policy.layers.LocalEncoder`), pooled per view by a heatmap (the target's in training, the
    # same Gaussian at the predicted point at inference), so the heads see the object's outline around the keyframe
    # position, e.g. a cube's edges.
    local_channels: int = 0
    local_dilations: tuple[int, ...] = (1, 2, 4, 8)
    # The same local features also enter the translation decoder's last convolutions beside ``d0`` (whose 1x1
    # convolution sees one pixel), so the heatmap can read an outline around each pixel, e.g. which side of a nut
    # its handle is on. Needs ``local_channels`` > 0.
    local_in_decoder: bool = False
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
    # NHWC conv activations (the same values): None = on the CPU only (ConvBlock says why), True/False everywhere.
    channels_last: bool | None = None

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
        # a tuple, hashable (a list from a caller or a parser would not be), with the top view and every axis pair
        object.__setattr__(self, "views", check_views(self.views))
        if self.local_channels < 0 or (self.local_channels and not self.local_dilations):
            raise ValueError("local_channels must be >= 0, with at least one dilation when > 0")
        if self.local_in_decoder and not self.local_channels:
            raise ValueError("local_in_decoder needs local_channels > 0")
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
    def num_views(self) -> int:
        return len(self.views)

    @property
    def tokens_per_side(self) -> int:
        return self.img_size // self.patch_size
