"""FiLM conditioning (not in the paper): a per-channel scale and shift, ``x * (1 + gamma) + beta``, from the
instruction (:class:`LanguageFiLM`) or from the proprio vector (:class:`ProprioFiLM`).

Where :mod:`sigma_policy.network` applies them: ``lang_film`` and ``proprio_film`` to the image tokens entering
fusion (step 5)."""

from __future__ import annotations

from torch import Tensor, nn

from sigma_policy.layers import DenseBlock

__all__ = ["LanguageFiLM", "ProprioFiLM"]


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
        """(B, L, D_tok) language tokens and (B, N, dim) image tokens -> the image tokens scaled and shifted."""
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
