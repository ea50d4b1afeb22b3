"""Contrastive imitation learning (docs/method.md §8): two symmetric InfoNCE terms with a learnable temperature.

* state ↔ language:        ``L_sl   = ½ [CE(s · v̂ l̂_allᵀ) + CE(s · l̂ v̂_allᵀ)]``
* (state, language) ↔ goal: ``L_goal = ½ [CE(s · q̂ ĝ_allᵀ) + CE(s · ĝ q̂_allᵀ)]``

v̂ = phi(s_t), l̂ = psi(l), q̂ = delta(s_t, l), ĝ = phi(g), all L2-normalised; s = exp(learnable log-scale) = 1/τ.
Negatives are the other rows of the batch gathered from every process (``torch.distributed``, e.g. under
``accelerate launch``). Gathered rows of other processes are constants; this process's own rows inside the
gathered tensor are the local (differentiable) tensors, so gradients flow only through local rows and one
process gives exactly the single-process loss. Per-process batch sizes may differ (e.g. a short last batch).

Optionally, negatives that share the positive's instruction are masked out (paper: "negatives from other
tasks"); in the state ↔ language term such negatives have the very same language feature as the positive.

Optionally (``center``, a sigma option, not in the paper), the goal term's features q and g have their mean over
the gathered batch subtracted before the L2 normalisation. Scenes of one table share most of their content, so at
initialisation every delta(s_t, l) and phi(g) of a batch points the same way (cosine similarity about 0.999 on the
tiny test scenes) and every logit is about the same. Centring removes the shared direction, so the logits compare
what differs between samples from the first step. The state ↔ language term is left as it is: a batch holds a few
instructions in a changing mix, and a language feature minus the batch mean would be a different target in every
batch (measured: docs/learning.md "Centred contrastive features").
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from dataclasses import dataclass

import torch
import torch.distributed as dist
import torch.nn.functional as F
from torch import Tensor


def instruction_ids(instructions: Sequence[str], device: torch.device | str = "cpu") -> Tensor:
    """Stable int64 id per instruction string (CRC-32 of its UTF-8 bytes), identical on every process."""
    return torch.tensor(
        [zlib.crc32(s.encode("utf-8")) for s in instructions], dtype=torch.int64, device=device
    )


def _world() -> tuple[int, int]:
    if dist.is_available() and dist.is_initialized():
        return dist.get_rank(), dist.get_world_size()
    return 0, 1


def gather_with_local_grad(x: Tensor) -> tuple[Tensor, int]:
    """All-gather ``x`` (B_local, ...) along dim 0 from every process.

    Returns ``(x_all, offset)``: the concatenation in rank order, in which this process's rows (starting at
    ``offset``) are ``x`` itself (they carry gradients) and the other rows are detached copies. Without an
    initialised process group it returns ``(x, 0)``.
    """
    rank, world = _world()
    if world == 1:
        return x, 0
    size = torch.tensor([x.shape[0]], device=x.device, dtype=torch.int64)
    sizes = [torch.zeros_like(size) for _ in range(world)]
    dist.all_gather(sizes, size)
    counts = [int(s.item()) for s in sizes]
    padded = torch.zeros((max(counts), *x.shape[1:]), dtype=x.dtype, device=x.device)
    padded[: x.shape[0]] = x.detach()
    chunks = [torch.empty_like(padded) for _ in range(world)]
    dist.all_gather(chunks, padded)
    parts = [x if r == rank else chunks[r][: counts[r]] for r in range(world)]
    return torch.cat(parts, dim=0), sum(counts[:rank])


def info_nce(
    query: Tensor,
    keys_all: Tensor,
    offset: int,
    logit_scale: Tensor,
    negative_mask: Tensor | None = None,
) -> Tensor:
    """Mean cross-entropy of ``scale · query keys_allᵀ`` with positives at ``offset + arange(B)``.

    ``negative_mask`` (B, N) bool marks columns to drop (never the positive).
    """
    logits = logit_scale * query @ keys_all.t()
    labels = torch.arange(query.shape[0], device=query.device) + offset
    if negative_mask is not None:
        negative_mask = negative_mask.clone()
        negative_mask[torch.arange(query.shape[0], device=query.device), labels] = False
        logits = logits.masked_fill(negative_mask, float("-inf"))
    if logits.dtype in (torch.float16, torch.bfloat16):
        logits = logits.float()
    return F.cross_entropy(logits, labels)


def centred(x: Tensor) -> Tensor:
    """``x`` (B_local, D) minus the mean of the batch gathered from every process (the same mean on each one)."""
    x_all, _ = gather_with_local_grad(x)
    return x - x_all.mean(dim=0, keepdim=True)


def symmetric_info_nce(a: Tensor, b: Tensor, logit_scale: Tensor, group_ids: Tensor | None = None) -> Tensor:
    """½ [InfoNCE(a -> b_all) + InfoNCE(b -> a_all)] for L2-normalised a, b (B_local, D).

    ``group_ids`` (B_local,) int64: negatives with the same id as the query row are masked out.
    """
    a_all, offset = gather_with_local_grad(a)
    b_all, _ = gather_with_local_grad(b)
    mask = None
    if group_ids is not None:
        ids_all, _ = gather_with_local_grad(group_ids)
        mask = group_ids[:, None] == ids_all[None, :]
    return 0.5 * (
        info_nce(a, b_all, offset, logit_scale, mask) + info_nce(b, a_all, offset, logit_scale, mask)
    )


@dataclass
class ContrastiveLosses:
    state_language: Tensor
    goal: Tensor

    @property
    def total(self) -> Tensor:
        return self.state_language + self.goal


def contrastive_losses(
    state_feat: Tensor,
    lang_feat: Tensor,
    fused_feat: Tensor,
    goal_feat: Tensor,
    logit_scale: Tensor,
    instruction_group: Tensor | None = None,
    logit_scale_max: float | None = None,
    center: bool = False,
) -> ContrastiveLosses:
    """Σ-agent's two InfoNCE terms from raw (unnormalised) features (B, D) and ``logit_scale`` = exp(param).

    ``instruction_group`` (B,) int64 (see :func:`instruction_ids`) masks same-instruction negatives in the
    state ↔ language term; ``logit_scale_max`` clamps the scale (CLIP uses 100; Σ does not clamp); ``center``
    subtracts the batch mean of ``fused_feat`` and ``goal_feat`` before normalising (see the module docstring).
    """
    if logit_scale_max is not None:
        logit_scale = logit_scale.clamp(max=logit_scale_max)
    state, lang, fused, goal = (
        x if x.dtype == torch.float64 else x.float() for x in (state_feat, lang_feat, fused_feat, goal_feat)
    )
    if center:
        fused, goal = centred(fused), centred(goal)
    state, lang, fused, goal = (F.normalize(x, dim=-1) for x in (state, lang, fused, goal))
    return ContrastiveLosses(
        state_language=symmetric_info_nce(state, lang, logit_scale, instruction_group),
        goal=symmetric_info_nce(fused, goal, logit_scale),
    )
