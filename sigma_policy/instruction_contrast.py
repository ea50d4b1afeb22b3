"""Instruction-contrastive decoding of the translation heatmaps (sigma addition, inference only, off in every preset;
``instruction_contrast`` in configuration_sigma.py).

A multi-task policy's heatmap for "put the can in its bin" holds two things: the place the words pick, and places
that are likely whatever the words say: PickPlace's tall cereal box and milk carton, which the side views show,
where the bread and the can stay hidden below the bin's rim (docs/learning.md, "the side views cannot see the bread
or the can"). At inference the policy knows every instruction of the instructed task (``instruction_tasks``, recorded
from the training dataset), so it can ask the same scene under each of them and discount what they share. Per view,
before the views are lifted to one 3D point (sigma_policy/heatmap.py):

    score(x) = log p(x | own) - w * log mean_j p(x | j)        j over every instruction of the task, own included

With ``w = 1`` this is the pointwise mutual information of place and instruction (the uniform mixture over the
task's instructions as the marginal), which turns every place that no instruction wants into a tie; ``0 <= w < 1``
keeps ``(1 - w) log p`` of the policy's own belief, so where all instructions agree (lift, carry to the bin) the
argmax is the policy's own, while a place that every instruction points at loses to the place only this one points
at. It is classifier-free guidance's contrast (Ho & Salimans 2022, https://arxiv.org/abs/2207.12598) with the task's
other instructions standing in for the unconditional model. An instruction alone in its task (Lift), or one the
policy was not trained on, is left as it is.

The same alternatives also give training a negative (``instruction_negative_weight``, :func:`swap_negative_loss`):
an episode's first frame, asked under another instruction of its task, should not point where its own
instruction's keyframe is. Stack's two orders, PickPlace's four objects and NutAssembly's two nuts all start from a
scene where only the words choose the object, and the frozen text encoder's features of two such instructions are
nearly identical (docs/learning.md, "Reading the instruction"); the BC loss alone leaves it to the draw whether a
run learns to read them. The negative is unlikelihood training (Welleck et al. 2019,
https://arxiv.org/abs/1908.04319) on the heatmap: ``-log(1 - q)`` with ``q`` the probability mass each view's
heatmap under the other instruction puts in a window around the target, averaged over views.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from torch import Tensor

from sigma_policy.heatmap import gaussian_heatmaps, heads_at_point
from sigma_policy.network import NetworkOutput
from sigma_policy.views import ALL_VIEWS

__all__ = [
    "check_contrast_weight",
    "contrast_instructions",
    "contrasted_logits",
    "instruction_negatives",
    "swap_negative_loss",
    "task_alternatives",
]


def check_contrast_weight(weight: float) -> float:
    """``weight`` when in [0, 1) (0 = off), else ValueError: at 1 every place no instruction wants ties."""
    if not 0.0 <= weight < 1.0:
        raise ValueError(f"instruction_contrast must be in [0, 1) (0 = off), got {weight}")
    return float(weight)


def task_alternatives(instructions: list[str], instruction_tasks: dict[str, str]) -> list[list[str]]:
    """For each instruction, the other instructions of its task in ``instruction_tasks`` (instruction -> task),
    sorted; [] for an instruction that is alone in its task or not in the map."""
    by_task: dict[str, list[str]] = {}
    for instruction, task in sorted(instruction_tasks.items()):
        by_task.setdefault(task, []).append(instruction)
    return [
        [other for other in by_task[instruction_tasks[s]] if other != s] if s in instruction_tasks else []
        for s in instructions
    ]


def contrasted_logits(own: Tensor, others: Tensor, valid: Tensor, weight: float) -> Tensor:
    """The contrasted per-view log-scores ``(B, V, H, W)`` of the module docstring.

    Args:
        own: (B, V, H, W) translation logits under each sample's own instruction.
        others: (K, B, V, H, W) the logits under the task's other instructions (K = the most any sample has).
        valid: (K, B) bool, which of ``others`` are a real instruction of the sample's task (the rest are padding).
        weight: ``w`` in [0, 1).
    """
    if others.shape[1:] != own.shape or valid.shape != others.shape[:2]:
        raise ValueError(
            f"others {tuple(others.shape)} and valid {tuple(valid.shape)} do not match own {tuple(own.shape)}"
        )
    log_own = torch.log_softmax(own.float().flatten(2), dim=-1)  # (B, V, N)
    log_others = torch.log_softmax(others.float().flatten(3), dim=-1)  # (K, B, V, N)
    log_others = log_others.masked_fill(~valid[:, :, None, None], -math.inf)
    count = 1 + valid.sum(0).to(log_own)  # (B,): own and the real others
    log_mean = torch.logsumexp(torch.cat([log_own[None], log_others]), dim=0) - count.log()[:, None, None]
    return (log_own - weight * log_mean).reshape(own.shape)


def swap_negative_loss(swapped_logits: Tensor, window: Tensor) -> Tensor:
    """(B,) unlikelihood of the own target under another instruction (module docstring), averaged over views.

    Args:
        swapped_logits: (B, V, H, W) translation logits of the same views under another instruction of the task.
        window: (B, V, H, W) in [0, 1], 1 at the own keyframe's pixel and falling off around it (0 in a view the
            target is outside of, which then costs nothing).
    """
    if swapped_logits.shape != window.shape:
        raise ValueError(f"logits {tuple(swapped_logits.shape)} and window {tuple(window.shape)} differ")
    p = torch.softmax(swapped_logits.float().flatten(2), dim=-1)
    q = (p * window.flatten(2)).sum(-1).clamp(0.0, 1.0 - 1e-6)  # (B, V)
    return -torch.log1p(-q).mean(-1)


def contrast_instructions(
    run: Callable[..., NetworkOutput],
    out: NetworkOutput,
    tasks: list[str],
    instruction_tasks: dict[str, str],
    weight: float,
    heads_sigma_px: float,
    side_tilt_deg: float = 0.0,
    fusion: str = "sum",
    views: tuple[int, ...] = ALL_VIEWS,
) -> NetworkOutput:
    """``out`` with its translation logits contrasted against the task's other instructions
    (:func:`contrasted_logits`) and its heads run again at the contrasted point, pooled there (a Gaussian of
    ``heads_sigma_px``) as training pools them at the target; ``out`` unchanged when no sample's task has another
    instruction. ``run(instructions, head_heatmap=None, head_uv=None)`` runs the network on the same views."""
    alternatives = task_alternatives(tasks, instruction_tasks)
    others, valid = [], []
    for k in range(max(map(len, alternatives), default=0)):
        # samples with fewer alternatives repeat their own instruction, masked out of the mean
        asked = [alt[k] if k < len(alt) else own for alt, own in zip(alternatives, tasks, strict=True)]
        others.append(run(asked).trans)
        valid.append(torch.tensor([k < len(alt) for alt in alternatives], device=out.trans.device))
    if not others:
        return out
    trans = contrasted_logits(out.trans, torch.stack(others), torch.stack(valid), weight)
    pooled = run(tasks, **heads_at_point(trans, side_tilt_deg, heads_sigma_px, fusion, views))
    pooled.trans = trans
    return pooled


def instruction_negatives(
    run_rows: Callable[[Tensor, list[str]], NetworkOutput],
    tasks: list[str],
    first: list[bool],
    instruction_tasks: dict[str, str],
    target_uv: Tensor,
    window_sigma_px: float,
    generator: torch.Generator,
) -> Tensor:
    """(B,) the unlikelihood (:func:`swap_negative_loss`) of each first frame's own target, at ``target_uv``
    (B, V, 2), under another instruction of its task drawn from ``generator``; 0 for the other samples.
    ``run_rows(rows, instructions)`` runs the network once on those rows of the batch under those instructions."""
    b = len(tasks)
    negative = torch.zeros(b, device=target_uv.device)
    alternatives = task_alternatives(tasks, instruction_tasks)
    rows = [i for i in range(b) if alternatives[i] and first[i]]
    if not rows:
        return negative
    draws = torch.randint(0, 2**31 - 1, (len(rows),), generator=generator).tolist()
    asked = [alternatives[i][d % len(alternatives[i])] for i, d in zip(rows, draws, strict=True)]
    idx = torch.tensor(rows, device=target_uv.device)
    out = run_rows(idx, asked)
    window = gaussian_heatmaps(target_uv[idx], out.trans.shape[-1], sigma=window_sigma_px)
    window = window / window.amax((-2, -1), keepdim=True).clamp_min(1e-12)
    return negative.index_put((idx,), swap_negative_loss(out.trans, window))
