"""Import raw real-robot episodes (sigma's directory format) into the dense and keyframe datasets.

The format fits the paper's real setup (a UR5 arm and one fixed overhead RGB-D camera; any number of fixed or
moving cameras works). All geometry is in one **world frame** (typically the robot base): metres, quaternions
xyzw, camera extrinsics camera-to-world in OpenCV axes (x right, y down, z forward). ``docs/raw_format.md``
holds the same specification with an example. ::

    <root>/                              a directory of episodes, imported in sorted name order
      <episode>/                         (``--path`` may also point at one episode directory)
        episode.json                     {"instruction": "put the cup on the plate",     (required)
                                          "task": "cup_on_plate", "variation": "default",  (optional names)
                                          "fps": 20}                                       (optional, default 20)
        cameras/<cam>.json               one file per camera:
                                          {"height": 480, "width": 640,                    (required, pixels)
                                           "intrinsics": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]],   (required)
                                           "pixel_centers_at": 0.0,   (0.0: OpenCV calibration, pixel (u, v)
                                                                        centred at (u, v) -- the default;
                                                                        0.5: already sigma's convention)
                                           "extrinsics": 4x4 camera-to-world,  (a fixed camera; omit it for a
                                                                                moving camera, see frames)
                                           "depth_scale": 0.001}      (metres per unit of 16-bit PNG depth)
        rgb/<cam>/000000.png ...         8-bit RGB, height x width, one per frame (6-digit frame number)
        depth/<cam>/000000.png ...       16-bit depth, units of depth_scale (default millimetres), 0 = none
          or depth/<cam>/000000.npy      float32 (height, width) metres; 0 or NaN = none
        frames.jsonl                     one JSON object per frame, frame 0 first:
          {"eef_pos": [x, y, z],                     tool-centre-point position, metres          (required)
           "eef_quat": [qx, qy, qz, qw],             its orientation                             (required)
           "gripper_open": 1,                        1/true open, 0/false closed (commanded)     (required)
           "gripper_width": 0.085,                   finger opening, metres                      (optional)
           "keyframe": true,                         a hand-marked keyframe                      (optional)
           "ignore_collision": false,                label of the motion reaching that keyframe  (optional)
           "joint_positions": [q1, ..., q6],         arm joints, radians                         (optional)
           "action": [dx, dy, dz, rx, ry, rz, grip], the dense action, if the robot logged one   (optional)
           "extrinsics": {"<cam>": 4x4}}             camera-to-world of a moving camera          (optional)

Depth is z-depth along the optical axis, registered to the RGB image (same size and intrinsics).

Conversion (what lands in the datasets):

* ``observation.state`` = ``[eef_pos, eef_quat (w >= 0), gripper_open, gripper_width / 2, -gripper_width / 2]``
  (finger values 0 when ``gripper_width`` is absent);
* intrinsics: ``cx, cy`` shifted by ``0.5 - pixel_centers_at`` to sigma's convention (pixel centres at +0.5);
* dense ``action``: ``action`` when every frame has one; else derived from consecutive poses in robosuite's
  OSC_POSE delta units, ``(p[t+1] - p[t]) / 0.05 m`` and the rotation vector of ``R[t+1] R[t]^T`` / 0.5 rad,
  grip ``-1`` if frame t+1 is open else ``+1``; the last frame holds;
* keyframes: the marked frames plus every gripper change plus the last frame, when any frame is marked; else
  the ARM/PerAct heuristic on joint velocities (finite differences of ``joint_positions`` x fps); an episode
  with neither is an error.

Bad input (a missing file or field, an image of the wrong size or type, NaN poses) fails that episode with an
error naming the file and field; the other episodes still convert.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sigma_data.cameras import parse_cameras
from sigma_data.dataset_layout import DatasetLayout
from sigma_data.episode import CameraStream, Episode, Keyframe, canonical_quat
from sigma_data.importers import (
    DatasetSink,
    ImportSummary,
    OutputError,
    SourceError,
    finite_or_error,
    stored_views,
)
from sigma_data.keyframes import discover_keyframes
from sigma_data.output import OutputConfig

EPISODE_FILE = "episode.json"
FRAMES_FILE = "frames.jsonl"
DEFAULT_FPS = 20.0
POS_UNIT = 0.05  # metres per unit of robosuite's OSC_POSE delta
ROT_UNIT = 0.5  # radians per unit


@dataclass
class RawImportConfig:
    """Options of ``sigma-data import raw``."""

    # A directory of episode directories, or one episode directory (holding episode.json).
    path: Path | None = None
    # Where and how the datasets are written.
    output: OutputConfig = field(default_factory=OutputConfig)
    # Stored cameras to import, comma-separated (nothing is rendered); None = every camera of the first episode
    # (cameras/*.json).
    cameras: str | None = None
    # Convert at most this many episodes (sorted by name); None = all.
    max_episodes: int | None = None
    # Override every episode's instruction.
    instruction: str | None = None
    # Show a progress bar.
    progress: bool = True


@dataclass
class CameraSpec:
    """One camera's calibration file: K in sigma's convention (3, 3), optional fixed camera-to-world E (4, 4)."""

    name: str
    height: int
    width: int
    intrinsics: np.ndarray
    extrinsics: np.ndarray | None
    depth_scale: float


def episode_dirs(path: Path) -> list[Path]:
    """Episode directories under ``path`` (or ``[path]`` if it is one), sorted by name."""
    if not path.is_dir():
        raise FileNotFoundError(f"{path}: no such directory")
    if (path / EPISODE_FILE).is_file():
        return [path]
    eps = sorted(p for p in path.iterdir() if p.is_dir() and (p / EPISODE_FILE).is_file())
    if not eps:
        raise SourceError(path, None, EPISODE_FILE, "no episode directories (each needs an episode.json)")
    return eps


def _read_json(path: Path, episode: str) -> dict[str, Any]:
    if not path.is_file():
        raise SourceError(path, episode, None, "missing file")
    try:
        out = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise SourceError(path, episode, None, f"not valid JSON ({exc})") from None
    if not isinstance(out, dict):
        raise SourceError(path, episode, None, "must hold a JSON object")
    return out


def _matrix(value: Any, shape: tuple[int, int], path: Path, episode: str, name: str) -> np.ndarray:
    try:
        m = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise SourceError(path, episode, name, f"must be a {shape[0]}x{shape[1]} matrix of numbers") from None
    if m.shape != shape or not np.isfinite(m).all():
        raise SourceError(
            path, episode, name, f"must be a finite {shape[0]}x{shape[1]} matrix, got shape {m.shape}"
        )
    return m


def _check_pose(E: np.ndarray, path: Path, episode: str, name: str) -> np.ndarray:
    R = E[:3, :3]
    if (
        np.abs(R.T @ R - np.eye(3)).max() > 1e-3
        or np.linalg.det(R) < 0
        or np.abs(E[3] - [0, 0, 0, 1]).max() > 1e-6
    ):
        raise SourceError(
            path, episode, name, "not a rigid camera-to-world transform (rotation not orthonormal)"
        )
    return E


def read_camera(ep_dir: Path, cam: str) -> CameraSpec:
    """Read ``cameras/<cam>.json``; intrinsics converted to sigma's pixel-centre convention."""
    path = ep_dir / "cameras" / f"{cam}.json"
    spec = _read_json(path, ep_dir.name)
    for key in ("height", "width", "intrinsics"):
        if key not in spec:
            raise SourceError(path, ep_dir.name, key, "missing")
    h, w = int(spec["height"]), int(spec["width"])
    if h <= 0 or w <= 0:
        raise SourceError(path, ep_dir.name, "height/width", f"must be positive, got {h}x{w}")
    K = _matrix(spec["intrinsics"], (3, 3), path, ep_dir.name, "intrinsics")
    if K[0, 0] <= 0 or K[1, 1] <= 0 or np.abs(K[2] - [0, 0, 1]).max() > 1e-9:
        raise SourceError(path, ep_dir.name, "intrinsics", "needs fx, fy > 0 and last row (0, 0, 1)")
    shift = 0.5 - float(spec.get("pixel_centers_at", 0.0))
    K[0, 2] += shift
    K[1, 2] += shift
    E = None
    if "extrinsics" in spec:
        E = _check_pose(
            _matrix(spec["extrinsics"], (4, 4), path, ep_dir.name, "extrinsics"),
            path,
            ep_dir.name,
            "extrinsics",
        )
    scale = float(spec.get("depth_scale", 0.001))
    if not scale > 0:
        raise SourceError(path, ep_dir.name, "depth_scale", f"must be > 0, got {scale}")
    return CameraSpec(cam, h, w, K, E, scale)


def _read_image(path: Path, episode: str, cam: CameraSpec, depth: bool) -> np.ndarray:
    import cv2

    what = "depth" if depth else "rgb"
    if depth and path.suffix == ".npy":
        try:
            img = np.load(path)
        except (OSError, ValueError) as exc:
            raise SourceError(path, episode, what, f"cannot read: {exc}") from None
        img = img.reshape(img.shape[:2]) if img.ndim == 3 and img.shape[2] == 1 else img
        if img.ndim != 2 or not np.issubdtype(img.dtype, np.floating):
            raise SourceError(
                path, episode, what, f"must be float (H, W) metres, got {img.dtype} {img.shape}"
            )
    else:
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise SourceError(path, episode, what, "cannot read the image (missing, truncated or not a PNG)")
        if depth and (img.ndim != 2 or img.dtype != np.uint16):
            raise SourceError(
                path, episode, what, f"must be a 16-bit single-channel PNG, got {img.dtype} {img.shape}"
            )
        if not depth and (img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8):
            raise SourceError(path, episode, what, f"must be an 8-bit RGB PNG, got {img.dtype} {img.shape}")
    if img.shape[:2] != (cam.height, cam.width):
        raise SourceError(
            path,
            episode,
            what,
            f"image is {img.shape[0]}x{img.shape[1]}, camera '{cam.name}' is {cam.height}x{cam.width} (cameras/{cam.name}.json)",
        )
    if depth:
        out = img.astype(np.float32) * (cam.depth_scale if img.dtype == np.uint16 else 1.0)
        return np.nan_to_num(out, nan=0.0, posinf=0.0, neginf=0.0)
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def _depth_path(ep_dir: Path, cam: str, t: int) -> Path:
    png = ep_dir / "depth" / cam / f"{t:06d}.png"
    npy = png.with_suffix(".npy")
    if png.is_file():
        return png
    if npy.is_file():
        return npy
    raise SourceError(png, ep_dir.name, "depth", f"missing depth image for frame {t} (neither .png nor .npy)")


def read_frames(ep_dir: Path) -> list[dict[str, Any]]:
    path = ep_dir / FRAMES_FILE
    if not path.is_file():
        raise SourceError(path, ep_dir.name, None, "missing file")
    frames = []
    for line_no, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        try:
            frame = json.loads(line)
        except json.JSONDecodeError as exc:
            raise SourceError(path, ep_dir.name, f"line {line_no}", f"not valid JSON ({exc})") from None
        if not isinstance(frame, dict):
            raise SourceError(path, ep_dir.name, f"line {line_no}", "must be a JSON object")
        frames.append(frame)
    if len(frames) < 2:
        raise SourceError(path, ep_dir.name, None, f"needs at least 2 frames, got {len(frames)}")
    return frames


def _column(frames: Sequence[dict], key: str, width: int | None, path: Path, episode: str) -> np.ndarray:
    rows = []
    for t, frame in enumerate(frames):
        if key not in frame:
            raise SourceError(path, episode, f"frame {t}.{key}", "missing")
        rows.append(frame[key])
    try:
        arr = np.asarray(rows, dtype=np.float64)
    except (TypeError, ValueError):
        raise SourceError(path, episode, key, "values must be numbers (same length in every frame)") from None
    if width is not None and arr.shape != (len(frames), width):
        raise SourceError(path, episode, key, f"must have {width} values per frame, got shape {arr.shape}")
    finite_or_error(arr.reshape(len(arr), -1), path, episode, key)
    return arr


def derived_actions(pos: np.ndarray, quat: np.ndarray, gripper_open: np.ndarray) -> np.ndarray:
    """(T, 7) OSC_POSE-style deltas between consecutive poses (robosuite units), the last frame holding."""
    from scipy.spatial.transform import Rotation

    T = len(pos)
    out = np.zeros((T, 7), dtype=np.float64)
    rot = Rotation.from_quat(quat)
    out[:-1, :3] = (pos[1:] - pos[:-1]) / POS_UNIT
    out[:-1, 3:6] = (rot[1:] * rot[:-1].inv()).as_rotvec() / ROT_UNIT
    out[:-1, 6] = np.where(gripper_open[1:] > 0.5, -1.0, 1.0)
    out[-1, 6] = -1.0 if gripper_open[-1] > 0.5 else 1.0
    return out


def read_episode(
    ep_dir: Path, cameras: Sequence[str], instruction: str | None = None
) -> tuple[Episode, list[CameraSpec]]:
    """Read one raw episode into an :class:`Episode` with stored images; :class:`SourceError` on bad input."""
    name = ep_dir.name
    meta = _read_json(ep_dir / EPISODE_FILE, name)
    text = instruction if instruction is not None else meta.get("instruction")
    if not isinstance(text, str) or not text.strip():
        raise SourceError(ep_dir / EPISODE_FILE, name, "instruction", "missing or empty")
    fps = float(meta.get("fps", DEFAULT_FPS))
    if not fps > 0:
        raise SourceError(ep_dir / EPISODE_FILE, name, "fps", f"must be > 0, got {fps}")
    frames = read_frames(ep_dir)
    fpath = ep_dir / FRAMES_FILE
    T = len(frames)
    pos = _column(frames, "eef_pos", 3, fpath, name)
    quat = _column(frames, "eef_quat", 4, fpath, name)
    if (np.linalg.norm(quat, axis=1) < 1e-6).any():
        raise SourceError(fpath, name, "eef_quat", "zero-length quaternion")
    quat = canonical_quat(quat)
    gripper = (_column(frames, "gripper_open", None, fpath, name).reshape(T) > 0.5).astype(np.float32)
    width = (
        _column(frames, "gripper_width", None, fpath, name).reshape(T)
        if all("gripper_width" in f for f in frames)
        else np.zeros(T)
    )
    states = np.concatenate([pos, quat, gripper[:, None], width[:, None] / 2, -width[:, None] / 2], axis=1)
    has_actions = all("action" in f for f in frames)
    actions = (
        _column(frames, "action", 7, fpath, name) if has_actions else derived_actions(pos, quat, gripper)
    )

    joint_vel = None
    if all("joint_positions" in f for f in frames):
        q = _column(frames, "joint_positions", None, fpath, name)
        joint_vel = np.gradient(q, axis=0) * fps if q.ndim == 2 else None
    marked = [t for t, f in enumerate(frames) if f.get("keyframe")]
    if marked and marked[0] == 0:
        marked = marked[1:]  # frame 0 is the start, never a keyframe
    if marked or any(f.get("keyframe") for f in frames):
        changes = [t for t in range(1, T) if gripper[t] != gripper[t - 1]]
        indices = sorted(set(marked) | set(changes) | {T - 1})
        sources = {t: "manual" if t in marked else "gripper" if t in changes else "final" for t in indices}
    elif joint_vel is not None:
        indices = discover_keyframes(joint_vel, gripper)
        sources = dict.fromkeys(indices, "heuristic")
    else:
        raise SourceError(
            fpath, name, "keyframe", "no frame is marked and there are no joint_positions for the heuristic"
        )
    keyframes = [
        Keyframe(t, bool(gripper[t]), bool(frames[t].get("ignore_collision", False)), source=sources[t])
        for t in indices
    ]

    specs = [read_camera(ep_dir, cam) for cam in cameras]
    streams = {}
    for cam in specs:
        rgb = np.empty((T, cam.height, cam.width, 3), dtype=np.uint8)
        depth = np.empty((T, cam.height, cam.width), dtype=np.float32)
        extr = np.empty((T, 4, 4), dtype=np.float32)
        for t in range(T):
            rgb[t] = _read_image(ep_dir / "rgb" / cam.name / f"{t:06d}.png", name, cam, depth=False)
            depth[t] = _read_image(_depth_path(ep_dir, cam.name, t), name, cam, depth=True)
            per_frame = (frames[t].get("extrinsics") or {}).get(cam.name)
            if per_frame is not None:
                field_name = f"frame {t}.extrinsics.{cam.name}"
                extr[t] = _check_pose(
                    _matrix(per_frame, (4, 4), fpath, name, field_name), fpath, name, field_name
                )
            elif cam.extrinsics is not None:
                extr[t] = cam.extrinsics
            else:
                raise SourceError(
                    fpath,
                    name,
                    f"frame {t}.extrinsics.{cam.name}",
                    f"missing, and cameras/{cam.name}.json has no fixed extrinsics",
                )
        intr = np.broadcast_to(cam.intrinsics.astype(np.float32), (T, 3, 3)).copy()
        streams[cam.name] = CameraStream(rgb, depth, intr, extr)
    episode = Episode(
        task=str(meta.get("task", "real_robot")),
        variation=str(meta.get("variation", "default")),
        instruction=text.strip(),
        states=states,
        actions=actions,
        keyframes=keyframes,
        joint_velocities=joint_vel,
        images=streams,
        provenance={
            "importer": "raw",
            "episode_dir": str(ep_dir),
            "fps": fps,
            "actions": "recorded" if has_actions else "derived from consecutive eef poses",
            "finger_width": "recorded"
            if all("gripper_width" in f for f in frames)
            else "absent (stored as 0)",
            **{k: v for k, v in meta.items() if k not in ("instruction",)},
        },
    )
    return episode, specs


def static_calibration(
    episode: Episode, specs: Sequence[CameraSpec]
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """K and E of the cameras whose extrinsics never change in ``episode``."""
    out = {}
    for cam in specs:
        E = episode.images[cam.name].extrinsics
        if np.abs(E - E[0]).max() == 0:
            out[cam.name] = (cam.intrinsics, E[0].astype(np.float64))
    return out


def camera_names(ep_dir: Path) -> tuple[str, ...]:
    names = tuple(sorted(p.stem for p in (ep_dir / "cameras").glob("*.json")))
    if not names:
        raise SourceError(ep_dir / "cameras", ep_dir.name, None, "no camera files (cameras/<cam>.json)")
    return names


def import_raw(cfg: RawImportConfig) -> ImportSummary:
    """Convert the raw episodes under ``cfg.path`` into the datasets under ``cfg.output.dir``."""
    from tqdm import tqdm

    if cfg.path is None:
        raise ValueError("--path is required (a raw episode directory or a directory of them)")
    if cfg.max_episodes is not None and cfg.max_episodes < 1:
        raise ValueError(f"max_episodes must be >= 1, got {cfg.max_episodes}")
    root = Path(cfg.path)
    cfg.output.check_writable()
    dirs = episode_dirs(root)[: cfg.max_episodes]
    cameras = parse_cameras(cfg.cameras, "--cameras") if cfg.cameras else camera_names(dirs[0])
    provenance = {
        "source": "raw real-robot episodes (sigma_data.importers.raw, docs/raw_format.md)",
        "path": str(root.resolve()),
        "conventions_note": "world frame = the frame of the raw episodes' poses and extrinsics (robot base)",
    }
    with DatasetSink(cfg.output, "raw", provenance) as sink:
        for ep_dir in tqdm(dirs, desc=f"import {root.name}", unit="ep", disable=not cfg.progress):
            try:
                episode, specs = read_episode(ep_dir, cameras, cfg.instruction)
                h, w = specs[0].height, specs[0].width
                if any((c.height, c.width) != (h, w) for c in specs):
                    sizes = {c.name: (c.height, c.width) for c in specs}
                    raise SourceError(
                        ep_dir / "cameras", ep_dir.name, None, f"cameras differ in size {sizes}"
                    )
                layout = DatasetLayout(tuple(cameras), h, w)
                sink.add(episode, stored_views(episode), layout, static_calibration(episode, specs))
            except OutputError:
                raise  # the output, not this episode: every later one would fail too
            except Exception as exc:
                sink.fail(
                    str(ep_dir),
                    exc if isinstance(exc, SourceError) else SourceError(ep_dir, None, None, repr(exc)),
                )
    return sink.summary
