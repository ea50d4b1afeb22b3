"""The behaviour-cloning loss of one keyframe prediction (docs/method.md §6.1), per sample.

* translation: the soft-target cross-entropy of each virtual view's heatmap logits against the Gaussian target at
  the projected keyframe position (``sigma_policy/heatmap.py``), averaged over views;
* rotation: a cross-entropy per Euler axis over the ``num_rotation_bins`` bins of the keyframe's gimbal-fixed
  angles (``sigma_policy/rotation.py``), summed over the three axes;
* gripper and collision: a two-class cross-entropy each, against the action's 0/1 flags.

BC is their sum; ``SigmaPolicy.forward`` weights it per frame and mixes it with the contrastive terms
(``sigma_policy/contrastive.py``). Every term is computed in float32 whatever the network's autocast dtype.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from sigma_policy.rotation import quat_to_bins


@dataclass
class BCLosses:
    """Per-sample terms, each (B,); ``total`` is their sum."""

    translation: Tensor
    rotation: Tensor
    gripper: Tensor
    collision: Tensor

    @property
    def total(self) -> Tensor:
        return self.translation + self.rotation + self.gripper + self.collision

    def info(self) -> dict[str, float]:
        """Batch means under the names ``lerobot-train`` logs."""
        return {
            "trans_loss": self.translation.mean().item(),
            "rot_loss": self.rotation.mean().item(),
            "grip_loss": self.gripper.mean().item(),
            "collision_loss": self.collision.mean().item(),
            "bc_loss": self.total.mean().item(),
        }


def bc_losses(
    trans_logits: Tensor,
    target_heatmaps: Tensor,
    rot_logits: Tensor,
    grip_logits: Tensor,
    collision_logits: Tensor,
    action: Tensor,
    quat: Tensor,
) -> BCLosses:
    """BC terms of a batch.

    Args:
        trans_logits: (B, V, H, W) heatmap logits; target_heatmaps: (B, V, H, W), each view summing to 1 (or 0 where
            the target is outside the view).
        rot_logits: (B, 3, num_bins) Euler-bin logits (roll, pitch, yaw); grip_logits, collision_logits: (B, 2).
        action: (B, 9) recorded keyframe (its flags at 7 and 8); quat: (B, 4) xyzw target orientation (the action's,
            turned by the augmentation).
    """
    log_p = torch.log_softmax(trans_logits.float().flatten(2), dim=-1)
    translation = -(target_heatmaps.flatten(2) * log_p).sum(-1).mean(-1)
    rot_bins = quat_to_bins(quat, rot_logits.shape[-1])  # (B, 3)
    rotation = F.cross_entropy(rot_logits.float().transpose(1, 2), rot_bins, reduction="none").sum(-1)
    gripper = F.cross_entropy(grip_logits.float(), action[:, 7].round().long(), reduction="none")
    collision = F.cross_entropy(collision_logits.float(), action[:, 8].round().long(), reduction="none")
    return BCLosses(translation, rotation, gripper, collision)
