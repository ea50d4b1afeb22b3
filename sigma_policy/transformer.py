"""The multi-view transformer's layers (:mod:`sigma_policy.network`, steps 4-5): multi-head attention through
``F.scaled_dot_product_attention``, a GEGLU feed-forward and the pre-LayerNorm layer that joins them, for self- and
cross-attention."""

from __future__ import annotations

import torch.nn.functional as F
from torch import Tensor, nn

__all__ = ["Attention", "GEGLUFeedForward", "TransformerLayer"]


class Attention(nn.Module):
    """Multi-head attention via SDPA: q (no bias), kv (no bias), out (bias); dropout on attention weights."""

    def __init__(self, dim: int, heads: int, dim_head: int, dropout: float):
        super().__init__()
        inner = heads * dim_head
        self.heads, self.dropout = heads, dropout
        self.to_q = nn.Linear(dim, inner, bias=False)
        self.to_kv = nn.Linear(dim, 2 * inner, bias=False)
        self.to_out = nn.Linear(inner, dim)

    def forward(self, x: Tensor, context: Tensor | None = None) -> Tensor:
        context = x if context is None else context
        q = self.to_q(x)
        k, v = self.to_kv(context).chunk(2, dim=-1)
        b, n, _ = q.shape
        q, k, v = (t.reshape(b, t.shape[1], self.heads, -1).transpose(1, 2) for t in (q, k, v))
        out = F.scaled_dot_product_attention(q, k, v, dropout_p=self.dropout if self.training else 0.0)
        return self.to_out(out.transpose(1, 2).reshape(b, n, -1))


class GEGLUFeedForward(nn.Module):
    """Linear dim -> 8 dim, split into (a, b), a * GELU(b), Linear 4 dim -> dim."""

    def __init__(self, dim: int, mult: int = 4):
        super().__init__()
        self.proj_in = nn.Linear(dim, dim * mult * 2)
        self.proj_out = nn.Linear(dim * mult, dim)

    def forward(self, x: Tensor) -> Tensor:
        a, gate = self.proj_in(x).chunk(2, dim=-1)
        return self.proj_out(a * F.gelu(gate))


class TransformerLayer(nn.Module):
    """Pre-LN layer: ``x + Attn(LN(x)[, LN(ctx)])`` then ``x + FF(LN(x))``; ``cross`` adds a context LayerNorm."""

    def __init__(self, dim: int, heads: int, dim_head: int, dropout: float, cross: bool = False):
        super().__init__()
        self.norm_attn = nn.LayerNorm(dim)
        self.norm_context = nn.LayerNorm(dim) if cross else None
        self.attn = Attention(dim, heads, dim_head, dropout)
        self.norm_ff = nn.LayerNorm(dim)
        self.ff = GEGLUFeedForward(dim)

    def forward(self, x: Tensor, context: Tensor | None = None) -> Tensor:
        if self.norm_context is not None:
            if context is None:
                raise ValueError("a cross-attention layer needs a context")
            context = self.norm_context(context)
        x = x + self.attn(self.norm_attn(x), context)
        return x + self.ff(self.norm_ff(x))
