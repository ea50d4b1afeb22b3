"""FiLM conditioning (not in the paper): a per-channel scale and shift, ``x * (1 + gamma) + beta``, from the
instruction (:class:`LanguageFiLM`) or from the proprio vector (:class:`ProprioFiLM`).

Where :mod:`sigma_policy.network` applies them: ``lang_film`` and ``proprio_film`` to the image tokens entering
fusion (step 5); ``decoder_lang_film`` to the translation decoder's full-resolution inputs (step 6), the upsampled
tokens beside the per-pixel features ``d0`` and the local features, so a word can select a colour pixel by pixel
(CLIPort's language-times-decoder fusion, Shridhar et al. 2021, arXiv 2109.12098)."""

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
        gamma, beta = self.coefficients(lang_tokens).unsqueeze(1).chunk(2, dim=-1)
        return img * (1 + gamma) + beta

    def coefficients(self, lang_tokens: Tensor) -> Tensor:
        """(B, L, D_tok) -> (B, 2 dim): gamma then beta, for callers whose features are not (B, N, dim) tokens."""
        if lang_tokens.shape[1] != self.length:
            raise ValueError(
                f"LanguageFiLM expects {self.length} language tokens, got {lang_tokens.shape[1]}"
            )
        return self.out(self.token_proj(lang_tokens).flatten(1))

    def modulate_maps(self, lang_tokens: Tensor, maps: Tensor) -> Tensor:
        """Feature maps (B*V, dim, H, W), V views per instruction -> the same, scaled and shifted per channel."""
        coeff = self.coefficients(lang_tokens).to(maps.dtype)
        v = maps.shape[0] // coeff.shape[0]
        gamma, beta = coeff.repeat_interleave(v, dim=0)[:, :, None, None].chunk(2, dim=1)
        return maps * (1 + gamma) + beta


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
