"""Policy viewer: log synthetic policy outputs to .rrd and read them back with Rerun's reader."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pipelines.viz.blueprints import policy_blueprint
from pipelines.viz.cli import ViewerDelivery, close_recording, open_recording
from pipelines.viz.policy import (
    DEFAULT_VIEW_NAMES,
    heatmap_to_rgba,
    log_policy_frame,
    quaternion_angle_deg,
)
from tests.pipelines import viz_fixtures as fx

V, C, H, W = 5, 10, 16, 20
NUM_POINTS, BUDGET, BINS = 500, 200, 72
PEAKS = [(2, 3), (5, 7), (8, 1), (15, 19), (0, 0)]  # (row, col) of each view's heatmap mode
INSTRUCTION = "put the red cube in the drawer"


def _outputs(with_gt: bool = True) -> dict:
    g = torch.Generator().manual_seed(0)
    views = torch.rand(V, C, H, W, generator=g) * 2 - 1
    views[:, 3:6] = torch.rand(V, 3, H, W, generator=g)
    views[:, 6, :4, :4] = -1.0  # empty pixels
    logits = torch.randn(V, H, W, generator=g)
    for v, (r, c) in enumerate(PEAKS):
        logits[v, r, c] = 20.0
    heatmaps = torch.softmax(logits.view(V, -1), dim=1).view(V, H, W)
    s = np.sqrt(0.5)
    pred = torch.tensor([0.10, 0.00, 0.90, 0.0, 0.0, 0.0, 1.0, 1.0, 0.0])
    gt = torch.tensor([0.10, 0.03, 0.94, 0.0, 0.0, s, s, 0.0, 1.0])  # 50 mm away, 90° about z
    rot = torch.softmax(torch.randn(3, BINS, generator=g), dim=1)
    return {
        "views": views,
        "heatmaps": heatmaps,
        "pred_action": pred,
        "gt_action": gt if with_gt else None,
        "cloud_xyz": torch.rand(NUM_POINTS, 3, generator=g),
        "cloud_rgb": torch.rand(NUM_POINTS, 3, generator=g),
        "rot_probs": rot,
        "grip_probs": torch.tensor([0.2, 0.8]),
        "collision_probs": torch.tensor([0.9, 0.1]),
        "instruction": INSTRUCTION,
    }


def _log(tmp_path, outputs: dict, **kwargs) -> tuple[fx.RrdContents, object]:
    delivery = ViewerDelivery(save=tmp_path / "policy.rrd")
    rec = open_recording("sigma/test_policy", delivery, policy_blueprint(DEFAULT_VIEW_NAMES))
    try:
        rec.set_time("frame_index", sequence=0)
        summary = log_policy_frame(rec, **outputs, point_budget=BUDGET, **kwargs)
    finally:
        close_recording(rec, delivery)
    return fx.read_rrd(tmp_path / "policy.rrd"), summary


def test_policy_frame_entities_and_counts(tmp_path):
    gt_pixels = torch.tensor([[c + 0.5, r + 0.5] for r, c in PEAKS])
    contents, summary = _log(tmp_path, _outputs(), gt_pixels=gt_pixels)
    assert contents.num_recordings == 1 and contents.num_blueprints == 1

    view_entities = {e.split("/")[3] for e in contents.entities_under("/policy/views/")}
    assert view_entities == set(DEFAULT_VIEW_NAMES)
    for v, name in enumerate(DEFAULT_VIEW_NAMES):
        base = f"/policy/views/{name}"
        assert contents.rows[f"{base}/rgb"]["Image:buffer"] == 1
        assert contents.rows[f"{base}/heatmap_overlay"]["Image:buffer"] == 1
        assert contents.rows[f"{base}/heatmap"]["Tensor:data"] == 1
        assert contents.rows[f"{base}/depth"]["DepthImage:buffer"] == 1
        assert contents.rows[f"{base}/xyz"]["Image:buffer"] == 1
        r, c = PEAKS[v]
        peak = contents.values[f"{base}/markers/peak"]["Points2D:positions"][0][0]
        assert peak == pytest.approx([c + 0.5, r + 0.5])
        assert contents.values[f"{base}/markers/gt"]["Points2D:positions"][0][0] == pytest.approx(peak)

    cloud = contents.values["/policy/world/point_cloud"]["Points3D:positions"]
    assert len(cloud) == 1 and len(cloud[0]) == BUDGET
    pred_t = contents.values["/policy/world/pred"]["Transform3D:translation"][0][0]
    gt_t = contents.values["/policy/world/gt"]["Transform3D:translation"][0][0]
    assert pred_t == pytest.approx([0.10, 0.00, 0.90]) and gt_t == pytest.approx([0.10, 0.03, 0.94])
    arrow = contents.values["/policy/world/error"]["Arrows3D:vectors"][0][0]
    assert arrow == pytest.approx([0.0, -0.03, -0.04], abs=1e-6)
    assert (
        contents.values["/policy/world/pred/label"]["Points3D:labels"][0][0] == "pred: open, avoid collisions"
    )
    assert (
        contents.values["/policy/world/gt/label"]["Points3D:labels"][0][0] == "gt: closed, ignore collisions"
    )

    for axis in "xyz":
        bars = contents.values[f"/policy/probs/rotation/{axis}"]["BarChart:values"]
        assert len(bars) == 1
    assert contents.rows["/policy/probs/gripper"]["BarChart:values"] == 1
    assert contents.rows["/policy/probs/collision"]["BarChart:values"] == 1

    assert summary.translation_error_m == pytest.approx(0.05, abs=1e-6)
    assert summary.rotation_error_deg == pytest.approx(90.0, abs=1e-3)
    assert summary.gripper_open_prob == pytest.approx(0.8)
    assert summary.num_points == BUDGET
    text = contents.values["/policy/summary"]["TextDocument:text"][0][0]
    assert INSTRUCTION in text and "50.0 mm" in text and "90.0°" in text


def test_live_frame_without_ground_truth(tmp_path):
    contents, summary = _log(tmp_path, _outputs(with_gt=False), step=3)
    assert summary.translation_error_m is None and summary.rotation_error_deg is None
    gt_rows = contents.rows["/policy/world/gt"]
    assert "Transform3D:translation" not in gt_rows and gt_rows["Clear:is_recursive"] == 1  # stale gt cleared
    assert contents.timeline_rows["/policy/world/pred"]["step"] == 1
    text = contents.values["/policy/summary"]["TextDocument:text"][0][0]
    assert "**pred**" in text and "**gt**" not in text


def test_heatmap_overlay_alpha_follows_heat():
    hm = np.zeros((4, 5), dtype=np.float32)
    hm[1, 2], hm[3, 4] = 0.75, 0.25
    rgba = heatmap_to_rgba(hm)
    assert rgba.shape == (4, 5, 4) and rgba.dtype == np.uint8
    assert rgba[1, 2, 3] == rgba[..., 3].max() > rgba[3, 4, 3] > 0
    assert rgba[0, 0, 3] == 0


def test_quaternion_angle_is_sign_invariant():
    q = np.array([0.0, 0.0, np.sin(np.pi / 8), np.cos(np.pi / 8)])  # 45° about z
    identity = np.array([0.0, 0.0, 0.0, 1.0])
    assert quaternion_angle_deg(q, identity) == pytest.approx(45.0)
    assert quaternion_angle_deg(-q, identity) == pytest.approx(45.0)


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("heatmaps", torch.zeros(V, H + 1, W), "heatmaps: expected shape"),
        ("pred_action", torch.zeros(8), "pred_action: expected shape"),
        ("cloud_rgb", torch.zeros(NUM_POINTS - 1, 3), "cloud_rgb: expected shape"),
        ("views", torch.zeros(V, 6, H, W), "expected >= 7 channels"),
        ("rot_probs", torch.zeros(2, BINS), "rot_probs: expected shape"),
    ],
)
def test_bad_shapes_are_named(tmp_path, key, value, message):
    outputs = _outputs()
    outputs[key] = value
    with pytest.raises(ValueError, match=message):
        _log(tmp_path, outputs)
