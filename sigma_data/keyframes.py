"""Keyframe discovery for demonstrations without an expert, and keyframe bookkeeping.

:func:`discover_keyframes` is the PerAct/ARM "keypoint discovery" heuristic (docs/robosuite.md §7.1),
re-implemented: frame ``i > 0`` is a keyframe if the gripper state changes there, if it is the last frame, or
if the arm has *stopped* (every arm joint slower than ``velocity_threshold``, the gripper state unchanged around
``i``, and no other stopped keyframe in the previous ``stopped_buffer`` frames). Its only dedup: when the last
two keyframes are consecutive frames, the second-last is dropped. With robosuite/robomimic demos take the
gripper state from the commands (:func:`sigma_data.episode.gripper_open_from_actions`): a finger-width threshold
is ambiguous while holding objects. :func:`dedup_by_pose` is the optional extra filter of docs/robosuite.md §7.2.

:func:`next_keyframe_index` gives each frame the episode-relative index of the next keyframe strictly after it
(the last frame points to itself); :func:`compare_keyframes` scores heuristic against expert keyframes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation


def discover_keyframes(
    joint_velocities: np.ndarray,
    gripper_open: np.ndarray,
    velocity_threshold: float = 0.1,
    stopped_buffer: int = 4,
) -> list[int]:
    """Keyframe frame indices (sorted) of one episode by the ARM/PerAct heuristic.

    Args:
        joint_velocities: (T, n_arm) arm joint velocities, rad/s.
        gripper_open: (T,) gripper-open flags (0/1 or bool) per frame.
        velocity_threshold: "stopped" means ``|qdot| <= velocity_threshold`` for every arm joint (rad/s).
        stopped_buffer: after a stopped keyframe, the next ``stopped_buffer`` frames cannot be stopped ones.
    """
    qd = np.asarray(joint_velocities, dtype=np.float64)
    g = np.asarray(gripper_open).astype(bool)
    n = len(g)
    if qd.ndim != 2 or len(qd) != n:
        raise ValueError(f"joint_velocities must be (T, n_arm) with T = {n}, got {qd.shape}")
    if n == 0:
        return []
    keyframes: list[int] = []
    buffer = 0
    for i in range(n):
        # The reference code reads open[i-1], open[i-2] with Python's wrap-around for i < 2, and the
        # next-frame check makes the second-last frame never "stopped".
        next_is_final = i == n - 2
        gripper_steady = i < n - 2 and g[i] == g[i + 1] == g[i - 1] and g[i - 2] == g[i - 1]
        small = bool(np.all(np.abs(qd[i]) <= velocity_threshold))
        stopped = buffer <= 0 and small and not next_is_final and gripper_steady
        buffer = stopped_buffer if stopped else buffer - 1
        last = i == n - 1
        if i != 0 and (g[i] != g[i - 1] or last or stopped):
            keyframes.append(i)
    if len(keyframes) > 1 and keyframes[-1] - 1 == keyframes[-2]:
        keyframes.pop(-2)
    return keyframes


def dedup_by_pose(
    keyframes: Sequence[int],
    poses: np.ndarray,
    gripper_open: np.ndarray,
    position_tolerance: float = 0.01,
    rotation_tolerance_deg: float = 5.0,
) -> list[int]:
    """Drop keyframe k when the next kept candidate has the same gripper state and a pose within tolerance.

    Args:
        keyframes: sorted frame indices; the last one is always kept.
        poses: (T, 7) ``[x, y, z, qx, qy, qz, qw]`` per frame, metres.
        gripper_open: (T,) flags per frame.
        position_tolerance: metres; rotation_tolerance_deg: degrees (geodesic).
    """
    kfs = list(keyframes)
    if not kfs:
        return []
    poses = np.asarray(poses, dtype=np.float64)
    g = np.asarray(gripper_open).astype(bool)
    kept = [kfs[-1]]
    for k in reversed(kfs[:-1]):
        nxt = kept[-1]
        close = np.linalg.norm(poses[k, :3] - poses[nxt, :3]) < position_tolerance
        angle = np.degrees(
            (Rotation.from_quat(poses[k, 3:7]).inv() * Rotation.from_quat(poses[nxt, 3:7])).magnitude()
        )
        if not (g[k] == g[nxt] and close and angle < rotation_tolerance_deg):
            kept.append(k)
    return sorted(kept)


def next_keyframe_index(keyframes: Sequence[int], length: int) -> np.ndarray:
    """(length,) int64: for each frame the first keyframe strictly after it; the last frame maps to itself.

    ``keyframes`` must be sorted, unique, inside the episode and include the last frame ``length - 1``.
    """
    kfs = np.asarray(sorted(set(keyframes)), dtype=np.int64)
    if len(kfs) == 0 or kfs[-1] != length - 1 or kfs[0] < 0:
        raise ValueError(
            f"keyframes {list(keyframes)} must lie in [0, {length - 1}] and include the last frame"
        )
    frames = np.arange(length)
    out = kfs[np.searchsorted(kfs, frames, side="right").clip(max=len(kfs) - 1)]
    out[-1] = length - 1
    return out


def keyframe_mask(keyframes: Sequence[int], length: int) -> np.ndarray:
    """(length,) bool, True at keyframes."""
    mask = np.zeros(length, dtype=bool)
    mask[list(keyframes)] = True
    return mask


@dataclass(frozen=True)
class KeyframeMatch:
    """How one keyframe set (``found``) covers a reference set (``reference``) within ``tolerance`` frames."""

    reference: int  # number of reference keyframes
    found: int  # number of found keyframes
    matched: int  # reference keyframes with a found keyframe within tolerance
    precision: float  # fraction of found keyframes within tolerance of a reference keyframe
    recall: float  # matched / reference
    mean_offset: float  # mean |frame offset| of the matched reference keyframes


def compare_keyframes(reference: Sequence[int], found: Sequence[int], tolerance: int = 3) -> KeyframeMatch:
    """Match found keyframes to reference ones (e.g. heuristic vs expert) within ``tolerance`` frames."""
    ref = np.asarray(reference, dtype=np.int64)
    fnd = np.asarray(found, dtype=np.int64)
    if len(ref) == 0 or len(fnd) == 0:
        return KeyframeMatch(len(ref), len(fnd), 0, 0.0, 0.0, float("nan"))
    dist = np.abs(ref[:, None] - fnd[None, :])
    ref_best = dist.min(axis=1)
    matched = ref_best <= tolerance
    precision = float((dist.min(axis=0) <= tolerance).mean())
    return KeyframeMatch(
        reference=len(ref),
        found=len(fnd),
        matched=int(matched.sum()),
        precision=precision,
        recall=float(matched.mean()),
        mean_offset=float(ref_best[matched].mean()) if matched.any() else float("nan"),
    )
