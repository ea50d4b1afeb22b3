"""Episode viewer: one episode of a sigma dataset (dense or keyframe) logged to Rerun in 3D.

What gets logged (entity paths; ``world`` is z-up, metres):

- ``world/cameras/<cam>``: camera-to-world ``Transform3D`` + ``Pinhole`` (K, OpenCV RDF axes) per frame;
  ``.../rgb`` JPEG-compressed colour, ``.../depth`` metric ``DepthImage`` (back-projects in the 3D view).
- ``world/point_cloud``: the fused colour cloud of all cameras (depth back-projected with K and E),
  subsampled to ``point_budget`` points per frame.
- ``world/eef``: the end-effector (grip site) pose per frame; ``world/eef_trajectory``: its whole path.
- ``world/keyframes/kf_<k>``: each keyframe pose as axes, with a label carrying its gripper state.
- ``world/goal``: the goal keyframe pose of the current frame; ``world/goal_link``: arrow eef -> goal.
- ``timeseries/state/<name>``, ``timeseries/action/<name>``, ``timeseries/goal_distance``: scalar plots.
- ``instruction``: a markdown ``TextDocument`` with the instruction and episode facts.

Timelines: ``frame_index`` (sequence), ``time`` (seconds since episode start) and ``keyframe`` (decision
point ordinal: 0 = start frame, k = k-th keyframe; only decision-point frames exist on it, so scrubbing it
steps from keyframe to keyframe).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import rerun as rr
from lerobot.datasets import LeRobotDataset
from tqdm import tqdm

from pipelines.viz.episode_tracks import (
    CameraFeatures,
    EpisodeTracks,
    backproject_depth,
    decision_points,
    discover_cameras,
    goal_poses,
    hwc_uint8,
    keyframe_poses,
    load_episode_tracks,
    subsample_evenly,
)
from sigma_data.contract import STATE, DatasetKind

logger = logging.getLogger(__name__)

AXIS_LENGTH_M = 0.05
OPEN_COLOR = (40, 200, 80)
CLOSED_COLOR = (230, 60, 40)


@dataclass(frozen=True)
class EpisodeLogSummary:
    """What ``log_episode`` logged; printed as the CLI's one-line summary."""

    kind: DatasetKind
    episode_index: int
    num_frames: int
    cameras: tuple[str, ...]
    num_keyframes: int
    max_points_per_frame: int

    def one_line(self) -> str:
        return (
            f"episode {self.episode_index} ({self.kind}): {self.num_frames} frames, "
            f"{len(self.cameras)} cameras [{', '.join(self.cameras)}], {self.num_keyframes} keyframes, "
            f"<= {self.max_points_per_frame} cloud points per frame"
        )


# ----------------------------------------------------------------------------------------------- logging


@dataclass
class EpisodeLogOptions:
    """Knobs of ``log_episode`` (the CLI exposes them)."""

    point_budget: int = 10_000  # fused cloud points per frame, all cameras together
    max_depth_m: float = 3.0  # depth beyond this (background, far plane) is left out of the fused cloud
    jpeg_quality: int = 85  # RGB compression; 0 logs raw images
    log_depth_images: bool = True  # metric DepthImage per camera (back-projects in 3D; raw float32)
    # 16-bit millimetre PNG instead of raw float32 (lossless to 1 mm, several times smaller; Rerun 0.33
    # marks EncodedDepthImage unstable)
    compress_depth: bool = False
    point_radius_m: float = 0.004


def _quat(q_xyzw: np.ndarray) -> rr.Quaternion:
    return rr.Quaternion(xyzw=np.asarray(q_xyzw, dtype=np.float32))


def _gripper_word(gripper_open: float) -> str:
    return "open" if gripper_open >= 0.5 else "closed"


def _gripper_color(gripper_open: float) -> tuple[int, int, int]:
    return OPEN_COLOR if gripper_open >= 0.5 else CLOSED_COLOR


def log_static_episode_context(
    rec: rr.RecordingStream, tracks: EpisodeTracks, kind: DatasetKind, episode_index: int
) -> int:
    """Timeless entities: world axes, trajectory, keyframe axes, instruction and the time series.

    Returns the number of keyframes logged.
    """
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    rec.log(
        "world/eef_trajectory",
        rr.LineStrips3D([tracks.state[:, :3]], colors=[(90, 160, 255)], radii=0.002),
        static=True,
    )
    kf_frames, kf_poses = keyframe_poses(tracks, kind)
    for k, (frame, pose) in enumerate(zip(kf_frames, kf_poses, strict=True), start=1):
        path = f"world/keyframes/kf_{k:02d}"
        rec.log(
            path,
            rr.Transform3D(translation=pose[:3], quaternion=_quat(pose[3:7])),
            rr.TransformAxes3D(AXIS_LENGTH_M),
            static=True,
        )
        rec.log(
            f"{path}/label",
            rr.Points3D(
                [[0.0, 0.0, 0.0]],
                radii=0.008,
                colors=[_gripper_color(pose[7])],
                labels=[f"kf {k} (frame {frame}): {_gripper_word(pose[7])}"],
            ),
            static=True,
        )

    instructions = list(dict.fromkeys(tracks.tasks))
    kf_list = ", ".join(str(int(f)) for f in kf_frames)
    doc = "\n".join(
        [
            "# Instruction",
            *[f"> {t}" for t in instructions],
            "",
            f"- dataset kind: **{kind}**",
            f"- episode: {episode_index}, frames: {len(tracks.frame_index)}",
            f"- keyframes ({len(kf_frames)}) at frames: {kf_list}",
            "- keyframe axes: red x, green y, blue z; label dot green = gripper open, red = closed",
        ]
    )
    rec.log("instruction", rr.TextDocument(doc, media_type=rr.MediaType.MARKDOWN), static=True)

    indexes = [
        rr.TimeColumn("frame_index", sequence=tracks.frame_index),
        rr.TimeColumn("time", duration=tracks.timestamps - tracks.timestamps[0]),
    ]
    for group, values, names in (
        ("state", tracks.state, tracks.state_names),
        ("action", tracks.action, tracks.action_names),
    ):
        for d, name in enumerate(names):
            path = f"timeseries/{group}/{rr.escape_entity_path_part(name)}"
            rec.send_columns(path, indexes=indexes, columns=rr.Scalars.columns(scalars=values[:, d]))
    goal = goal_poses(tracks, kind)
    dist = np.linalg.norm(goal[:, :3] - tracks.state[:, :3], axis=1)
    rec.send_columns("timeseries/goal_distance", indexes=indexes, columns=rr.Scalars.columns(scalars=dist))
    rec.log("timeseries/goal_distance", rr.SeriesLines(names=["eef to goal (m)"]), static=True)
    return len(kf_frames)


def _depth_archetype(depth_m: np.ndarray, compress: bool) -> rr.DepthImage | rr.EncodedDepthImage:
    """Metric depth for Rerun: float32 metres (meter=1), or uint16 millimetres PNG (meter=1000)."""
    turbo = rr.components.Colormap.Turbo
    if not compress:
        return rr.DepthImage(depth_m, meter=1.0, colormap=turbo)
    mm = np.clip(np.nan_to_num(depth_m, nan=0.0, posinf=0.0) * 1000.0, 0, np.iinfo(np.uint16).max)
    return rr.DepthImage(mm.round().astype(np.uint16), meter=1000.0, colormap=turbo).compress()


def _camera_matrices(cam: CameraFeatures, item: dict) -> tuple[np.ndarray, np.ndarray]:
    K = item[cam.intrinsics].numpy() if cam.intrinsics else cam.static_intrinsics
    E = item[cam.extrinsics].numpy() if cam.extrinsics else cam.static_extrinsics
    assert K is not None and E is not None  # guaranteed by discover_cameras
    return np.asarray(K, dtype=np.float64), np.asarray(E, dtype=np.float64)


def log_frame(
    rec: rr.RecordingStream,
    item: dict,
    cameras: list[CameraFeatures],
    goal: np.ndarray,
    options: EpisodeLogOptions,
) -> int:
    """Log one frame's cameras, fused cloud, end-effector, goal and goal link. Returns the cloud size."""
    cloud_xyz, cloud_rgb = [], []
    for cam in cameras:
        K, E = _camera_matrices(cam, item)
        rgb = hwc_uint8(item[cam.rgb])
        h, w = rgb.shape[:2]
        base = f"world/cameras/{cam.name}"
        rec.log(base, rr.Transform3D(translation=E[:3, 3], mat3x3=E[:3, :3]))
        rec.log(
            base,
            rr.Pinhole(
                image_from_camera=K,
                resolution=[w, h],
                camera_xyz=rr.ViewCoordinates.RDF,
                image_plane_distance=0.1,
            ),
        )
        image = rr.Image(rgb)
        rec.log(
            f"{base}/rgb",
            image.compress(jpeg_quality=options.jpeg_quality) if options.jpeg_quality else image,
        )
        if cam.depth is None:
            continue
        depth = item[cam.depth].detach().cpu().numpy().reshape(h, w).astype(np.float32)
        if options.log_depth_images:
            rec.log(f"{base}/depth", _depth_archetype(depth, options.compress_depth))
        xyz, flat = backproject_depth(depth, K, E, options.max_depth_m)
        cloud_xyz.append(xyz)
        cloud_rgb.append(rgb.reshape(-1, 3)[flat])

    n_points = 0
    if cloud_xyz:
        xyz, rgb = np.concatenate(cloud_xyz), np.concatenate(cloud_rgb)
        keep = subsample_evenly(len(xyz), options.point_budget)
        n_points = len(keep)
        rec.log("world/point_cloud", rr.Points3D(xyz[keep], colors=rgb[keep], radii=options.point_radius_m))

    state = item[STATE].numpy()
    rec.log(
        "world/eef",
        rr.Transform3D(translation=state[:3], quaternion=_quat(state[3:7])),
        rr.TransformAxes3D(AXIS_LENGTH_M * 0.6),
    )
    rec.log(
        "world/goal",
        rr.Transform3D(translation=goal[:3], quaternion=_quat(goal[3:7])),
        rr.TransformAxes3D(AXIS_LENGTH_M * 1.4),
    )
    rec.log(
        "world/goal_link",
        rr.Arrows3D(
            origins=[state[:3]],
            vectors=[goal[:3] - state[:3]],
            colors=[_gripper_color(goal[7])],
            radii=0.003,
            labels=[f"goal: gripper {_gripper_word(goal[7])}"],
        ),
    )
    return n_points


def log_episode(
    rec: rr.RecordingStream,
    ds: LeRobotDataset,
    kind: DatasetKind,
    episode_index: int,
    options: EpisodeLogOptions | None = None,
    progress: bool = True,
) -> EpisodeLogSummary:
    """Log one episode (``ds`` must be loaded with ``episodes=[episode_index]`` and ``depth_output_unit="m"``)."""
    options = options or EpisodeLogOptions()
    if ds.depth_output_unit != "m":
        raise ValueError(
            f"{ds.root}: load the dataset with depth_output_unit='m' (got {ds.depth_output_unit!r})"
        )
    cameras = discover_cameras(ds.features)
    tracks = load_episode_tracks(ds, kind)
    n = len(tracks.frame_index)
    if n == 0:
        raise ValueError(f"{ds.root}: episode {episode_index} has no frames")
    num_keyframes = log_static_episode_context(rec, tracks, kind, episode_index)
    goals = goal_poses(tracks, kind)
    ordinal = {int(f): k for k, f in enumerate(decision_points(tracks, kind))}
    t0 = tracks.timestamps[0]

    max_points = 0
    for row in tqdm(range(n), desc=f"episode {episode_index}", disable=not progress):
        item = ds[row]
        i = int(item["frame_index"])  # episode-relative; load_episode_tracks checked it spans 0..n-1
        rec.set_time("frame_index", sequence=i)
        rec.set_time("time", duration=float(item["timestamp"]) - t0)
        if i in ordinal:
            rec.set_time("keyframe", sequence=ordinal[i])
        else:
            rec.disable_timeline("keyframe")
        max_points = max(max_points, log_frame(rec, item, cameras, goals[i], options))
    rec.reset_time()
    return EpisodeLogSummary(
        kind=kind,
        episode_index=episode_index,
        num_frames=n,
        cameras=tuple(c.name for c in cameras),
        num_keyframes=num_keyframes,
        max_points_per_frame=max_points,
    )
