"""What ``SigmaPolicy`` reads from a LeRobot batch: frames, instructions, the camera cloud and the proprio input.

A training batch carries a time axis ``[current, goal]`` on every ``observation.*`` tensor
(``observation_delta_indices=[0, 1]``); an inference batch has none and is frame 0. Every reader names the key and
the shape it expected when the batch does not match, so a dataset without a camera or with a wrong shape fails with
the field's name rather than deep inside the network.

The camera cloud (docs/method.md §3): each camera's metric depth, intrinsics and camera-to-world extrinsics
(sigma_data/contract.py names them per camera) give world points coloured by its RGB, all cameras concatenated.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
from lerobot.utils.constants import OBS_STATE
from torch import Tensor

from sigma_data.contract import STATE_QUAT, TIMESTAMP
from sigma_policy.configuration_sigma import SigmaConfig
from sigma_policy.pointcloud import depth_to_world_points, world_to_cube
from sigma_policy.rotation import quat_to_matrix
from sigma_policy.test_time import transform_points

__all__ = [
    "Cloud",
    "batch_tasks",
    "camera_cloud",
    "check_depth_unit",
    "first_frames",
    "proprio_input",
    "site_position",
    "take",
]

MM_PER_M = 1000.0


@dataclass
class Cloud:
    """The fused camera cloud of one frame."""

    points: Tensor  # (B, N, 3) world metres; NaN where depth was invalid
    colors: Tensor  # (B, N, 3) RGB in [0, 1]


def take(batch: dict[str, Any], key: str, t: int, item_ndim: int) -> Tensor:
    """Frame ``t`` of ``batch[key]``: (B, T, *item) -> (B, *item); (B, *item) is frame 0 (inference)."""
    if key not in batch:
        raise KeyError(
            f"sigma: batch has no '{key}' (keys: {sorted(k for k in batch if k.startswith('obs'))})"
        )
    x = batch[key]
    if x.ndim == item_ndim + 2:
        return x[:, t]
    if x.ndim == item_ndim + 1 and t == 0:
        return x
    raise ValueError(
        f"sigma: '{key}' has shape {tuple(x.shape)}; expected (B, {'T, ' if t else ''}...) with a "
        f"{item_ndim}-D item" + ("; the goal frame needs observation_delta_indices=[0, 1]" if t else "")
    )


def batch_tasks(batch: dict[str, Any], b: int) -> list[str]:
    """The ``b`` language instructions of the batch (its ``task`` strings)."""
    if "task" not in batch:
        raise KeyError("sigma: batch has no 'task' (the language instruction)")
    tasks = batch["task"]
    tasks = [tasks] if isinstance(tasks, str) else list(tasks)
    if len(tasks) != b:
        raise ValueError(f"sigma: {len(tasks)} task strings for a batch of {b}")
    return tasks


def first_frames(batch: dict[str, Any], b: int, device: torch.device, option: str) -> Tensor:
    """(B,) bool: which samples are their episode's first frame (timestamp 0); ``option`` names who asks."""
    if TIMESTAMP not in batch:
        raise KeyError(f"sigma: {option} needs the batch's '{TIMESTAMP}'")
    first = torch.as_tensor(batch[TIMESTAMP], device=device).reshape(-1) < 1e-6
    if first.shape != (b,):
        raise ValueError(f"sigma: '{TIMESTAMP}' has {first.numel()} entries for a batch of {b}")
    return first


def check_depth_unit(depth_m: Tensor, key: str, depth_unit: str) -> None:
    """Fail fast when depth read as ``depth_unit`` is clearly not metres (e.g. millimetres read as metres)."""
    valid = depth_m[torch.isfinite(depth_m) & (depth_m > 0)]
    if valid.numel() == 0:
        raise ValueError(f"depth feature '{key}' has no valid (finite, > 0) pixel in this batch")
    median = float(valid.median())
    if not 0.02 < median < 50.0:
        raise ValueError(
            f"depth feature '{key}' has median {median:.4g} m when read as policy.depth_unit='{depth_unit}'; "
            "set --policy.depth_unit to the unit the dataset returns (LeRobot's --dataset.depth_output_unit, "
            "default 'mm')"
        )


def camera_cloud(batch: dict[str, Any], config: SigmaConfig, t: int, check_depth: bool = False) -> Cloud:
    """The world-frame cloud of all of ``config``'s cameras at frame ``t``; ``check_depth`` first checks each
    camera's depth unit (:func:`check_depth_unit`)."""
    scale = 1 / MM_PER_M if config.depth_unit == "mm" else 1.0
    points, colors = [], []
    for cam in config.camera_names():
        keys = config.camera_keys(cam)
        rgb = take(batch, keys["rgb"], t, 3).float()
        depth = take(batch, keys["depth"], t, 3).float()[:, 0] * scale
        K = take(batch, keys["intrinsics"], t, 2).float()
        E = take(batch, keys["extrinsics"], t, 2).float()
        if check_depth:
            check_depth_unit(depth, keys["depth"], config.depth_unit)
        if rgb.shape[-2:] != depth.shape[-2:]:
            raise ValueError(f"camera '{cam}': RGB {tuple(rgb.shape)} and depth {tuple(depth.shape)} differ")
        points.append(depth_to_world_points(depth, K, E).flatten(1, 2))
        colors.append(rgb.flatten(2).transpose(1, 2))
    return Cloud(points=torch.cat(points, 1), colors=torch.cat(colors, 1).clamp(0, 1))


def site_position(
    batch: dict[str, Any], t: int, device: torch.device, transforms: Tensor | None = None
) -> Tensor:
    """(B, 3) the grip site's world position at frame ``t`` (``observation.state[:3]``), moved by the
    augmentation ``transforms`` (B, 4, 4) when given."""
    pos = take(batch, OBS_STATE, t, 1).float()[:, :3].to(device)
    return pos if transforms is None else transform_points(transforms, pos)


def proprio_input(
    batch: dict[str, Any],
    config: SigmaConfig,
    bounds: Tensor,
    transforms: Tensor | None,
    device: torch.device,
) -> Tensor | None:
    """The proprio token's input: [gripper_open, finger_q1, finger_q2] (+ the grip site's position in the scene box
    with ``proprio_position``, + its orientation as the first two columns of its rotation matrix with
    ``proprio_orientation``; both moved by the same augmentation as the cloud); None without ``use_proprio``."""
    if not config.use_proprio:
        return None
    state = take(batch, OBS_STATE, 0, 1).float()
    parts = [state[:, 7:10]]
    if config.proprio_position:
        parts.append(world_to_cube(site_position(batch, 0, device, transforms).to(state), bounds))
    if config.proprio_orientation:
        R = quat_to_matrix(state[:, STATE_QUAT])
        if transforms is not None:
            R = transforms[:, :3, :3].to(state) @ R
        parts.append(R[:, :, :2].transpose(1, 2).flatten(1))  # columns x, y: continuous, sign-free
    return torch.cat(parts, dim=-1)
