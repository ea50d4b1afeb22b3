"""Bilinear upsampling with a replicate border as two matrix products: the decoder's x ``patch_size`` upsample
(:mod:`sigma_policy.network`, step 6), whose backward avoids PyTorch's atomic scatter kernels (docs/gpu.md)."""

from __future__ import annotations

import torch
from torch import Tensor, nn

__all__ = ["BilinearUpsample", "bilinear_upsample_matrix"]


def bilinear_upsample_matrix(size_in: int, scale: int, pad: int = 0) -> Tensor:
    """``(size_in * scale + 2 pad, size_in)`` float64 matrix ``A`` with ``A @ x`` = bilinear upsampling of ``x``
    along one axis by ``scale`` (``align_corners=False``, PyTorch's sampling), then replicate padding by ``pad``.

    Output index ``i`` samples source ``max((i + 1/2) / scale - 1/2, 0)``, blended between its floor and the next
    pixel (clamped to the last). The replicate border comes out of the same rule: for scale >= 1 the outermost
    upsampled pixels already equal the outermost source pixels, and so do the border indices ``-pad .. -1`` and
    ``size_in * scale .. + pad - 1``.
    """
    if size_in < 1 or scale < 1 or pad < 0:
        raise ValueError(f"need size_in >= 1, scale >= 1, pad >= 0; got {size_in}, {scale}, {pad}")
    dst = torch.arange(-pad, size_in * scale + pad, dtype=torch.float64)
    src = ((dst + 0.5) / scale - 0.5).clamp_min(0)
    lo = src.floor().long().clamp_max(size_in - 1)
    hi = (lo + 1).clamp_max(size_in - 1)
    w_hi = (src - lo).clamp(0, 1)
    a = torch.zeros(len(dst), size_in, dtype=torch.float64)
    rows = torch.arange(len(dst))
    a.index_put_((rows, lo), 1 - w_hi, accumulate=True)
    a.index_put_((rows, hi), w_hi, accumulate=True)
    return a


class BilinearUpsample(nn.Module):
    """Bilinear x ``scale`` (``align_corners=False``) followed by replicate padding by ``pad``, as two small
    matrix products ``A x A^T``. Same values as ``F.pad(F.interpolate(x, scale_factor=scale, mode="bilinear"),
    (pad,) * 4, mode="replicate")``, but its backward is two matrix products too: PyTorch's upsample and
    replicate-pad backward kernels scatter with atomics and took a quarter of the paper network's GPU step."""

    def __init__(self, size_in: int, scale: int, pad: int = 0):
        super().__init__()
        self.register_buffer("matrix", bilinear_upsample_matrix(size_in, scale, pad), persistent=False)

    def forward(self, x: Tensor) -> Tensor:
        a = self.matrix.to(x.dtype)  # under autocast, matmul casts both to the autocast dtype anyway
        return torch.matmul(torch.matmul(a, x), a.t())
