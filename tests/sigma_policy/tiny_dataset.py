"""A tiny synthetic keyframe dataset that follows the sigma data contract, written with the real LeRobot writer.

Scene: a table plane at z = 0.8 m, one or two coloured cubes (5 cm) and a small dark "gripper" marker cube at the
end-effector position, seen by two static RGB-D cameras (``front`` and ``side``) that are ray-cast exactly
(z-depth in metres along the optical axis, OpenCV axes, pixel centres at +0.5).

Episode (keyframe dataset): frame 0 = start (gripper at home), frame 1 = pre-grasp 8 cm above the target cube,
frame 2 = the grasp at the cube centre (final state, goal only). Frame i's ``action`` is frame i+1's pose
``[x, y, z, qx, qy, qz, qw, gripper_open, ignore_collision]`` (top-down gripper, quaternion xyzw (1, 0, 0, 0));
the last frame repeats its own pose.

``scenes="varied"``: one cube ("red"), its position changes per episode, instruction "reach the red cube".
``scenes="language"``: one fixed scene with a red and a blue cube; episodes alternate between the instructions
"reach the red cube" and "reach the blue cube" and go to the named cube.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sigma_data.episode import KEYFRAME_ACTION_NAMES, STATE_NAMES

TABLE_Z = 0.8
CUBE_HALF = 0.025
MARKER_HALF = 0.02
HOME = np.array([0.0, 0.0, 1.15], dtype=np.float32)
DOWN_QUAT = np.array([1.0, 0.0, 0.0, 0.0], dtype=np.float32)  # xyzw, 180 deg about x: gripper points down
BOUNDS = (-0.3, -0.3, 0.7, 0.3, 0.3, 1.3)  # metres; scene box for the policy on this dataset
CAMERAS = {"front": ((0.75, 0.0, 1.35), (0.0, 0.0, 0.85)), "side": ((0.1, -0.7, 1.45), (0.0, 0.0, 0.85))}
FOVY_DEG = 55.0
COLORS = {"red": (220, 30, 30), "blue": (30, 60, 230), "table": (150, 140, 120), "marker": (20, 20, 20)}


@dataclass(frozen=True)
class Box:
    center: np.ndarray
    half: float
    color: tuple[int, int, int]


def intrinsics(size: int) -> np.ndarray:
    f = 0.5 * size / np.tan(np.deg2rad(FOVY_DEG) / 2)
    return np.array([[f, 0, size / 2], [0, f, size / 2], [0, 0, 1]], dtype=np.float32)


def look_at(eye, target) -> np.ndarray:
    """Camera-to-world 4x4 in OpenCV axes (x right, y down, z forward) looking from ``eye`` at ``target``."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    out = np.eye(4, dtype=np.float32)
    out[:3, :3] = np.stack([x, y, z], axis=1)
    out[:3, 3] = eye
    return out


def render(K: np.ndarray, E: np.ndarray, size: int, boxes: list[Box]) -> tuple[np.ndarray, np.ndarray]:
    """Ray-cast the table plane and axis-aligned boxes: RGB (H, W, 3) uint8 and z-depth (H, W, 1) float32 m."""
    u, v = np.meshgrid(np.arange(size) + 0.5, np.arange(size) + 0.5)
    d_cam = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1)
    d = d_cam @ E[:3, :3].T.astype(float)  # world direction per unit camera z, so ray parameter = z-depth
    eye = E[:3, 3].astype(float)
    depth = np.full((size, size), np.inf)
    rgb = np.zeros((size, size, 3), dtype=np.uint8)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_table = (TABLE_Z - eye[2]) / d[..., 2]
    hit = (t_table > 0) & np.isfinite(t_table)
    depth[hit] = t_table[hit]
    rgb[hit] = COLORS["table"]
    for box in boxes:
        lo, hi = box.center - box.half, box.center + box.half
        with np.errstate(divide="ignore", invalid="ignore"):
            t0, t1 = (lo - eye) / d, (hi - eye) / d
        t_near = np.minimum(t0, t1).max(axis=-1)
        t_far = np.maximum(t0, t1).min(axis=-1)
        hit = (t_near <= t_far) & (t_near > 0) & (t_near < depth)
        depth[hit] = t_near[hit]
        rgb[hit] = box.color
    if not np.isfinite(depth).all():
        raise ValueError("tiny dataset camera sees past the table; move the camera")
    return rgb, depth[..., None].astype(np.float32)


def features(size: int) -> dict:
    feats: dict = {}
    for cam, (eye, target) in CAMERAS.items():
        feats[f"observation.images.{cam}"] = {
            "dtype": "image",
            "shape": (size, size, 3),
            "names": ["height", "width", "channels"],
            "info": {
                "sigma.intrinsics": intrinsics(size).tolist(),
                "sigma.extrinsics": look_at(eye, target).tolist(),
            },
        }
        feats[f"observation.images.{cam}_depth"] = {
            "dtype": "image",
            "shape": (size, size, 1),
            "names": ["height", "width", "channels"],
            "info": {"is_depth_map": True},
        }
        feats[f"observation.camera.{cam}.intrinsics"] = {"dtype": "float32", "shape": (3, 3), "names": None}
        feats[f"observation.camera.{cam}.extrinsics"] = {"dtype": "float32", "shape": (4, 4), "names": None}
    feats["observation.state"] = {"dtype": "float32", "shape": (10,), "names": list(STATE_NAMES)}
    feats["action"] = {"dtype": "float32", "shape": (9,), "names": list(KEYFRAME_ACTION_NAMES)}
    return feats


def pose_vector(pos: np.ndarray, gripper_open: float, ignore_collision: float) -> np.ndarray:
    return np.concatenate([pos, DOWN_QUAT, [gripper_open, ignore_collision]]).astype(np.float32)


LIFT_M = 0.1  # the "grasp_lift" plan's lift


def episode_plan(target: np.ndarray, plan: str = "reach") -> list[tuple[np.ndarray, float]]:
    """(eef position, gripper_open) of the keyframes: home, pre-grasp, grasp (closed) for ``"reach"``; home,
    pre-grasp, at the grasp open, closed in place, lifted for ``"grasp_lift"``."""
    above = target + np.array([0, 0, 0.08], np.float32)
    if plan == "reach":
        return [(HOME, 1.0), (above, 1.0), (target.copy(), 0.0)]
    if plan == "grasp_lift":
        lifted = target + np.array([0, 0, LIFT_M], np.float32)
        return [(HOME, 1.0), (above, 1.0), (target.copy(), 1.0), (target.copy(), 0.0), (lifted, 0.0)]
    raise ValueError(f"plan must be 'reach' or 'grasp_lift', got {plan!r}")


def scene_layout(scenes: str, episode: int, rng: np.random.Generator) -> tuple[dict[str, np.ndarray], str]:
    """Cube centres by colour and the named target colour."""
    z = TABLE_Z + CUBE_HALF
    if scenes == "varied":
        xy = rng.uniform(-0.15, 0.15, size=2)
        return {"red": np.array([xy[0], xy[1], z], np.float32)}, "red"
    if scenes == "language":
        cubes = {"red": np.array([0.1, 0.12, z], np.float32), "blue": np.array([-0.08, -0.1, z], np.float32)}
        return cubes, ("red", "blue")[episode % 2]
    raise ValueError(f"scenes must be 'varied' or 'language', got {scenes!r}")


def write_tiny_keyframe_dataset(
    root: Path, episodes: int = 6, size: int = 48, scenes: str = "varied", seed: int = 0, plan: str = "reach"
) -> Path:
    """Write the dataset under ``root`` (must not exist) with LeRobot's writer and return ``root``; ``plan`` is
    :func:`episode_plan`'s."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    rng = np.random.default_rng(seed)
    K = intrinsics(size)
    extrinsics = {cam: look_at(eye, target) for cam, (eye, target) in CAMERAS.items()}
    ds = LeRobotDataset.create(
        "local/sigma_tiny", fps=20, features=features(size), root=root, use_videos=False
    )
    try:
        for ep in range(episodes):
            cubes, target_color = scene_layout(scenes, ep, rng)
            keyframes = episode_plan(cubes[target_color], plan)
            instruction = f"reach the {target_color} cube"
            for i, (pos, grip) in enumerate(keyframes):
                nxt_pos, nxt_grip = keyframes[min(i + 1, len(keyframes) - 1)]
                boxes = [Box(c, CUBE_HALF, COLORS[name]) for name, c in cubes.items()]
                boxes.append(Box(pos + np.array([0, 0, 0.06], np.float32), MARKER_HALF, COLORS["marker"]))
                state = np.concatenate([pos, DOWN_QUAT, [grip, 0.04 * grip, 0.04 * grip]]).astype(np.float32)
                frame = {
                    "observation.state": state,
                    "action": pose_vector(nxt_pos, nxt_grip, float(i == 0)),
                    "task": instruction,
                }
                for cam, E in extrinsics.items():
                    rgb, depth = render(K, E, size, boxes)
                    frame[f"observation.images.{cam}"] = rgb
                    frame[f"observation.images.{cam}_depth"] = depth
                    frame[f"observation.camera.{cam}.intrinsics"] = K
                    frame[f"observation.camera.{cam}.extrinsics"] = E
                ds.add_frame(frame)
            ds.save_episode()
    finally:
        ds.finalize()
    return root
