"""Tiny synthetic datasets that follow the sigma data contract, written with the real LeRobot writer.

A table plane at z = 0.8 m seen by a fixed top-down camera and a wrist camera riding 10 cm above the end
effector; the end effector moves and the gripper closes at frame 10. ``Defects`` break one thing at a time so
that every validation check can be shown to fire.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sigma_data.episode import STATE_NAMES

TABLE_Z = 0.8
SIZE = 24
FOVY_DEG = 45.0
KEYFRAMES = (5, 10, 19)  # expert keyframes of the 20-frame dense episode
LENGTH = 20
DOWN = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]])  # camera-to-world rotation looking straight down


@dataclass
class Defects:
    depth_scale: float = 1.0  # 1000 stores millimetres in a metres field
    invalid_depth_fraction: float = 0.0
    principal_point_outside: bool = False
    skewed_extrinsics: bool = False
    eef_out_of_view: bool = False
    no_keyframe_at_gripper_change: bool = False
    next_index_backwards: bool = False
    goal_offset_m: float = 0.0
    negative_w: bool = False
    blank_instruction_episode: bool = False
    quat_sign_flip_at: int = -1  # from this frame on, the state quaternion is stored as -q
    no_depth: bool = False  # RGB-only cameras (allowed for dense datasets)


def intrinsics() -> np.ndarray:
    f = 0.5 * SIZE / np.tan(np.deg2rad(FOVY_DEG) / 2)
    return np.array([[f, 0, SIZE / 2], [0, f, SIZE / 2], [0, 0, 1]], dtype=np.float32)


def pose(position) -> np.ndarray:
    out = np.eye(4, dtype=np.float32)
    out[:3, :3], out[:3, 3] = DOWN, position
    return out


def eef_track(t: int, episode: int) -> tuple[np.ndarray, float]:
    s = t / (LENGTH - 1)
    pos = np.array([-0.05 + 0.1 * s, 0.02 * episode - 0.05 * s, 1.0 - 0.1 * s], dtype=np.float32)
    return pos, 1.0 if t < 10 else 0.0


def features(kind: str, depth: bool = True) -> dict:
    feats = {}
    for cam in ("top", "wrist"):
        feats[f"observation.images.{cam}"] = {
            "dtype": "image",
            "shape": (SIZE, SIZE, 3),
            "names": ["height", "width", "channels"],
        }
        if depth:
            feats[f"observation.images.{cam}_depth"] = {
                "dtype": "image",
                "shape": (SIZE, SIZE, 1),
                "names": ["height", "width", "channels"],
                "info": {"is_depth_map": True},
            }
        feats[f"observation.camera.{cam}.intrinsics"] = {"dtype": "float32", "shape": (3, 3), "names": None}
        feats[f"observation.camera.{cam}.extrinsics"] = {"dtype": "float32", "shape": (4, 4), "names": None}
    feats["observation.state"] = {"dtype": "float32", "shape": (10,), "names": list(STATE_NAMES)}
    if kind == "dense":
        feats["action"] = {
            "dtype": "float32",
            "shape": (7,),
            "names": ["dx", "dy", "dz", "rx", "ry", "rz", "grip"],
        }
        feats["sigma.is_keyframe"] = {"dtype": "bool", "shape": (1,), "names": None}
        feats["sigma.next_keyframe_index"] = {"dtype": "int64", "shape": (1,), "names": None}
    else:
        feats["action"] = {
            "dtype": "float32",
            "shape": (9,),
            "names": ["x", "y", "z", "qx", "qy", "qz", "qw", "gripper_open", "ignore_collision"],
        }
    return feats


def frame(t: int, episode: int, defects: Defects) -> dict:
    pos, grip = eef_track(t, episode)
    if defects.eef_out_of_view:
        pos = pos + np.array([3.0, 0, 0], dtype=np.float32)
    quat = np.array([1.0, 0, 0, 0], dtype=np.float32)  # xyzw: 180 deg about x (gripper pointing down)
    if 0 <= defects.quat_sign_flip_at <= t:
        quat = -quat
    state = np.concatenate([pos, quat, [grip], [0.04 * grip, -0.04 * grip]]).astype(np.float32)
    out = {"observation.state": state}
    rng = np.random.default_rng(t)
    for cam, cam_pos in (("top", np.array([0.0, 0.0, 2.0])), ("wrist", pos + [0, 0, 0.1])):
        K, E = intrinsics(), pose(cam_pos)
        if defects.principal_point_outside:
            K[0, 2] = 3 * SIZE
        if defects.skewed_extrinsics:
            E[0, 1] = 0.3
        depth = np.full((SIZE, SIZE, 1), (cam_pos[2] - TABLE_Z) * defects.depth_scale, dtype=np.float32)
        if defects.invalid_depth_fraction:
            depth[rng.random((SIZE, SIZE)) < defects.invalid_depth_fraction] = 0.0
        rgb = np.full((SIZE, SIZE, 3), (90, 120, 60), dtype=np.uint8)
        out |= {
            f"observation.images.{cam}": rgb,
            f"observation.camera.{cam}.intrinsics": K,
            f"observation.camera.{cam}.extrinsics": E,
        }
        if not defects.no_depth:
            out[f"observation.images.{cam}_depth"] = depth
    return out


def write_dataset(root: Path, kind: str, defects: Defects | None = None, episodes: int = 2) -> Path:
    """Write a 2-episode contract dataset (``kind`` = "dense" or "keyframe") under ``root``; return it."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    defects = defects or Defects()
    ds = LeRobotDataset.create(
        f"local/contract_{kind}",
        fps=20,
        features=features(kind, depth=not defects.no_depth),
        root=root,
        use_videos=False,
    )
    try:
        for ep in range(episodes):
            instruction = "" if (defects.blank_instruction_episode and ep == 1) else f"move to spot {ep % 2}"
            keyframes = [k for k in KEYFRAMES if not (defects.no_keyframe_at_gripper_change and k == 10)]
            if kind == "dense":
                for t in range(LENGTH):
                    fr = frame(t, ep, defects)
                    nxt = next((k for k in keyframes if k > t), LENGTH - 1)
                    if defects.next_index_backwards and t == 7:
                        nxt = 2
                    fr["action"] = np.zeros(7, dtype=np.float32)
                    fr["sigma.is_keyframe"] = np.array([t in keyframes])
                    fr["sigma.next_keyframe_index"] = np.array([nxt], dtype=np.int64)
                    ds.add_frame(fr | {"task": instruction})
            else:
                stops = [0, *keyframes]
                frames = [frame(t, ep, defects) for t in stops]
                for i, fr in enumerate(frames):
                    goal = frames[min(i + 1, len(frames) - 1)]["observation.state"]
                    action = np.concatenate([goal[:7], [goal[7], 0.0]]).astype(np.float32)
                    action[0] += defects.goal_offset_m
                    if defects.negative_w:
                        action[3:7] = [0.0, 0.0, 0.0, -1.0]
                    ds.add_frame(fr | {"action": action, "task": instruction})
            ds.save_episode()
    finally:
        ds.finalize()
    (root / "meta" / "sigma.json").write_text(json.dumps({"kind": kind}))
    return root
