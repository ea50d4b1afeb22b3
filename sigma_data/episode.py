"""The one in-memory episode type between every source (experts, HDF5 imports, teleop, real robots) and writers.

An :class:`Episode` holds ``T`` frames. Frame ``t`` is the observation *before* ``actions[t]`` was executed;
the last frame is the final state, and its action is a hold (zero arm motion, last gripper command), so
``len(actions) == len(states) == T``. Pixels come from one of two places:

* ``sim_states`` (T, 1 + nq + nv): flattened MuJoCo states ``[time, qpos, qvel]``; frames are rendered on
  demand by replaying the state (:func:`sigma_data.cameras.CameraRig.render_state`), so recording never pays
  for rendering and only stored frames are rendered;
* ``images``: per camera, stored frames (:class:`CameraStream`), e.g. from a real robot or an image HDF5.

Conventions (the data contract, ``docs/data_contract.md`` and :mod:`sigma_data.contract`): positions in metres, world frame; quaternions xyzw, unit;
keyframe poses (the keyframe dataset's action) with w >= 0; the state's orientation ``observation.state[3:7]``
continuous in time (:func:`continuous_quats`: w >= 0 at frame 0, then each frame on the hemisphere of the one
before, so a policy never sees q jump to -q between two frames; with the gripper pointing down w is near 0 and
the w >= 0 rule flipped it several times per episode); extrinsics camera-to-world 4x4 in OpenCV axes (x right, y down, z forward); depth metric
z-depth along the optical axis, metres; images upright (row 0 at the top).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sigma_data.contract import (  # noqa: F401  (re-exported: the names an Episode is written with)
    DENSE_ACTION_NAMES,
    GRIPPER_OPEN_INDEX,
    KEYFRAME_ACTION_NAMES,
    STATE_DIM,
    STATE_NAMES,
)


def canonical_quat(quat_xyzw: np.ndarray) -> np.ndarray:
    """Normalise xyzw quaternion(s) (..., 4) and flip the sign so that w >= 0."""
    q = np.asarray(quat_xyzw, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., 3:4] < 0, -q, q)


def continuous_quats(quats_xyzw: np.ndarray) -> np.ndarray:
    """(T, 4) xyzw quaternions -> the same rotations, unit, w >= 0 at frame 0 and every later frame's sign chosen
    so that its dot product with the previous frame's is >= 0 (hemisphere continuity; the sign of ``q`` and
    ``-q`` is the only thing that changes)."""
    q = canonical_quat(quats_xyzw)
    if len(q) < 2:
        return q
    flips = np.einsum("ij,ij->i", q[1:], q[:-1]) < 0  # does frame t's canonical sign oppose frame t-1's?
    sign = np.concatenate([[1.0], np.where(np.cumprod(np.where(flips, -1.0, 1.0)) < 0, -1.0, 1.0)])
    return q * sign[:, None]


@dataclass(frozen=True)
class Keyframe:
    """A decision point: frame ``index`` ends a motion segment.

    ``gripper_open`` and ``ignore_collision`` are the labels of the motion that *reaches* this frame (RLBench
    semantics: the gripper state to hold there, and whether the approach may touch the scene).
    ``source`` is ``"expert"`` (a scripted waypoint end), ``"heuristic"`` (discovered) or ``"final"`` (the
    last frame, always a keyframe).
    """

    index: int
    gripper_open: bool
    ignore_collision: bool
    source: str = "expert"


@dataclass
class CameraFrame:
    """One camera at one frame: upright RGB (H, W, 3) uint8, metric depth (H, W) float32 metres,
    intrinsics (3, 3) and camera-to-world extrinsics (4, 4) (OpenCV axes), all at the same state."""

    rgb: np.ndarray
    depth: np.ndarray
    intrinsics: np.ndarray
    extrinsics: np.ndarray


@dataclass
class CameraStream:
    """Stored frames of one camera: rgb (T, H, W, 3) uint8, depth (T, H, W) float32 metres,
    intrinsics (T, 3, 3), extrinsics (T, 4, 4) camera-to-world OpenCV."""

    rgb: np.ndarray
    depth: np.ndarray
    intrinsics: np.ndarray
    extrinsics: np.ndarray

    def __len__(self) -> int:
        return len(self.rgb)

    def frame(self, t: int) -> CameraFrame:
        return CameraFrame(self.rgb[t], self.depth[t], self.intrinsics[t], self.extrinsics[t])


# A frame's camera views by camera name.
CameraViews = dict[str, CameraFrame]


@dataclass
class Episode:
    """One demonstration, source-independent. ``T`` frames; see the module docstring for the frame convention.

    Fields:
        task, variation: registry names (``"stack"``, ``"red_on_green"``); free text for other sources.
        instruction: the natural-language instruction (LeRobot's per-frame ``task``).
        states: (T, 10) float32 ``observation.state`` (:data:`STATE_NAMES`); the quaternion is made continuous
            in time on construction (:func:`continuous_quats`).
        actions: (T, 7) float32 executed OSC_POSE deltas ``[dx, dy, dz, rx, ry, rz, grip]`` (+1 close).
        keyframes: sorted by index, unique, the last one at frame ``T - 1``.
        joint_velocities: (T, n_arm) rad/s, for the keyframe heuristic (optional).
        sim_states: (T, D) flattened MuJoCo states for render-by-replay (optional).
        images: stored camera frames by camera name (optional).
        seed: the reset seed (sim sources), or None.
        provenance: free-form JSON-able facts about the source (importer, file, demo name, ...).
    """

    task: str
    variation: str
    instruction: str
    states: np.ndarray
    actions: np.ndarray
    keyframes: list[Keyframe]
    joint_velocities: np.ndarray | None = None
    sim_states: np.ndarray | None = None
    images: Mapping[str, CameraStream] | None = None
    seed: int | None = None
    provenance: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.states = np.array(self.states, dtype=np.float32)
        self.actions = np.asarray(self.actions, dtype=np.float32)
        self.validate()
        self.states[:, 3:7] = continuous_quats(self.states[:, 3:7])

    @property
    def name(self) -> str:
        seed = "" if self.seed is None else f" seed {self.seed}"
        return f"episode {self.task}/{self.variation}{seed}"

    def __len__(self) -> int:
        return len(self.states)

    @property
    def keyframe_indices(self) -> list[int]:
        return [k.index for k in self.keyframes]

    def validate(self) -> None:
        """Raise ``ValueError`` naming the episode and field if shapes or keyframes are inconsistent."""
        T = len(self.states)
        if T < 2:
            raise ValueError(f"{self.name}: needs at least 2 frames, got {T}")
        if self.states.shape != (T, STATE_DIM):
            raise ValueError(f"{self.name}: states must be (T, {STATE_DIM}), got {self.states.shape}")
        if self.actions.shape != (T, len(DENSE_ACTION_NAMES)):
            raise ValueError(f"{self.name}: actions must be ({T}, 7), got {self.actions.shape}")
        for name, arr in (("states", self.states), ("actions", self.actions)):
            if not np.isfinite(arr).all():
                raise ValueError(f"{self.name}: {name} contain NaN or inf")
        norm = np.linalg.norm(self.states[:, 3:7], axis=1)
        if (np.abs(norm - 1) > 1e-2).any():
            t = int(np.flatnonzero(np.abs(norm - 1) > 1e-2)[0])
            raise ValueError(f"{self.name}: states[{t}, 3:7] (eef quaternion) has norm {norm[t]:.4f}, not 1")
        idx = self.keyframe_indices
        if not idx or idx != sorted(set(idx)) or idx[0] < 1 or idx[-1] != T - 1:
            raise ValueError(
                f"{self.name}: keyframes must be unique, increasing, in [1, {T - 1}] and end at the last "
                f"frame {T - 1}; got {idx}"
            )
        if self.joint_velocities is not None and len(self.joint_velocities) != T:
            raise ValueError(f"{self.name}: joint_velocities has {len(self.joint_velocities)} rows, not {T}")
        if self.sim_states is not None and len(self.sim_states) != T:
            raise ValueError(f"{self.name}: sim_states has {len(self.sim_states)} rows, not {T}")
        for cam, stream in (self.images or {}).items():
            if len(stream) != T:
                raise ValueError(f"{self.name}: camera '{cam}' has {len(stream)} stored frames, not {T}")
        if self.sim_states is None and not self.images:
            raise ValueError(f"{self.name}: no pixels source (neither sim_states nor images)")

    def keyframe_poses(self) -> np.ndarray:
        """(K, 9) float32 keyframe actions ``[x, y, z, qx, qy, qz, qw, gripper_open, ignore_collision]``."""
        rows = []
        for kf in self.keyframes:
            s = self.states[kf.index]
            quat = canonical_quat(s[3:7])
            rows.append([*s[:3], *quat, float(kf.gripper_open), float(kf.ignore_collision)])
        return np.asarray(rows, dtype=np.float32)

    def decision_frames(self, start: int = 0) -> list[int]:
        """Frames of one keyframe chain: ``start``, then every keyframe strictly after it."""
        return [start] + [k for k in self.keyframe_indices if k > start]


def gripper_open_from_actions(actions: np.ndarray, initial_open: bool = True) -> np.ndarray:
    """(T,) float32 gripper-open flags per frame from the *commanded* grip (robosuite: +1 close, -1 open).

    Frame t reflects the last command before it, ``actions[t - 1, -1] < 0``; frame 0 is ``initial_open``.
    """
    actions = np.asarray(actions)
    out = np.empty(len(actions), dtype=np.float32)
    out[0] = float(initial_open)
    out[1:] = (actions[:-1, -1] < 0).astype(np.float32)
    return out


def hold_action(last_action: np.ndarray | None, gripper_open: bool = True) -> np.ndarray:
    """The final frame's action: no arm motion, the last gripper command (+1 close / -1 open)."""
    grip = float(last_action[-1]) if last_action is not None else (-1.0 if gripper_open else 1.0)
    return np.array([0, 0, 0, 0, 0, 0, grip], dtype=np.float32)


def with_final_keyframe(keyframes: Sequence[Keyframe], length: int, gripper_open: bool) -> list[Keyframe]:
    """``keyframes`` plus the last frame as a keyframe (source ``"final"``) if it is not one already.

    The final keyframe keeps the last gripper state and ``ignore_collision = False`` (no motion reaches it).
    """
    out = list(keyframes)
    if not out or out[-1].index != length - 1:
        out.append(Keyframe(length - 1, gripper_open, False, source="final"))
    return out
