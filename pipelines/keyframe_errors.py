"""How far a predicted 9-D keyframe is from the recorded one, per head, and the summaries ``sigma-diagnose``
reports (``pipelines/diagnostics.py``).

* **translation** error, centimetres (Euclidean distance of the positions);
* **rotation** error, degrees: the geodesic angle, and per extrinsic-xyz Euler axis (roll, pitch, yaw) the wrapped
  difference of the gimbal-fixed angles that the rotation head classifies (``sigma_policy/rotation.py``), and the
  yaw error modulo a half turn (``yaw_half_turn_deg``): a parallel gripper closes across the same axis at yaws 180°
  apart, so a large yaw error with a small half-turn error is the other wrist side of the right grasp;
* **gripper** and **collision** agreement (the two binary heads, thresholded at 0.5).

Summaries: median, mean, 90th percentile and the shares within 1 cm / 2 cm / 10° / 20° (:data:`METRICS`), over a
set of frames, per keyframe step and per label (task or variation).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

METRICS = (
    "trans_cm_median",
    "trans_cm_mean",
    "trans_cm_p90",
    "within_1cm",
    "within_2cm",
    "rot_deg_median",
    "rot_deg_mean",
    "within_10deg",
    "within_20deg",
    "roll_deg_mean",
    "pitch_deg_mean",
    "yaw_deg_mean",
    "yaw_half_turn_deg_mean",
    "gripper_acc",
    "collision_acc",
)


def wrap_deg(x: np.ndarray) -> np.ndarray:
    """Angles in degrees wrapped to [-180, 180)."""
    return (np.asarray(x) + 180.0) % 360.0 - 180.0


def geodesic_deg(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Angle (degrees) of the rotation between unit quaternions ``(N, 4)`` (any order, sign-invariant)."""
    q1 = q1 / np.linalg.norm(q1, axis=-1, keepdims=True)
    q2 = q2 / np.linalg.norm(q2, axis=-1, keepdims=True)
    dot = np.abs(np.sum(q1 * q2, axis=-1)).clip(0.0, 1.0)
    return np.degrees(2 * np.arccos(dot))


def action_errors(pred: np.ndarray, true: np.ndarray) -> dict[str, np.ndarray]:
    """Per-frame errors between predicted and recorded 9-D keyframe actions ``(N, 9)``."""
    import torch

    from sigma_policy.rotation import gimbal_fixed_euler

    pred, true = np.asarray(pred, dtype=np.float64), np.asarray(true, dtype=np.float64)
    euler_p = gimbal_fixed_euler(torch.from_numpy(pred[:, 3:7])).numpy()
    euler_t = gimbal_fixed_euler(torch.from_numpy(true[:, 3:7])).numpy()
    axes = np.abs(wrap_deg(euler_p - euler_t))
    return {
        "trans_cm": 100 * np.linalg.norm(pred[:, :3] - true[:, :3], axis=-1),
        "rot_deg": geodesic_deg(pred[:, 3:7], true[:, 3:7]),
        "roll_deg": axes[:, 0],
        "pitch_deg": axes[:, 1],
        "yaw_deg": axes[:, 2],
        "yaw_half_turn_deg": np.minimum(axes[:, 2], 180.0 - axes[:, 2]),
        "gripper_ok": (pred[:, 7] > 0.5) == (true[:, 7] > 0.5),
        "collision_ok": (pred[:, 8] > 0.5) == (true[:, 8] > 0.5),
    }


def summarise_errors(err: dict[str, np.ndarray]) -> dict[str, float]:
    """Median / mean / p90 / within-threshold shares of :func:`action_errors` (empty input -> NaNs)."""
    t, r = err["trans_cm"], err["rot_deg"]
    if len(t) == 0:
        return dict.fromkeys(METRICS, math.nan) | {"frames": 0}
    return {
        "frames": len(t),
        "trans_cm_median": float(np.median(t)),
        "trans_cm_mean": float(np.mean(t)),
        "trans_cm_p90": float(np.percentile(t, 90)),
        "within_1cm": float(np.mean(t <= 1.0)),
        "within_2cm": float(np.mean(t <= 2.0)),
        "rot_deg_median": float(np.median(r)),
        "rot_deg_mean": float(np.mean(r)),
        "within_10deg": float(np.mean(r <= 10.0)),
        "within_20deg": float(np.mean(r <= 20.0)),
        "roll_deg_mean": float(np.mean(err["roll_deg"])),
        "pitch_deg_mean": float(np.mean(err["pitch_deg"])),
        "yaw_deg_mean": float(np.mean(err["yaw_deg"])),
        "yaw_half_turn_deg_mean": float(np.mean(err["yaw_half_turn_deg"])),
        "gripper_acc": float(np.mean(err["gripper_ok"])),
        "collision_acc": float(np.mean(err["collision_ok"])),
    }


def summaries(err: dict[str, np.ndarray], steps: np.ndarray) -> dict[str, Any]:
    """``{"all": ..., "per_step": {step: ...}}``: :func:`summarise_errors` of every frame and of each keyframe step."""
    per_step = {
        str(int(s)): summarise_errors({k: v[steps == s] for k, v in err.items()}) for s in np.unique(steps)
    }
    return {"all": summarise_errors(err), "per_step": per_step}


def split_summaries(err: dict[str, np.ndarray], steps: np.ndarray, labels: np.ndarray) -> dict[str, Any]:
    """:func:`summaries` of the frames of each label (task or variation): ``{label: {"all", "per_step"}}``."""
    return {
        label: summaries({k: v[labels == label] for k, v in err.items()}, steps[labels == label])
        for label in sorted(set(labels.tolist()))
    }
