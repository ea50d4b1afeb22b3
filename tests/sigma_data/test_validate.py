"""`sigma-data validate`: passes contract datasets and fires each check on a deliberately broken one."""

from __future__ import annotations

import json

import pytest

from sigma_data.validate import ValidateConfig, run_validate, validate_dataset
from tests.sigma_data.contract_datasets import Defects, write_dataset


def statuses(report) -> dict[str, set[str]]:
    out: dict[str, set[str]] = {}
    for c in report.checks:
        out.setdefault(c.name, set()).add(c.status)
    return out


@pytest.mark.parametrize("kind", ["dense", "keyframe"])
def test_clean_dataset_passes_and_writes_report(tmp_path, kind, capsys):
    root = write_dataset(tmp_path / kind, kind)
    report_path = tmp_path / "report.json"
    assert run_validate(ValidateConfig(root=root, report=report_path)) == 0
    report = json.loads(report_path.read_text())
    assert report["kind"] == kind and report["num_errors"] == 0
    assert report["num_episodes"] == 2 and report["cameras"] == ["top", "wrist"]
    assert report["instructions"] == {"move to spot 0": 1, "move to spot 1": 1}
    out = capsys.readouterr().out
    assert "validate passed" in out and "eef.projection" in out


BROKEN = [
    ("dense", Defects(depth_scale=1000.0), "depth.unit", "observation.images.top_depth"),
    ("dense", Defects(invalid_depth_fraction=0.6), "depth.invalid", "observation.images.top_depth"),
    ("keyframe", Defects(principal_point_outside=True), "intrinsics", "observation.camera.top.intrinsics"),
    ("keyframe", Defects(skewed_extrinsics=True), "extrinsics", "observation.camera.top.extrinsics"),
    ("dense", Defects(eef_out_of_view=True), "eef.projection", "observation.camera.top.extrinsics"),
    ("dense", Defects(no_keyframe_at_gripper_change=True), "keyframes.gripper", "sigma.is_keyframe"),
    ("dense", Defects(next_index_backwards=True), "keyframes.links", "sigma.next_keyframe_index"),
    ("keyframe", Defects(goal_offset_m=0.05), "goals.links", "action"),
    ("keyframe", Defects(negative_w=True), "goals.quaternion", "action"),
    ("dense", Defects(quat_sign_flip_at=7), "state.continuity", "observation.state[3:7]"),
]


@pytest.mark.parametrize(("kind", "defects", "check", "field"), BROKEN, ids=[b[2] for b in BROKEN])
def test_each_check_fires_on_a_broken_dataset(tmp_path, kind, defects, check, field):
    root = write_dataset(tmp_path / "broken", kind, defects)
    report = validate_dataset(ValidateConfig(root=root))
    failing = [c for c in report.checks if c.status == "error"]
    assert check in {c.name for c in failing}, report.table()
    hit = next(c for c in failing if c.name == check)
    assert hit.field == field and hit.episode is not None
    assert run_validate(ValidateConfig(root=root, report=tmp_path / "r.json")) == 1


def test_state_continuity_names_the_frame_in_its_episode(tmp_path):
    root = write_dataset(tmp_path / "flip", "dense", Defects(quat_sign_flip_at=7))
    hit = next(c for c in validate_dataset(ValidateConfig(root=root)).checks if c.name == "state.continuity")
    assert (hit.episode, hit.frame) == (0, 7) and "2 quaternion sign flip(s)" in hit.detail


def test_rgb_only_dense_dataset_passes(tmp_path):
    """A dense dataset without depth (``sigma-data collect --dense_depth=false``, for stock image policies)."""
    root = write_dataset(tmp_path / "rgb", "dense", Defects(no_depth=True))
    report = validate_dataset(ValidateConfig(root=root))
    assert report.num_errors == 0, report.table()
    assert "RGB-only dense" in next(c.detail for c in report.checks if c.name == "structure")
    keyframe = validate_dataset(
        ValidateConfig(root=write_dataset(tmp_path / "kf", "keyframe", Defects(no_depth=True)))
    )
    hit = next(c for c in keyframe.checks if c.name == "structure")  # sigma's policy needs depth
    assert hit.status == "error" and hit.field == "observation.images.top_depth"


def test_depth_range_fires(tmp_path):
    root = write_dataset(tmp_path / "far", "keyframe", Defects(depth_scale=1000.0))
    report = validate_dataset(ValidateConfig(root=root, depth_range=(0.01, 10.0)))
    assert "error" in statuses(report)["depth.range"]


def test_instruction_missing_and_splits(tmp_path):
    root = write_dataset(tmp_path / "lang", "keyframe", Defects(blank_instruction_episode=True))
    report = validate_dataset(ValidateConfig(root=root))
    assert "error" in statuses(report)["language.instruction"]

    root = write_dataset(tmp_path / "splits", "keyframe")
    info_path = root / "meta" / "info.json"
    info = json.loads(info_path.read_text())
    info["splits"] = {"train": "0:1", "val": "1:2"}
    info_path.write_text(json.dumps(info))
    report = validate_dataset(ValidateConfig(root=root))
    split_row = next(c for c in report.checks if c.name == "language.splits")
    assert split_row.status == "warn" and "move to spot 1" in split_row.detail


def test_not_a_dataset_is_a_clear_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="not a LeRobot dataset"):
        validate_dataset(ValidateConfig(root=tmp_path))
