"""What a sigma dataset's frames carry: the camera layout, the camera columns' LeRobot features, depth encoding.

:class:`DatasetLayout` (cameras, image size, whether depth is stored) is fixed per dataset and shared by every
source (the collectors and the importers in ``sigma_data/importers/``) and both writers (``sigma_data/writers.py``).
The column names come from ``sigma_data/contract.py``; docs/data_contract.md describes them.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from sigma_data.contract import (
    IS_DEPTH_MAP,
    STATIC_EXTRINSICS,
    STATIC_INTRINSICS,
    depth_key,
    extrinsics_key,
    intrinsics_key,
    rgb_key,
)
from sigma_data.episode import CameraViews

# Per camera, the fixed (K, E) of a camera that does not move, recorded once in its feature's info.
StaticCalibration = Mapping[str, tuple[np.ndarray, np.ndarray]]

__all__ = [
    "DatasetLayout",
    "DepthRange",
    "StaticCalibration",
    "camera_features",
    "camera_frame_values",
    "depth_encoder_config",
]


@dataclass(frozen=True)
class DatasetLayout:
    """What every frame carries: cameras, image size (pixels) and whether depth is stored.

    ``depth=False`` writes RGB-only camera features (calibration kept): stock LeRobot image policies (ACT,
    Diffusion Policy) take every video feature as a 3-channel image and fail on a 1-channel depth stream."""

    cameras: tuple[str, ...]
    height: int
    width: int
    depth: bool = True


@dataclass(frozen=True)
class DepthRange:
    """Depth quantiser range for video depth, metres (12-bit log codes; values outside are clipped)."""

    depth_min: float = 0.02
    depth_max: float = 3.0


def depth_encoder_config(depth_range: DepthRange = DepthRange()) -> Any:
    """LeRobot's depth video encoder as sigma uses it: 12-bit log-quantised HEVC, lossless as LeRobot's
    default, with x265's per-video statistics silenced. (x265's ``ultrafast`` preset takes a quarter of the
    default's ~10 ms of CPU per 128^2 frame, but its decoded depth was off by up to 0.4 m in the writer
    round-trip test: not used.)"""
    from lerobot.configs.video import DepthEncoderConfig

    return DepthEncoderConfig(
        depth_min=depth_range.depth_min,
        depth_max=depth_range.depth_max,
        extra_options={"x265-params": "lossless=1:log-level=error"},
    )


def camera_features(
    layout: DatasetLayout, dtype: str, static_calibration: StaticCalibration | None = None
) -> dict[str, dict]:
    """LeRobot feature specs of the contract's camera features (RGB, depth, per-frame K and E)."""
    h, w = layout.height, layout.width
    feats: dict[str, dict] = {}
    for cam in layout.cameras:
        rgb_info: dict[str, Any] = {}
        if static_calibration and cam in static_calibration:
            K, E = static_calibration[cam]
            rgb_info = {
                STATIC_INTRINSICS: np.asarray(K, dtype=np.float32).tolist(),
                STATIC_EXTRINSICS: np.asarray(E, dtype=np.float32).tolist(),
            }
        feats[rgb_key(cam)] = {
            "dtype": dtype,
            "shape": (h, w, 3),
            "names": ["height", "width", "channels"],
            **({"info": rgb_info} if rgb_info else {}),
        }
        if layout.depth:
            feats[depth_key(cam)] = {
                "dtype": dtype,
                "shape": (h, w, 1),
                "names": ["height", "width", "channels"],
                "info": {IS_DEPTH_MAP: True},
            }
        feats[intrinsics_key(cam)] = {"dtype": "float32", "shape": (3, 3), "names": None}
        feats[extrinsics_key(cam)] = {"dtype": "float32", "shape": (4, 4), "names": None}
    return feats


def camera_frame_values(layout: DatasetLayout, views: CameraViews, where: str) -> dict[str, np.ndarray]:
    """One frame's camera columns from its rendered views; ``where`` (episode and frame) prefixes the errors of a
    missing camera or a wrong image shape."""
    out: dict[str, np.ndarray] = {}
    for cam in layout.cameras:
        if cam not in views:
            raise KeyError(f"{where}: no view of camera '{cam}' (have {sorted(views)})")
        v = views[cam]
        if v.rgb.shape != (layout.height, layout.width, 3):
            raise ValueError(
                f"{where}: camera '{cam}' rgb is {v.rgb.shape}, expected {(layout.height, layout.width, 3)}"
            )
        out[rgb_key(cam)] = v.rgb
        if layout.depth:
            out[depth_key(cam)] = v.depth.reshape(layout.height, layout.width, 1).astype(np.float32)
        out[intrinsics_key(cam)] = np.asarray(v.intrinsics, dtype=np.float32)
        out[extrinsics_key(cam)] = np.asarray(v.extrinsics, dtype=np.float32)
    return out
