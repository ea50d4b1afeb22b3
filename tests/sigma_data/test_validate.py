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
    """A dense dataset without depth (``sigma-data collect --output.dense_depth=false``, for stock image policies)."""
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


def _edit_parquet(root, edit) -> None:
    """Rewrite the dataset's (single) data parquet file with ``edit(table) -> table``."""
    import pyarrow.parquet as pq

    (path,) = sorted((root / "data").rglob("*.parquet"))
    pq.write_table(edit(pq.read_table(path)), path)


def _set(table, column: str, row: int, value):
    import pyarrow as pa

    values = table.column(column).to_pylist()
    values[row] = value
    index = table.schema.get_field_index(column)
    return table.set_column(
        index, table.schema.field(index), pa.array(values, type=table.schema.field(index).type)
    )


def test_a_lost_row_is_named(tmp_path):
    """One dropped parquet row: stock LeRobot would index past the episode's end; validate names the episode."""
    root = write_dataset(tmp_path / "lost", "dense")
    _edit_parquet(root, lambda t: t.take([i for i in range(t.num_rows) if i != 5]))
    hit = next(c for c in validate_dataset(ValidateConfig(root=root)).checks if c.name == "rows.count")
    assert hit.status == "error" and hit.episode == 0 and "rows in data/" in hit.detail


def test_implausible_values_and_honest_numbers(tmp_path):
    """Garbage that is finite still fails (positions 1e31 m away); messages give the real numbers and the frame
    within the episode, not the dataset row."""
    root = write_dataset(tmp_path / "garbage", "keyframe")
    report = validate_dataset(ValidateConfig(root=root))
    second = report.num_frames // 2 + 1  # row of frame 1 of episode 1 (two equal episodes)

    def edit(t):
        state = t.column("observation.state").to_pylist()
        state[second][0] = 6.6e31
        t = _set(t, "observation.state", second, state[second])
        action = t.column("action").to_pylist()
        action[second][3:7] = [0.0, 0.0, 0.0, 0.0]
        t = _set(t, "action", second, action[second])
        extr = t.column("observation.camera.top.extrinsics").to_pylist()
        extr[second][0][3] = float("nan")
        return _set(t, "observation.camera.top.extrinsics", second, extr[second])

    _edit_parquet(root, edit)
    checks = {c.name: c for c in validate_dataset(ValidateConfig(root=root)).checks if c.status == "error"}
    plausible = checks["values.plausible"]
    assert (plausible.episode, plausible.frame) == (1, 1) and "beyond 5.0 m" in plausible.detail
    assert "norm 0.0000" in checks["goals.quaternion"].detail and checks["goals.quaternion"].frame == 1
    assert checks["extrinsics"].detail == "NaN or inf in the camera-to-world transform"
    assert (checks["extrinsics"].episode, checks["extrinsics"].frame) == (1, 1)


def test_an_undecodable_image_is_named(tmp_path):
    root = write_dataset(tmp_path / "png", "keyframe")  # images stored in the parquet rows (PNG bytes)

    def edit(t):
        img = t.column("observation.images.top").to_pylist()
        img[0]["bytes"] = b"\x89PNG\r\n\x1a\n" + b"\x00" * 64
        return _set(t, "observation.images.top", 0, img[0])

    _edit_parquet(root, edit)
    report = validate_dataset(ValidateConfig(root=root))
    hit = next(c for c in report.checks if c.name == "images.decode")
    assert hit.status == "error" and (hit.episode, hit.frame, hit.field) == (0, 0, "observation.images.top")
    assert "does not decode" in hit.detail
