"""Episode viewer: write real LeRobot datasets, log episodes to .rrd, read them back with Rerun's reader."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pipelines.viz.cli import main
from pipelines.viz.episode_tracks import load_episode_dataset
from sigma_data.contract import dataset_kind
from tests.pipelines import viz_fixtures as fx

POINT_BUDGET = 300  # below the 2 x 24 x 32 valid pixels per frame, so subsampling is exercised
CAMERA_ENTITIES = {f"/world/cameras/{cam}" for cam in fx.CAMERAS}


@pytest.fixture(scope="module")
def dense(tmp_path_factory) -> fx.FixtureDataset:
    return fx.write_dense_dataset(tmp_path_factory.mktemp("viz") / "dense", write_sidecar=True)


@pytest.fixture(scope="module")
def keyframe(tmp_path_factory) -> fx.FixtureDataset:
    return fx.write_keyframe_dataset(tmp_path_factory.mktemp("viz") / "keyframe", write_sidecar=False)


def _view(dataset: fx.FixtureDataset, episode: int, out: Path, *extra: str) -> fx.RrdContents:
    main(
        [
            "episode",
            "--root",
            str(dataset.root),
            "--episode-index",
            str(episode),
            "--save",
            str(out),
            "--log.point_budget",
            str(POINT_BUDGET),
            *extra,
        ]
    )
    return fx.read_rrd(out)


def _translations(contents: fx.RrdContents, entity: str) -> np.ndarray:
    return np.array([row[0] for row in contents.values[entity]["Transform3D:translation"]])


def test_dense_episode_entities_counts_and_timelines(dense, tmp_path):
    episode = 1
    n = dense.episode_lengths[episode]
    contents = _view(dense, episode, tmp_path / "dense.rrd")

    assert contents.num_recordings == 1
    assert contents.num_blueprints == 1  # the default layout travels in the file
    assert contents.entities_under("/world/cameras/") >= CAMERA_ENTITIES
    for cam in CAMERA_ENTITIES:
        rows = contents.rows[cam]
        assert rows["Transform3D:translation"] == n
        assert rows["Pinhole:image_from_camera"] == n
        assert rows["Pinhole:camera_xyz"] == n
        assert contents.rows[f"{cam}/rgb"]["EncodedImage:blob"] == n  # JPEG-compressed
        assert contents.rows[f"{cam}/depth"]["DepthImage:buffer"] == n
        assert contents.values[f"{cam}/depth"]["DepthImage:meter"][0] == [pytest.approx(1.0)]

    keyframes = {e for e in contents.entities_under("/world/keyframes/") if not e.endswith("/label")}
    assert len(keyframes) == dense.keyframes_per_episode
    assert all("TransformAxes3D:axis_length" in contents.static[e] for e in keyframes)
    labels = [contents.values[f"{e}/label"]["Points3D:labels"][0][0] for e in sorted(keyframes)]
    assert labels[0].endswith("open") and labels[-1].endswith("closed")  # the fixture grasps at frame 7

    clouds = contents.values["/world/point_cloud"]["Points3D:positions"]
    assert len(clouds) == n
    assert all(len(c) == POINT_BUDGET for c in clouds)
    assert contents.rows["/world/goal_link"]["Arrows3D:vectors"] == n
    assert len(contents.values["/world/eef_trajectory"]["LineStrips3D:strips"][0][0]) == n

    timelines = contents.timeline_rows["/world/point_cloud"]
    assert timelines["frame_index"] == n and timelines["time"] == n
    assert timelines["keyframe"] == 1 + dense.keyframes_per_episode  # start frame + keyframes
    assert len(contents.entities_under("/timeseries/state/")) == len(fx.STATE_NAMES)
    assert len(contents.entities_under("/timeseries/action/")) == len(fx.DENSE_ACTION_NAMES)
    assert contents.rows["/timeseries/state/eef_x"]["Scalars:scalars"] == n
    text = contents.values["/instruction"]["TextDocument:text"][0][0]
    assert fx.TASK in text and "dense" in text


def test_dense_goals_follow_next_keyframe_index(dense, tmp_path):
    contents = _view(dense, 0, tmp_path / "dense0.rrd")
    ds = load_episode_dataset(dense.root, 0)
    table = ds.hf_dataset.with_format(None).select_columns(
        ["observation.state", "sigma.next_keyframe_index"]
    )[:]
    state = np.asarray(table["observation.state"])
    nxt = np.asarray(table["sigma.next_keyframe_index"]).reshape(-1)
    goals = _translations(contents, "/world/goal")
    np.testing.assert_allclose(goals, state[nxt, :3], atol=1e-6)
    eef = _translations(contents, "/world/eef")
    arrows = contents.values["/world/goal_link"]
    np.testing.assert_allclose(np.array([r[0] for r in arrows["Arrows3D:origins"]]), eef, atol=1e-6)
    np.testing.assert_allclose(np.array([r[0] for r in arrows["Arrows3D:vectors"]]), goals - eef, atol=1e-6)


def test_keyframe_dataset_detected_from_action_dim(keyframe, tmp_path):
    assert not (keyframe.root / "meta" / "sigma.json").exists()
    n = keyframe.episode_lengths[0]
    contents = _view(keyframe, 0, tmp_path / "kf.rrd", "--log.compress_depth", "true")
    text = contents.values["/instruction"]["TextDocument:text"][0][0]
    assert "keyframe" in text
    keyframes = {e for e in contents.entities_under("/world/keyframes/") if not e.endswith("/label")}
    assert len(keyframes) == n - 1  # every frame after the start is a decision point
    assert contents.timeline_rows["/world/eef"]["keyframe"] == n
    # The goal of frame i is frame i+1's pose; the last frame is its own goal.
    eef = _translations(contents, "/world/eef")
    goals = _translations(contents, "/world/goal")
    np.testing.assert_allclose(goals[:-1], eef[1:], atol=1e-6)
    np.testing.assert_allclose(goals[-1], eef[-1], atol=1e-6)
    assert len(contents.entities_under("/timeseries/action/")) == len(fx.KEYFRAME_ACTION_NAMES)
    depth = contents.rows[f"/world/cameras/{fx.CAMERAS[0]}/depth"]
    assert depth["EncodedDepthImage:blob"] == n and "DepthImage:buffer" not in depth  # 16-bit mm PNG


def test_fused_cloud_lies_on_the_scene(dense, tmp_path):
    """K/E conventions end to end: every logged cloud point is on the table or the cube."""
    contents = _view(dense, 0, tmp_path / "geom.rrd")
    points = np.concatenate(
        [np.asarray(c) for c in contents.values["/world/point_cloud"]["Points3D:positions"]]
    )
    on = fx.on_scene_surface(points)
    assert on.mean() == 1.0, f"{(~on).sum()} of {len(points)} points off the scene, e.g. {points[~on][:3]}"
    rel = np.abs(points - fx.CUBE_CENTER).max(axis=1)
    assert (rel < fx.CUBE_HALF + 2e-3).sum() > 50  # the cube is seen, not only the table


def test_kind_detection_errors(tmp_path):
    feats = {"action": {"dtype": "float32", "shape": (5,), "names": None}}
    with pytest.raises(ValueError, match="'action' has 5 dims"):
        dataset_kind(tmp_path, feats)
    (tmp_path / "meta").mkdir()
    (tmp_path / "meta" / "sigma.json").write_text(json.dumps({"kind": "sparse"}))
    with pytest.raises(ValueError, match=r"sigma\.json: field 'kind'"):
        dataset_kind(tmp_path, feats)
