"""The data contract of sigma's two LeRobot v3 datasets: every key, shape and rule, defined once.

Writers, validation, the Rerun viewer, evaluation and the policy configuration take their names from here, so
changing the data format means changing this module and the writer that follows it (``sigma_data/writers.py``).
``docs/data_contract.md`` explains the format in words; this module imports nothing from sigma, so any layer may
use it (``sigma_policy`` uses it and nothing else from ``sigma_data``).

* **dense** dataset: every 20 Hz control step; ``action`` = the executed 7-D OSC delta (:data:`DENSE_ACTION_NAMES`).
* **keyframe** dataset: the decision points of each episode; ``action`` of frame i = the 9-D pose of frame i + 1
  (:data:`KEYFRAME_ACTION_NAMES`; :func:`goal_frame` is the pairing rule), so the goal of frame i is frame i + 1.
* Both: ``observation.state`` (:data:`STATE_NAMES`), per camera RGB (:func:`rgb_key`), metric depth
  (:func:`depth_key`, optional in dense) and per-frame calibration (:func:`intrinsics_key`,
  :func:`extrinsics_key`); a provenance sidecar :data:`SIDECAR` that LeRobot never rewrites.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal

DatasetKind = Literal["dense", "keyframe"]
DENSE: DatasetKind = "dense"
KEYFRAME: DatasetKind = "keyframe"
DATASET_KINDS: tuple[DatasetKind, ...] = (DENSE, KEYFRAME)

FPS = 20  # the dense dataset's frame rate: robosuite's control frequency
ROBOT_TYPE = "panda"

# --- frame features ------------------------------------------------------------------------------------------
STATE = "observation.state"
ACTION = "action"
STATE_NAMES: tuple[str, ...] = (
    "eef_x",
    "eef_y",
    "eef_z",
    "eef_qx",
    "eef_qy",
    "eef_qz",
    "eef_qw",
    "gripper_open",
    "finger_q1",
    "finger_q2",
)
STATE_DIM = len(STATE_NAMES)
STATE_QUAT = slice(3, 7)  # the grip site's orientation, xyzw, continuous in time
GRIPPER_OPEN_INDEX = STATE_NAMES.index("gripper_open")
DENSE_ACTION_NAMES: tuple[str, ...] = ("dx", "dy", "dz", "rx", "ry", "rz", "grip")
DENSE_ACTION_DIM = len(DENSE_ACTION_NAMES)
KEYFRAME_ACTION_NAMES: tuple[str, ...] = (
    "x",
    "y",
    "z",
    "qx",
    "qy",
    "qz",
    "qw",
    "gripper_open",
    "ignore_collision",
)
KEYFRAME_ACTION_DIM = len(KEYFRAME_ACTION_NAMES)
ACTION_NAMES: Mapping[str, tuple[str, ...]] = {DENSE: DENSE_ACTION_NAMES, KEYFRAME: KEYFRAME_ACTION_NAMES}

# LeRobot's time of a frame from its episode's start, seconds (frame_index / fps; 0 on an episode's first frame).
# Unlike frame_index, LeRobot's processors pass it on to the policy.
TIMESTAMP = "timestamp"

# sigma's own per-frame columns (stock policies ignore them)
IS_KEYFRAME = "sigma.is_keyframe"  # dense: the frame is a keyframe
NEXT_KEYFRAME_INDEX = "sigma.next_keyframe_index"  # dense: episode-relative index of the next keyframe
SOURCE_FRAME = "sigma.source_frame"  # keyframe: the dense episode frame this frame was rendered from

# --- cameras ------------------------------------------------------------------------------------------------
IMAGE_PREFIX = "observation.images."
DEPTH_SUFFIX = "_depth"
CALIBRATION_PREFIX = "observation.camera."
IS_DEPTH_MAP = "is_depth_map"  # LeRobot's feature-info flag on depth streams
STATIC_INTRINSICS = "sigma.intrinsics"  # feature-info keys of a fixed camera's calibration (RGB feature)
STATIC_EXTRINSICS = "sigma.extrinsics"


def rgb_key(camera: str) -> str:
    """(H, W, 3) uint8 RGB, upright."""
    return f"{IMAGE_PREFIX}{camera}"


def depth_key(camera: str) -> str:
    """(H, W, 1) float32 metric z-depth along the optical axis, metres."""
    return f"{IMAGE_PREFIX}{camera}{DEPTH_SUFFIX}"


def intrinsics_key(camera: str) -> str:
    """(3, 3) float32 pinhole matrix of this frame."""
    return f"{CALIBRATION_PREFIX}{camera}.intrinsics"


def extrinsics_key(camera: str) -> str:
    """(4, 4) float32 camera-to-world pose of this frame, OpenCV axes."""
    return f"{CALIBRATION_PREFIX}{camera}.extrinsics"


def rgb_cameras(features: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """Names of the RGB cameras among LeRobot ``features`` (image or video features that are not depth)."""
    return sorted(
        key[len(IMAGE_PREFIX) :]
        for key, feat in features.items()
        if key.startswith(IMAGE_PREFIX)
        and feat.get("dtype") in ("image", "video")
        and not (feat.get("info") or {}).get(IS_DEPTH_MAP)
        and not key.endswith(DEPTH_SUFFIX)
    )


# Physical plausibility (validation and importers): a state outside these is garbage, not a robot.
WORKSPACE_LIMIT_M = 5.0  # |x|, |y|, |z| of any position, metres from the world origin
FINGER_RANGE_M = (-0.05, 0.15)  # finger joint positions, metres


def implausible_state(state: Any) -> str | None:
    """Why one ``observation.state`` row cannot be a robot's state (positions, quaternion, fingers), or None."""
    import numpy as np

    s = np.asarray(state, dtype=np.float64)
    if not np.isfinite(s).all():
        return "NaN or inf"
    if np.abs(s[:3]).max() > WORKSPACE_LIMIT_M:
        return f"end effector at {np.round(s[:3], 3).tolist()} m, beyond {WORKSPACE_LIMIT_M} m of the origin"
    norm = float(np.linalg.norm(s[STATE_QUAT]))
    if abs(norm - 1) > 1e-3:
        return f"orientation quaternion norm {norm:.4f}, expected 1"
    lo, hi = FINGER_RANGE_M
    fingers = s[GRIPPER_OPEN_INDEX + 1 :]
    if ((fingers < lo) | (fingers > hi)).any():
        return f"finger joints {np.round(fingers, 4).tolist()} m outside [{lo}, {hi}]"
    return None


CONVENTIONS = {
    "quaternion": "xyzw, unit; keyframe actions w >= 0; observation.state continuous in time (w >= 0 at an "
    "episode's first frame, then each frame on the previous frame's hemisphere)",
    "pose": "grip site (gripper0_right_grip_site) in the world frame, metres",
    "extrinsics": "camera-to-world 4x4, OpenCV axes (x right, y down, z forward)",
    "intrinsics": "3x3 pinhole, f = 0.5 H / tan(fovy / 2), c = (W/2, H/2); pixel centres at +0.5",
    "depth": "metric z-depth along the optical axis, metres; background clipped to render.max_depth",
    "images": "upright (row 0 at the top)",
    "dense_action": "robosuite OSC_POSE delta [dx, dy, dz, rx, ry, rz, grip], base frame, 5 cm / 0.5 rad per unit,"
    " grip +1 close / -1 open; the final frame holds (zero motion, last grip)",
    "keyframe_action": "next keyframe [x, y, z, qx, qy, qz, qw, gripper_open, ignore_collision]; the last "
    "frame repeats its own pose and is a goal only",
    "gripper_open": "1 if the last commanded grip was open (< 0), else 0",
    "frames": "frame t is the observation before action t",
}


def goal_frame(i: int, n_frames: int) -> int:
    """The keyframe dataset's pairing rule: frame i's action (and contrastive goal) is frame i + 1's pose; the
    last frame of an episode is its own goal."""
    if not 0 <= i < n_frames:
        raise IndexError(f"frame {i} outside an episode of {n_frames} frames")
    return min(i + 1, n_frames - 1)


# --- provenance sidecar -------------------------------------------------------------------------------------
SIDECAR = Path("meta") / "sigma.json"


def read_sidecar(root: str | Path) -> dict[str, Any]:
    """The dataset's ``meta/sigma.json`` (kind, conventions, bounds, calibration, one record per episode)."""
    path = Path(root) / SIDECAR
    if not path.exists():
        raise FileNotFoundError(f"{root}: no provenance sidecar {SIDECAR}")
    try:
        return json.loads(path.read_text())
    except ValueError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from exc


def _sidecar_or_empty(root: str | Path) -> dict[str, Any]:
    """The dataset's sidecar, or {} where it is missing or unreadable: what the ``recorded_*`` readers fall back on
    (a dataset written by another tool records none of it)."""
    try:
        return read_sidecar(root)
    except (OSError, ValueError):
        return {}


def recorded_bounds(root: str | Path) -> list[list[float]]:
    """The task workspace boxes a sigma dataset records (``"bounds": {task: box}``); [] if there are none."""
    return [list(b) for b in _sidecar_or_empty(root).get("bounds", {}).values()]


def recorded_instruction_bounds(root: str | Path) -> dict[str, list[float]]:
    """instruction -> its task's workspace box, from a sigma dataset's ``meta/sigma.json`` (each episode's
    ``instruction`` and ``task``, and ``"bounds": {task: box}``); {} if the sidecar records neither."""
    sidecar = _sidecar_or_empty(root)
    boxes = sidecar.get("bounds", {})
    return {
        str(ep["instruction"]): list(boxes[ep["task"]])
        for ep in sidecar.get("episodes", [])
        if "instruction" in ep and ep.get("task") in boxes
    }


def recorded_instruction_tasks(root: str | Path) -> dict[str, str]:
    """instruction -> the task it belongs to (``"put the milk in its bin"`` -> ``"pick_place"``), from the episode
    records of a sigma dataset's ``meta/sigma.json``; {} if there is no readable sidecar."""
    return {
        str(ep["instruction"]): str(ep["task"])
        for ep in _sidecar_or_empty(root).get("episodes", [])
        if "instruction" in ep and "task" in ep
    }


def dataset_kind(root: str | Path, features: Mapping[str, Mapping[str, Any]]) -> DatasetKind:
    """``"dense"`` or ``"keyframe"``: the sidecar's ``kind`` if there is a sidecar, else the action size (7 or
    9). Raises ``ValueError`` naming the file or feature when neither decides."""
    sidecar = Path(root) / SIDECAR
    if sidecar.exists():
        kind = read_sidecar(root).get("kind")
        if kind not in DATASET_KINDS:
            raise ValueError(f"{sidecar}: field 'kind' is {kind!r}, expected 'dense' or 'keyframe'")
        return kind
    if ACTION not in features:
        raise ValueError(f"{root}: no {SIDECAR} and no '{ACTION}' feature to infer the dataset kind from")
    dim = int(tuple(features[ACTION]["shape"])[-1])
    by_dim = {DENSE_ACTION_DIM: DENSE, KEYFRAME_ACTION_DIM: KEYFRAME}
    if dim not in by_dim:
        raise ValueError(
            f"{root}: no {SIDECAR} and '{ACTION}' has {dim} dims; expected {DENSE_ACTION_DIM} (dense) "
            f"or {KEYFRAME_ACTION_DIM} (keyframe)"
        )
    return by_dim[dim]
