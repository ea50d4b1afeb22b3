"""Several trained policies acting as one (sigma addition, inference only; ``sigma-eval --ensemble``).

Policies of one recipe trained on the same demonstrations with different seeds disagree a lot on this suite's
short budgets (docs/learning.md: one recipe scored 64/200 and 45/200 with training seeds 0 and 1, Door 18/20 against
1/20). A deep ensemble (Lakshminarayanan et al. 2017, https://arxiv.org/abs/1612.01474) averages such members'
predictive distributions. Here every member sees the same rendered views, and per inference pass:

* translation: per view, the members' heatmap probabilities are averaged, and the point is lifted from that mean as
  from one policy's heatmaps (sigma_policy/heatmap.py), so two members that put their mass on one object outvote a
  third that went to another, and a point half-way between two objects is never chosen for its own sake;
* rotation, gripper and collision: every member runs its heads again at that common point (pooled there as
  training pools them at the target, as instruction-contrastive decoding does), and their probabilities are
  averaged.

The members need the same views and boxes (:data:`SHARED_FIELDS`); their networks may differ. Combined with the
test-time yaw ensemble every turned pass is itself a member average, and with instruction-contrastive decoding the
contrast is applied to the member average.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from sigma_policy.configuration_sigma import SigmaConfig

__all__ = ["SHARED_FIELDS", "check_members", "mean_probability_logits"]

# What every member of an ensemble must share: how a scene becomes views and boxes, and how views become actions.
SHARED_FIELDS = (
    "img_size",
    "side_tilt_deg",
    "virtual_views",
    "render_radius_px",
    "scene_bounds",
    "per_task_bounds",
    "instruction_bounds",
    "place_with_mean_at_eval",
    "depth_unit",
    "num_rotation_bins",
    "gt_heatmap_sigma",
    "heatmap_refine_px",
)


def check_members(lead: SigmaConfig, members: list[SigmaConfig], names: list[str]) -> None:
    """ValueError naming the member and the field when a member's config differs from ``lead``'s in one of
    :data:`SHARED_FIELDS` or in its cameras; ``names`` names the members (their checkpoint paths)."""
    for member, name in zip(members, names, strict=True):
        for field in SHARED_FIELDS:
            want, got = getattr(lead, field), getattr(member, field)
            if want != got:
                raise ValueError(
                    f"ensemble member {name}: {field} is {got!r}, the first policy's is {want!r}"
                )
        if lead.camera_names() != member.camera_names():
            raise ValueError(
                f"ensemble member {name}: cameras {member.camera_names()}, the first policy's {lead.camera_names()}"
            )


def mean_probability_logits(logits: list[Tensor], event_dims: int = 1) -> Tensor:
    """Logits whose softmax over the last ``event_dims`` dimensions is the mean of the members' softmaxes: the log
    of the mean probability (float32; ``-inf`` where every member gives 0)."""
    first = logits[0]
    shape = first.shape
    flat = torch.stack([x.float().flatten(-event_dims) for x in logits])  # (M, ..., N)
    log_p = torch.log_softmax(flat, dim=-1)
    return (torch.logsumexp(log_p, dim=0) - math.log(len(logits))).reshape(shape)
