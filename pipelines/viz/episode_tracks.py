"""One episode of a sigma dataset (dense or keyframe) as the episode viewer reads it, without Rerun: its cameras and
their calibration, its numeric columns, its decision points and goal poses, and depth back-projected to world points.

:mod:`pipelines.viz.episode` logs what this module reads.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from lerobot.datasets import LeRobotDataset, LeRobotDatasetMetadata

from sigma_data.contract import (
    ACTION,
    IS_KEYFRAME,
    NEXT_KEYFRAME_INDEX,
    STATE,
    STATIC_EXTRINSICS,
    STATIC_INTRINSICS,
    DatasetKind,
    extrinsics_key,
    intrinsics_key,
    rgb_cameras,
    rgb_key,
)

__all__ = [
    "CameraFeatures",
    "EpisodeTracks",
    "backproject_depth",
    "decision_points",
    "discover_cameras",
    "goal_poses",
    "hwc_uint8",
    "keyframe_poses",
    "load_episode_dataset",
    "load_episode_tracks",
    "subsample_evenly",
]


@dataclass(frozen=True)
class CameraFeatures:
    """Feature keys of one camera, following the sigma data contract."""

    name: str
    rgb: str
    depth: str | None
    intrinsics: str | None  # per-frame (3, 3) feature, if present
    extrinsics: str | None  # per-frame (4, 4) camera-to-world feature, if present
    static_intrinsics: np.ndarray | None  # from the RGB feature's info["sigma.intrinsics"]
    static_extrinsics: np.ndarray | None  # from the RGB feature's info["sigma.extrinsics"]


@dataclass
class EpisodeTracks:
    """Numeric per-frame columns of one episode (episode-relative frame order).

    ``state`` (N, S) and ``action`` (N, A) float32; ``timestamps`` (N,) seconds; ``is_keyframe`` (N,) bool and
    ``next_keyframe`` (N,) episode-relative indices, present for dense datasets only; ``tasks`` (N,) strings.
    """

    frame_index: np.ndarray
    timestamps: np.ndarray
    state: np.ndarray
    action: np.ndarray
    state_names: list[str]
    action_names: list[str]
    tasks: list[str]
    is_keyframe: np.ndarray | None = None
    next_keyframe: np.ndarray | None = None


# ---------------------------------------------------------------------------------------------- discovery


def discover_cameras(features: dict[str, dict]) -> list[CameraFeatures]:
    """Cameras of a dataset: every ``observation.images.<cam>`` RGB feature (not a depth map).

    Raises ``ValueError`` naming the camera when it has neither per-frame nor static calibration.
    """
    cameras = []
    for name in rgb_cameras(features):
        key = rgb_key(name)
        depth = f"{key}_depth" if f"{key}_depth" in features else None
        k_key, e_key = intrinsics_key(name), extrinsics_key(name)
        info = features[key].get("info") or {}
        static_k = info.get(STATIC_INTRINSICS)
        static_e = info.get(STATIC_EXTRINSICS)
        cam = CameraFeatures(
            name=name,
            rgb=key,
            depth=depth,
            intrinsics=k_key if k_key in features else None,
            extrinsics=e_key if e_key in features else None,
            static_intrinsics=None if static_k is None else np.asarray(static_k, dtype=np.float64),
            static_extrinsics=None if static_e is None else np.asarray(static_e, dtype=np.float64),
        )
        if cam.intrinsics is None and cam.static_intrinsics is None:
            raise ValueError(
                f"camera {name!r}: no feature {k_key!r} and no info['sigma.intrinsics'] on {key!r}"
            )
        if cam.extrinsics is None and cam.static_extrinsics is None:
            raise ValueError(
                f"camera {name!r}: no feature {e_key!r} and no info['sigma.extrinsics'] on {key!r}"
            )
        cameras.append(cam)
    if not cameras:
        raise ValueError("dataset has no RGB camera feature 'observation.images.<cam>'")
    return cameras


def _names(features: dict[str, dict], key: str) -> list[str]:
    feat = features[key]
    dim = int(feat["shape"][-1])
    names = feat.get("names")
    if isinstance(names, list) and len(names) == dim:
        return [str(n) for n in names]
    return [f"{key}_{i}" for i in range(dim)]


def load_episode_tracks(ds: LeRobotDataset, kind: DatasetKind) -> EpisodeTracks:
    """Read the numeric columns of the (single-episode) dataset without decoding any image."""
    for key in (STATE, ACTION):
        if key not in ds.features:
            raise ValueError(f"{ds.root}: missing feature {key!r} (required by the sigma data contract)")
    cols = ["frame_index", "timestamp", STATE, ACTION]
    if kind == "dense":
        for key in (IS_KEYFRAME, NEXT_KEYFRAME_INDEX):
            if key not in ds.features:
                raise ValueError(f"{ds.root}: dense dataset lacks the keyframe column {key!r}")
        cols += [IS_KEYFRAME, NEXT_KEYFRAME_INDEX]
    table = ds.hf_dataset.with_format(None).select_columns([*cols, "task_index"])[:]
    order = np.argsort(np.asarray(table["frame_index"]))
    tasks_df = ds.meta.tasks
    index_to_task = {int(i): str(t) for t, i in zip(tasks_df.index, tasks_df["task_index"], strict=True)}

    def col(name: str, dtype: type) -> np.ndarray:
        return np.asarray(table[name], dtype=dtype)[order]

    tracks = EpisodeTracks(
        frame_index=col("frame_index", np.int64),
        timestamps=col("timestamp", np.float64),
        state=col(STATE, np.float32),
        action=col(ACTION, np.float32),
        state_names=_names(ds.features, STATE),
        action_names=_names(ds.features, ACTION),
        tasks=[index_to_task[int(table["task_index"][i])] for i in order],
    )
    if not np.array_equal(tracks.frame_index, np.arange(len(order))):
        raise ValueError(f"{ds.root}: frame_index of the episode is not 0..{len(order) - 1}")
    if kind == "dense":
        tracks.is_keyframe = col(IS_KEYFRAME, bool).reshape(-1)
        tracks.next_keyframe = col(NEXT_KEYFRAME_INDEX, np.int64).reshape(-1)
        n = len(tracks.frame_index)
        bad = (tracks.next_keyframe < 0) | (tracks.next_keyframe >= n)
        if bad.any():
            raise ValueError(
                f"{ds.root}: {NEXT_KEYFRAME_INDEX} out of the episode range [0, {n}) at frames "
                f"{np.flatnonzero(bad)[:5].tolist()}"
            )
    if tracks.state.shape[1] < 8:
        raise ValueError(f"{ds.root}: {STATE} has {tracks.state.shape[1]} dims, need >= 8 (pose + gripper)")
    return tracks


# ----------------------------------------------------------------------------------------------- keyframes


def decision_points(tracks: EpisodeTracks, kind: DatasetKind) -> np.ndarray:
    """Episode-relative frames on the ``keyframe`` timeline: the start frame, then every keyframe in order."""
    n = len(tracks.frame_index)
    if kind == "keyframe":
        return np.arange(n)
    assert tracks.is_keyframe is not None
    return np.union1d([0], np.flatnonzero(tracks.is_keyframe))


def goal_poses(tracks: EpisodeTracks, kind: DatasetKind) -> np.ndarray:
    """Per-frame goal keyframe pose (N, 8): xyz, quaternion xyzw, gripper_open.

    Dense: the state at ``sigma.next_keyframe_index``. Keyframe: the frame's own 9-D action, which is the
    pose of frame i+1 (the last frame repeats its own pose).
    """
    if kind == "keyframe":
        return tracks.action[:, :8].copy()
    assert tracks.next_keyframe is not None
    return tracks.state[tracks.next_keyframe, :8].copy()


def keyframe_poses(tracks: EpisodeTracks, kind: DatasetKind) -> tuple[np.ndarray, np.ndarray]:
    """Keyframes (decision points after the start): (episode-relative frames (K,), poses (K, 8))."""
    frames = decision_points(tracks, kind)[1:]
    return frames, tracks.state[frames, :8].copy()


# ---------------------------------------------------------------------------------------------- geometry


def backproject_depth(
    depth_m: np.ndarray, K: np.ndarray, cam_to_world: np.ndarray, max_depth_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """World points of every valid pixel of a z-depth map.

    Args:
        depth_m: (H, W) z-depth along the optical axis, metres. Valid where 0 < depth < ``max_depth_m``.
        K: (3, 3) intrinsics, pixel centres at +0.5 (pixel (row v, col u) sits at (u + 0.5, v + 0.5)).
        cam_to_world: (4, 4) camera-to-world, OpenCV axes (x right, y down, z forward).
        max_depth_m: far cut-off; removes background and far-plane pixels.

    Returns:
        (xyz (N, 3) float32 world points, flat pixel indices (N,) into the (H, W) image, row-major).
    """
    h, w = depth_m.shape
    v, u = np.mgrid[0:h, 0:w]
    z = depth_m.astype(np.float64)
    valid = np.isfinite(z) & (z > 0) & (z < max_depth_m)
    flat = np.flatnonzero(valid)
    zs = z.reshape(-1)[flat]
    pix = np.stack([u.reshape(-1)[flat] + 0.5, v.reshape(-1)[flat] + 0.5, np.ones_like(zs)], axis=0)
    cam = (np.linalg.inv(K.astype(np.float64)) @ pix) * zs  # (3, N) camera frame
    world = cam_to_world[:3, :3].astype(np.float64) @ cam + cam_to_world[:3, 3:4].astype(np.float64)
    return world.T.astype(np.float32), flat


def subsample_evenly(n: int, budget: int) -> np.ndarray:
    """Indices of at most ``budget`` of ``n`` items, evenly spread (deterministic: no flicker across frames)."""
    if n <= budget:
        return np.arange(n)
    return np.linspace(0, n - 1, budget).round().astype(np.int64)


def hwc_uint8(img: torch.Tensor) -> np.ndarray:
    """LeRobot (3, H, W) float in [0, 1] (or uint8) -> (H, W, 3) uint8 (numpy: no torch thread start-up)."""
    arr = img.detach().cpu().numpy().transpose(1, 2, 0)
    if arr.dtype == np.uint8:
        return np.ascontiguousarray(arr)
    return (np.clip(arr, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def load_episode_dataset(root: Path, episode_index: int, repo_id: str | None = None) -> LeRobotDataset:
    """Stock ``LeRobotDataset`` for one local episode, depth in metres (no network)."""
    root = Path(root)
    if not (root / "meta" / "info.json").exists():
        raise FileNotFoundError(f"{root}: not a LeRobot dataset (no meta/info.json)")
    total = LeRobotDatasetMetadata(repo_id or f"local/{root.name}", root=root).total_episodes
    if not 0 <= episode_index < total:
        raise ValueError(f"{root}: episode index {episode_index} out of range (dataset has {total} episodes)")
    ds = LeRobotDataset(
        repo_id or f"local/{root.name}",
        root=root,
        episodes=[episode_index],
        depth_output_unit="m",
        video_backend="pyav",  # torchcodec cannot load without system FFmpeg; skip its noisy probe
    )
    if ds.num_frames == 0:
        raise ValueError(f"{root}: episode {episode_index} not found or empty")
    return ds
