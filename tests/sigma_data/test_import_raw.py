"""Raw real-robot episodes (synthetic fixture written here in the documented format) into both datasets:
validation passes, stock LeRobot reads them, depth/calibration/keyframes round-trip; bad episodes fail alone."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from sigma_data.cli import main as cli_main
from sigma_data.importers import REPORT, SourceError
from sigma_data.importers.raw import RawImportConfig, import_raw, read_episode
from sigma_data.output import OutputConfig
from sigma_data.validate import ValidateConfig, validate_dataset

H, W = 24, 32
T = 12
DOWN = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]])  # camera-to-world rotation looking straight down
TOP_POS = np.array([0.4, 0.0, 1.0])
GRIP_CLOSE_AT = 6  # first closed frame
QUAT = [0.9238795, 0.0, 0.0, 0.3826834]  # xyzw, 135 deg about x: the tool points down and back


def pose(R: np.ndarray, t: np.ndarray) -> list:
    E = np.eye(4)
    E[:3, :3], E[:3, 3] = R, t
    return E.tolist()


def eef_pos(t: int) -> np.ndarray:
    s = t / (T - 1)
    return np.array([0.3 + 0.2 * s, 0.05 * s, 0.3 - 0.2 * np.sin(np.pi * s)])


def write_episode(root: Path, name: str, marks: bool = True, joints: bool = False) -> Path:
    """One episode: a fixed overhead camera ('top', 16-bit PNG depth in mm) over a table plane at z = 0 with
    a box, and a wrist camera ('wrist', .npy depth in m, per-frame extrinsics)."""
    ep = root / name
    (ep / "cameras").mkdir(parents=True)
    f = 0.5 * H / np.tan(np.deg2rad(45.0) / 2)
    K = [[f, 0, (W - 1) / 2], [0, f, (H - 1) / 2], [0, 0, 1]]  # OpenCV convention: pixel centres at integers
    (ep / "episode.json").write_text(
        json.dumps({"instruction": "put the cup on the plate", "task": "cup", "fps": 10})
    )
    (ep / "cameras" / "top.json").write_text(
        json.dumps({"height": H, "width": W, "intrinsics": K, "extrinsics": pose(DOWN, TOP_POS)})
    )
    (ep / "cameras" / "wrist.json").write_text(json.dumps({"height": H, "width": W, "intrinsics": K}))
    rng = np.random.default_rng(len(name))
    # UR5-like joints that pause over frames 3-5 and 9 (zero velocity there -> "stopped" keyframes)
    joint_q = np.cumsum([0.0 if t in (3, 4, 5, 9) else 0.2 for t in range(T)])
    lines = []
    for t in range(T):
        for cam in ("top", "wrist"):
            (ep / "rgb" / cam).mkdir(parents=True, exist_ok=True)
            (ep / "depth" / cam).mkdir(parents=True, exist_ok=True)
            rgb = rng.integers(0, 255, (H, W, 3), dtype=np.uint8)
            cv2.imwrite(str(ep / "rgb" / cam / f"{t:06d}.png"), rgb[..., ::-1])
        depth_mm = np.full((H, W), 1000, dtype=np.uint16)  # the table, 1 m below the camera
        depth_mm[8:14, 10:18] = 900  # a 10 cm box
        depth_mm[0, 0] = 0  # one pixel without a measurement
        cv2.imwrite(str(ep / "depth" / "top" / f"{t:06d}.png"), depth_mm)
        p = eef_pos(t)
        np.save(ep / "depth" / "wrist" / f"{t:06d}.npy", np.full((H, W), p[2] + 0.1, dtype=np.float32))
        quat = QUAT if t % 2 else [-q for q in QUAT]  # the same rotation with both signs
        frame = {
            "eef_pos": p.tolist(),
            "eef_quat": quat,
            "gripper_open": int(t < GRIP_CLOSE_AT),
            "gripper_width": 0.085 if t < GRIP_CLOSE_AT else 0.03,
            "extrinsics": {"wrist": pose(DOWN, p + [0, 0, 0.1])},
        }
        if marks and t in (3, 9):
            frame["keyframe"] = True
            frame["ignore_collision"] = t == 3
        if joints:
            frame["joint_positions"] = [float(joint_q[t])] * 6
        lines.append(json.dumps(frame))
    (ep / "frames.jsonl").write_text("\n".join(lines) + "\n")
    return ep


def out_config(out: Path, **kw) -> OutputConfig:
    return OutputConfig(dir=out, dense_video=False, **kw)


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    src = tmp_path_factory.mktemp("raw")
    write_episode(src, "ep_000", marks=True)
    write_episode(src, "ep_001", marks=False, joints=True)
    out = tmp_path_factory.mktemp("raw_out")
    summary = import_raw(RawImportConfig(path=src, output=out_config(out), progress=False))
    return src, out, summary


def test_raw_episodes_pass_validation_and_load(imported):
    _src, out, summary = imported
    assert summary.converted == 2 and not summary.failed, summary.failed
    assert summary.frames == {"dense": 2 * T, "keyframe": summary.frames["keyframe"]}
    for kind in ("dense", "keyframe"):
        report = validate_dataset(ValidateConfig(root=out / kind, frames_per_episode=3))
        assert report.num_errors == 0, report.table()
    ds = LeRobotDataset("local/raw", root=out / "dense", depth_output_unit="m", video_backend="pyav")
    assert ds.meta.total_episodes == 2 and len(ds) == 2 * T
    item = ds[0]
    assert item["task"] == "put the cup on the plate"
    assert item["observation.images.top"].shape == (3, H, W)
    depth = item["observation.images.top_depth"].numpy()[0]
    assert depth[0, 0] == 0.0 and depth[10, 12] == pytest.approx(0.9, abs=1e-6)
    assert depth[20, 30] == pytest.approx(1.0, abs=1e-6)
    K = item["observation.camera.top.intrinsics"].numpy()
    assert K[0, 2] == pytest.approx(W / 2) and K[1, 2] == pytest.approx(
        H / 2
    )  # shifted to sigma's convention
    wrist_E = ds[5]["observation.camera.wrist.extrinsics"].numpy()
    np.testing.assert_allclose(wrist_E[:3, 3], eef_pos(5) + [0, 0, 0.1], atol=1e-6)
    for t in (0, 1):  # stored with w >= 0 whatever the sign in the file
        np.testing.assert_allclose(ds[t]["observation.state"].numpy()[3:7], QUAT, atol=1e-6)
    state = ds[1]["observation.state"].numpy()
    np.testing.assert_allclose(state[8:10], [0.0425, -0.0425], atol=1e-6)
    # The fixed camera's calibration also sits in the feature info; the wrist camera's does not.
    assert "sigma.extrinsics" in ds.meta.features["observation.images.top"]["info"]
    assert "info" not in ds.meta.features["observation.images.wrist"]


def test_raw_import_writes_an_rgb_only_dense_dataset_on_request(tmp_path):
    """``--output.dense_depth=false``: the dense dataset for stock image policies; the keyframe one keeps depth."""
    src = tmp_path / "raw"
    write_episode(src, "ep_000", marks=True)
    summary = import_raw(
        RawImportConfig(path=src, output=out_config(tmp_path / "out", dense_depth=False), progress=False)
    )
    assert summary.converted == 1, summary.failed
    dense = LeRobotDataset("local/raw", root=tmp_path / "out" / "dense", video_backend="pyav")
    assert not any(k.endswith("_depth") for k in dense.meta.features)
    assert dense[0]["observation.images.top"].shape == (3, H, W)
    keyframe = LeRobotDataset("local/raw_kf", root=tmp_path / "out" / "keyframe", video_backend="pyav")
    assert "observation.images.top_depth" in keyframe.meta.features
    report = validate_dataset(ValidateConfig(root=tmp_path / "out" / "dense", frames_per_episode=2))
    assert report.num_errors == 0, report.table()


def test_raw_keyframes_marks_and_heuristic(imported):
    src, _out, _summary = imported
    marked, _ = read_episode(src / "ep_000", ("top",))
    # the two marks, the gripper change and the last frame
    assert marked.keyframe_indices == [3, GRIP_CLOSE_AT, 9, T - 1]
    assert [k.source for k in marked.keyframes] == ["manual", "gripper", "manual", "final"]
    assert marked.keyframes[0].ignore_collision and not marked.keyframes[2].ignore_collision
    assert marked.keyframes[2].gripper_open is False
    # derived dense action: pose deltas in OSC units, grip +1 once the next frame is closed
    np.testing.assert_allclose(marked.actions[0, :3], (eef_pos(1) - eef_pos(0)) / 0.05, atol=1e-5)
    assert marked.actions[GRIP_CLOSE_AT - 1, 6] == 1.0 and marked.actions[0, 6] == -1.0
    heuristic, _ = read_episode(src / "ep_001", ("top",))
    assert all(k.source == "heuristic" for k in heuristic.keyframes)
    assert GRIP_CLOSE_AT in heuristic.keyframe_indices and heuristic.keyframe_indices[-1] == T - 1


def test_raw_bad_episodes_fail_alone(tmp_path):
    src = tmp_path / "src"
    write_episode(src, "a_good")
    missing = write_episode(src, "b_missing_image")
    (missing / "rgb" / "top" / "000004.png").unlink()
    wrong = write_episode(src, "c_wrong_size")
    cv2.imwrite(str(wrong / "depth" / "top" / "000002.png"), np.zeros((H + 1, W), dtype=np.uint16))
    nan = write_episode(src, "d_nan_pose")
    lines = (nan / "frames.jsonl").read_text().splitlines()
    frame3 = json.loads(lines[3])
    frame3["eef_pos"][0] = float("nan")
    lines[3] = json.dumps(frame3)  # Python's json writes NaN
    (nan / "frames.jsonl").write_text("\n".join(lines) + "\n")
    moved = write_episode(
        src, "e_fixed_camera_moved"
    )  # 'top' is fixed, 5 cm away from where it was in a_good
    top = json.loads((moved / "cameras" / "top.json").read_text())
    top["extrinsics"] = pose(DOWN, np.asarray(TOP_POS) + [0.05, 0, 0])
    (moved / "cameras" / "top.json").write_text(json.dumps(top))

    out = tmp_path / "out"
    summary = import_raw(RawImportConfig(path=src, output=out_config(out), progress=False))
    assert summary.converted == 1 and len(summary.failed) == 4
    errors = {Path(f.episode).name: f.error for f in summary.failed}
    assert "b_missing_image" in errors["b_missing_image"] and "000004.png" in errors["b_missing_image"]
    assert "rgb" in errors["b_missing_image"]
    assert "000002.png" in errors["c_wrong_size"] and "25x32" in errors["c_wrong_size"]
    assert "frames.jsonl" in errors["d_nan_pose"] and "eef_pos" in errors["d_nan_pose"]
    assert "row 3" in errors["d_nan_pose"]
    assert "fixed camera 'top' has other calibration" in errors["e_fixed_camera_moved"]
    assert "failed 4" in summary.line()
    # The good episode is written and readable; the report lists the failures.
    ds = LeRobotDataset("local/raw", root=out / "keyframe", depth_output_unit="m", video_backend="pyav")
    assert ds.meta.total_episodes == 1
    report = json.loads((out / REPORT).read_text())
    assert len(report["failed"]) == 4 and report["converted"] == 1
    # An existing dataset is never overwritten by default: the second run stops before touching it.
    with pytest.raises(FileExistsError, match="already exists"):
        import_raw(RawImportConfig(path=src, output=out_config(out), progress=False))
    assert LeRobotDataset("local/raw", root=out / "dense", video_backend="pyav").meta.total_episodes == 1


def test_raw_missing_calibration_and_keyframes_are_named(tmp_path):
    ep = write_episode(tmp_path, "ep", marks=False)
    with pytest.raises(SourceError, match=r"ep/frames\.jsonl: ep: keyframe: no frame is marked"):
        read_episode(ep, ("top",))
    cam = json.loads((ep / "cameras" / "top.json").read_text())
    del cam["intrinsics"]
    (ep / "cameras" / "top.json").write_text(json.dumps(cam))
    lines = (ep / "frames.jsonl").read_text().splitlines()
    lines[2] = json.dumps({**json.loads(lines[2]), "keyframe": True})
    (ep / "frames.jsonl").write_text("\n".join(lines))
    with pytest.raises(SourceError, match=r"top\.json: ep: intrinsics: missing"):
        read_episode(ep, ("top",))


def test_cli_import_raw(tmp_path, capsys):
    write_episode(tmp_path / "src", "ep_000")
    broken = write_episode(tmp_path / "src", "ep_001")
    (broken / "frames.jsonl").unlink()
    out = tmp_path / "out"
    args = [
        "import",
        "raw",
        f"--path={tmp_path / 'src'}",
        f"--output.dir={out}",
        "--output.dense_video=false",
    ]
    assert cli_main([*args, "--progress=false"]) == 1  # one episode failed
    captured = capsys.readouterr()
    assert "import raw: converted 1, failed 1 episodes, dense 12 frames" in captured.out
    assert "ep_001/frames.jsonl: ep_001: missing file" in captured.err
    assert LeRobotDataset("local/raw", root=out / "dense", video_backend="pyav").meta.total_episodes == 1
    assert cli_main(["import", "video", "--path=x"]) == 1
    assert "one of hdf5, raw, teleop" in capsys.readouterr().err


def test_a_failed_write_stops_the_import_and_says_what_each_dataset_holds(tmp_path, monkeypatch):
    """Disk full while writing the keyframe dataset: the import stops (every later episode would fail too), the
    error and import.json give each dataset's episode count, and a dataset left without episodes is removed
    (LeRobot cannot read one) instead of left looking like a dataset."""
    import errno

    from sigma_data.importers import OutputError
    from sigma_data.writers import KeyframeWriter

    src = tmp_path / "src"
    for name in ("a", "b", "c"):
        write_episode(src, name)

    def disk_full(self, episode, views):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(KeyframeWriter, "add_episode", disk_full)
    out = tmp_path / "out"
    with pytest.raises(
        OutputError, match=r"keyframe dataset failed .*No space left.*dense already holds this"
    ):
        import_raw(RawImportConfig(path=src, output=out_config(out), progress=False))
    report = json.loads((out / REPORT).read_text())
    assert report["episodes"] == {"dense": 1, "keyframe": 0} and report["converted"] == 0
    assert report["failed"][-1]["episode"] == "output"
    assert not (out / "keyframe").exists()
    assert LeRobotDataset("local/raw", root=out / "dense", video_backend="pyav").meta.total_episodes == 1
    code = cli_main(["import", "raw", f"--path={src}", f"--output.dir={tmp_path / 'out2'}"])
    assert code == 1
