"""The camera columns of a frame (``sigma_data/dataset_layout.py``): their LeRobot features and one frame's values."""

from __future__ import annotations

import numpy as np
import pytest

from sigma_data.contract import (
    IS_DEPTH_MAP,
    STATIC_INTRINSICS,
    depth_key,
    extrinsics_key,
    intrinsics_key,
    rgb_key,
)
from sigma_data.dataset_layout import DatasetLayout, camera_features, camera_frame_values
from sigma_data.episode import CameraFrame


def _frame(h: int, w: int) -> CameraFrame:
    return CameraFrame(
        rgb=np.zeros((h, w, 3), np.uint8),
        depth=np.ones((h, w), np.float32),
        intrinsics=np.eye(3),
        extrinsics=np.eye(4),
    )


def test_features_follow_the_layout():
    K, E = np.eye(3), np.eye(4)
    with_depth = camera_features(DatasetLayout(("agentview", "wrist"), 8, 6), "image", {"agentview": (K, E)})
    assert with_depth[rgb_key("agentview")]["shape"] == (8, 6, 3)
    assert with_depth[rgb_key("agentview")]["info"][STATIC_INTRINSICS] == K.tolist()
    assert "info" not in with_depth[rgb_key("wrist")]  # no static calibration given for it
    assert with_depth[depth_key("wrist")]["info"] == {IS_DEPTH_MAP: True}
    assert with_depth[intrinsics_key("wrist")]["shape"] == (3, 3)
    rgb_only = camera_features(DatasetLayout(("agentview",), 8, 6, depth=False), "video")
    assert depth_key("agentview") not in rgb_only and extrinsics_key("agentview") in rgb_only


def test_frame_values_name_the_frame_and_camera_at_fault():
    layout = DatasetLayout(("agentview",), 8, 6)
    values = camera_frame_values(layout, {"agentview": _frame(8, 6)}, "ep 3 frame 7")
    assert values[depth_key("agentview")].shape == (8, 6, 1)
    assert values[depth_key("agentview")].dtype == np.float32
    with pytest.raises(KeyError, match="ep 3 frame 7: no view of camera 'agentview'"):
        camera_frame_values(layout, {"wrist": _frame(8, 6)}, "ep 3 frame 7")
    with pytest.raises(ValueError, match=r"ep 3 frame 7: camera 'agentview' rgb is \(6, 8, 3\)"):
        camera_frame_values(layout, {"agentview": _frame(6, 8)}, "ep 3 frame 7")
