"""Tiny sigma datasets written with the real LeRobot writer, for the Rerun viewer tests.

The scene is analytic so that geometry can be asserted: a table plane at ``TABLE_Z`` and an axis-aligned
cube (centre ``CUBE_CENTER``, half-size ``CUBE_HALF``), rendered by ray casting into two cameras:

- ``agentview``: static, looks at the cube from the front and above (its K/E also sit in the feature ``info``);
- ``robot0_eye_in_hand``: follows the end-effector, looking straight down (per-frame extrinsics change).

Camera conventions follow the data contract: K with pixel centres at +0.5, extrinsics camera-to-world in
OpenCV axes (x right, y down, z forward), depth = z-depth along the optical axis in metres.
Images are deliberately non-square (``H x W = 24 x 32``) to catch transposed axes.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from lerobot.datasets import LeRobotDataset

from sigma_data.episode import DENSE_ACTION_NAMES, KEYFRAME_ACTION_NAMES, STATE_NAMES

H, W = 24, 32
FPS = 20
TABLE_Z = 0.8
CUBE_CENTER = np.array([0.0, 0.0, 0.825])
CUBE_HALF = 0.025
MISS_DEPTH_M = 10.0  # depth written where a ray hits nothing (like a far plane)
CAMERAS = ("agentview", "robot0_eye_in_hand")
TASK = "pick up the red cube"
# Dense episodes: 12 frames, keyframes at these frames (the last frame is a keyframe, as in RVT).
DENSE_LENGTH = 12
DENSE_KEYFRAMES = (3, 6, 8, 11)
TABLE_RGB = np.array([150, 110, 70], dtype=np.uint8)
CUBE_RGB = np.array([220, 30, 30], dtype=np.uint8)


@dataclass(frozen=True)
class FixtureDataset:
    """What a fixture wrote: its root, kind and the numbers the tests assert against."""

    root: Path
    kind: str  # "dense" | "keyframe"
    episode_lengths: tuple[int, ...]
    keyframes_per_episode: int  # decision points excluding the start frame


def intrinsics(fovy_deg: float = 60.0) -> np.ndarray:
    """robosuite-style K: f = 0.5 H / tan(fovy / 2), principal point (W/2, H/2); (3, 3) float32."""
    f = 0.5 * H / np.tan(np.deg2rad(fovy_deg) / 2)
    return np.array([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1]], dtype=np.float32)


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Camera-to-world (4, 4) float32 in OpenCV axes: z towards ``target``, y down (against ``up``)."""
    z = target - eye
    z = z / np.linalg.norm(z)
    x = np.cross(z, up)
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    E = np.eye(4, dtype=np.float32)
    E[:3, 0], E[:3, 1], E[:3, 2], E[:3, 3] = x, y, z, eye
    return E


def render(K: np.ndarray, E: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ray-cast table + cube: returns RGB (H, W, 3) uint8 and z-depth (H, W, 1) float32 metres."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    rays_cam = np.stack([u + 0.5, v + 0.5, np.ones_like(u)], axis=-1) @ np.linalg.inv(K.astype(np.float64)).T
    dirs = rays_cam @ E[:3, :3].astype(np.float64).T  # world directions with camera z-component 1
    origin = E[:3, 3].astype(np.float64)

    with np.errstate(divide="ignore", invalid="ignore"):
        t_table = (TABLE_Z - origin[2]) / dirs[..., 2]
        lo = (CUBE_CENTER - CUBE_HALF - origin) / dirs
        hi = (CUBE_CENTER + CUBE_HALF - origin) / dirs
    t_near = np.nanmax(np.minimum(lo, hi), axis=-1)
    t_far = np.nanmin(np.maximum(lo, hi), axis=-1)
    hit_cube = (t_near <= t_far) & (t_near > 0)
    t_table = np.where(t_table > 0, t_table, np.inf)
    t_cube = np.where(hit_cube, t_near, np.inf)
    depth = np.minimum(t_table, t_cube)
    rgb = np.where((t_cube < t_table)[..., None], CUBE_RGB, TABLE_RGB).astype(np.uint8)
    depth = np.where(np.isfinite(depth), depth, MISS_DEPTH_M)
    return rgb, depth[..., None].astype(np.float32)


def _quat_down(yaw: float) -> np.ndarray:
    """Gripper pointing down (180° about x) then yawed about world z; xyzw with w >= 0."""
    qx, qy, qz, qw = np.cos(yaw / 2), np.sin(yaw / 2), 0.0, 0.0  # z-yaw ∘ x-flip
    q = np.array([qx, qy, qz, qw], dtype=np.float32)
    return q if q[3] >= 0 else -q


def _dense_trajectory(length: int) -> tuple[np.ndarray, np.ndarray]:
    """End-effector positions (length, 3) and gripper_open flags (length,) of a pick-and-lift."""
    waypoints = np.array(
        [[0.1, -0.1, 1.0], [0.0, 0.0, 0.9], [0.0, 0.0, 0.84], [0.0, 0.0, 0.84], [0.0, 0.0, 1.0]]
    )
    s = np.linspace(0, len(waypoints) - 1, length)
    pos = np.stack([np.interp(s, np.arange(len(waypoints)), waypoints[:, k]) for k in range(3)], axis=-1)
    gripper_open = (np.arange(length) < 7).astype(np.float32)
    return pos.astype(np.float32), gripper_open


def _features(action_names: list[str]) -> dict:
    K = intrinsics()
    static_E = look_at(np.array([0.5, 0.0, 1.3]), CUBE_CENTER, np.array([0.0, 0.0, 1.0]))
    feats: dict = {}
    for cam in CAMERAS:
        info = {}
        if cam == "agentview":
            info = {"sigma.intrinsics": K.tolist(), "sigma.extrinsics": static_E.tolist()}
        feats[f"observation.images.{cam}"] = {
            "dtype": "image",
            "shape": (H, W, 3),
            "names": ["height", "width", "channels"],
            "info": info,
        }
        feats[f"observation.images.{cam}_depth"] = {
            "dtype": "image",
            "shape": (H, W, 1),
            "names": ["height", "width", "channels"],
            "info": {"is_depth_map": True},
        }
        feats[f"observation.camera.{cam}.intrinsics"] = {"dtype": "float32", "shape": (3, 3), "names": None}
        feats[f"observation.camera.{cam}.extrinsics"] = {"dtype": "float32", "shape": (4, 4), "names": None}
    feats["observation.state"] = {"dtype": "float32", "shape": (10,), "names": list(STATE_NAMES)}
    feats["action"] = {"dtype": "float32", "shape": (len(action_names),), "names": action_names}
    return feats


def _observation(pos: np.ndarray, quat: np.ndarray, gripper_open: float) -> dict:
    K = intrinsics()
    cams = {
        "agentview": look_at(np.array([0.5, 0.0, 1.3]), CUBE_CENTER, np.array([0.0, 0.0, 1.0])),
        "robot0_eye_in_hand": look_at(
            pos + np.array([0.0, 0.0, 0.05]), pos - np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
        ),
    }
    frame: dict = {}
    for cam, E in cams.items():
        rgb, depth = render(K, E)
        frame[f"observation.images.{cam}"] = rgb
        frame[f"observation.images.{cam}_depth"] = depth
        frame[f"observation.camera.{cam}.intrinsics"] = K
        frame[f"observation.camera.{cam}.extrinsics"] = E
    finger = 0.04 * gripper_open
    frame["observation.state"] = np.concatenate([pos, quat, [gripper_open, finger, -finger]]).astype(
        np.float32
    )
    return frame


def write_dense_dataset(root: Path, num_episodes: int = 2, write_sidecar: bool = True) -> FixtureDataset:
    """Dense dataset: every step, 7-D delta action, ``sigma.is_keyframe`` / ``sigma.next_keyframe_index``."""
    features = _features(DENSE_ACTION_NAMES)
    features["sigma.is_keyframe"] = {"dtype": "bool", "shape": (1,), "names": None}
    features["sigma.next_keyframe_index"] = {"dtype": "int64", "shape": (1,), "names": None}
    ds = LeRobotDataset.create("local/viz_dense", fps=FPS, features=features, root=root, use_videos=False)
    try:
        for ep in range(num_episodes):
            pos, gripper_open = _dense_trajectory(DENSE_LENGTH)
            pos = pos + np.float32(0.01 * ep)
            for i in range(DENSE_LENGTH):
                frame = _observation(pos[i], _quat_down(0.1 * i), float(gripper_open[i]))
                nxt = min(i + 1, DENSE_LENGTH - 1)
                grip = -1.0 if gripper_open[nxt] else 1.0
                frame["action"] = np.array([*(pos[nxt] - pos[i]), 0.0, 0.0, 0.1, grip], dtype=np.float32)
                later = [k for k in DENSE_KEYFRAMES if k > i]
                frame["sigma.is_keyframe"] = np.array([i in DENSE_KEYFRAMES])
                frame["sigma.next_keyframe_index"] = np.array([later[0] if later else i], dtype=np.int64)
                frame["task"] = TASK
                ds.add_frame(frame)
            ds.save_episode()
    finally:
        ds.finalize()
    if write_sidecar:
        (root / "meta" / "sigma.json").write_text(json.dumps({"kind": "dense"}))
    return FixtureDataset(root, "dense", (DENSE_LENGTH,) * num_episodes, len(DENSE_KEYFRAMES))


def write_keyframe_dataset(root: Path, num_episodes: int = 2, write_sidecar: bool = False) -> FixtureDataset:
    """Keyframe dataset: start frame + keyframes, 9-D action = the pose of the next frame (last: itself)."""
    ds = LeRobotDataset.create(
        "local/viz_keyframe", fps=FPS, features=_features(KEYFRAME_ACTION_NAMES), root=root, use_videos=False
    )
    frames_idx = (0, *DENSE_KEYFRAMES)
    try:
        for ep in range(num_episodes):
            pos, gripper_open = _dense_trajectory(DENSE_LENGTH)
            pos = pos + np.float32(0.01 * ep)
            poses = [(pos[i], _quat_down(0.1 * i), float(gripper_open[i])) for i in frames_idx]
            for j, (p, q, g) in enumerate(poses):
                frame = _observation(p, q, g)
                gp, gq, gg = poses[min(j + 1, len(poses) - 1)]
                frame["action"] = np.array([*gp, *gq, gg, 0.0], dtype=np.float32)
                frame["task"] = TASK
                ds.add_frame(frame)
            ds.save_episode()
    finally:
        ds.finalize()
    if write_sidecar:
        (root / "meta" / "sigma.json").write_text(json.dumps({"kind": "keyframe"}))
    return FixtureDataset(root, "keyframe", (len(frames_idx),) * num_episodes, len(DENSE_KEYFRAMES))


# ------------------------------------------------------------------------------------ reading .rrd back


@dataclass
class RrdContents:
    """An .rrd read back with Rerun's own reader (``rerun.experimental.RrdReader``).

    ``rows[entity][component]``: number of logged (non-null) rows, static rows included;
    ``static[entity]``: components logged as static; ``timeline_rows[entity][timeline]``: rows that carry
    that timeline; ``values[entity][component]``: the logged values, one entry per row, sorted by
    ``frame_index`` when rows carry it (chunks are not stored in time order).
    """

    num_recordings: int
    num_blueprints: int
    rows: dict[str, dict[str, int]]
    static: dict[str, set[str]]
    timeline_rows: dict[str, dict[str, int]]
    values: dict[str, dict[str, list]]

    def entities_under(self, prefix: str) -> set[str]:
        return {e for e in self.rows if e.startswith(prefix)}


def read_rrd(path: Path) -> RrdContents:
    """Read every chunk of the first recording in ``path`` and tally entities, components and timelines."""
    from rerun.experimental import RrdReader

    reader = RrdReader(path)
    rows: dict[str, dict[str, int]] = {}
    static: dict[str, set[str]] = {}
    timeline_rows: dict[str, dict[str, int]] = {}
    keyed: dict[str, dict[str, list[tuple[int, object]]]] = {}
    for chunk in reader.stream():
        entity = chunk.entity_path
        batch = chunk.to_record_batch()
        timelines = set(chunk.timeline_names)
        order = (
            batch.column("frame_index").to_pylist() if "frame_index" in timelines else [0] * batch.num_rows
        )
        for name in batch.schema.names:
            column = batch.column(name)
            if name == "rerun.controls.RowId" or name in timelines:
                continue
            present = [(o or 0, v) for o, v in zip(order, column.to_pylist(), strict=True) if v is not None]
            rows.setdefault(entity, {}).setdefault(name, 0)
            rows[entity][name] += len(present)
            keyed.setdefault(entity, {}).setdefault(name, []).extend(present)
            if chunk.is_static:
                static.setdefault(entity, set()).add(name)
        for timeline in timelines:
            count = batch.num_rows - batch.column(timeline).null_count
            timeline_rows.setdefault(entity, {}).setdefault(timeline, 0)
            timeline_rows[entity][timeline] += count
    values = {
        entity: {name: [v for _, v in sorted(pairs, key=lambda p: p[0])] for name, pairs in comps.items()}
        for entity, comps in keyed.items()
    }
    return RrdContents(
        num_recordings=len(reader.recordings()),
        num_blueprints=len(reader.blueprints()),
        rows=rows,
        static=static,
        timeline_rows=timeline_rows,
        values=values,
    )


def on_scene_surface(points: np.ndarray, tol: float = 2e-3) -> np.ndarray:
    """True where a world point lies on the table top or on the cube's surface (within ``tol`` metres)."""
    on_table = np.abs(points[:, 2] - TABLE_Z) < tol
    rel = np.abs(points - CUBE_CENTER)
    on_cube = (np.abs(rel.max(axis=1) - CUBE_HALF) < tol) & (rel.max(axis=1) < CUBE_HALF + tol)
    return on_table | on_cube
