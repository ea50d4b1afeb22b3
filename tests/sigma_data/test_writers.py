"""Dense and keyframe writers on a stored-image episode, read back with stock LeRobotDataset."""

import json

import numpy as np
import pytest
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from sigma_data.contract import read_sidecar
from sigma_data.dataset_layout import DatasetLayout
from sigma_data.episode import CameraStream, Episode, Keyframe
from sigma_data.writers import DenseWriter, KeyframeWriter

H = W = 32  # SVT-AV1 crashes (SIGFPE) on 16x16 video
T = 12
KEYFRAMES = (4, 8, 11)
CAMS = ("front", "wrist")


def make_episode(seed: int) -> Episode:
    rng = np.random.default_rng(seed)
    states = np.zeros((T, 10), np.float32)
    states[:, 0] = np.linspace(0, 0.11, T)
    states[:, 2] = 1.0
    states[:, 6] = 1.0
    states[:, 7] = [1] * 9 + [0] * 3
    actions = rng.uniform(-1, 1, (T, 7)).astype(np.float32)
    streams = {}
    for c, cam in enumerate(CAMS):
        extr = np.tile(np.eye(4, dtype=np.float32), (T, 1, 1))
        extr[:, 2, 3] = 1.5 + 0.01 * np.arange(T) * c  # the wrist camera moves
        streams[cam] = CameraStream(
            rgb=rng.integers(0, 255, (T, H, W, 3), dtype=np.uint8),
            depth=rng.uniform(0.3, 2.0, (T, H, W)).astype(np.float32),
            intrinsics=np.tile(np.array([[40, 0, 16], [0, 40, 16], [0, 0, 1]], np.float32), (T, 1, 1)),
            extrinsics=extr,
        )
    return Episode(
        task="lift",
        variation="lift_cube",
        instruction=f"instruction {seed}",
        states=states,
        actions=actions,
        keyframes=[Keyframe(4, True, False), Keyframe(8, False, True), Keyframe(11, False, False, "final")],
        images=streams,
        seed=seed,
    )


def stored(ep: Episode):
    requested = []

    def views(t: int):
        requested.append(t)
        return {cam: s.frame(t) for cam, s in ep.images.items()}

    return views, requested


def test_dense_and_keyframe_round_trip(tmp_path):
    layout = DatasetLayout(CAMS, H, W)
    static = {"front": (np.eye(3), np.eye(4))}
    eps = [make_episode(0), make_episode(1)]
    with (
        DenseWriter(
            tmp_path / "dense", layout, static_calibration=static, provenance={"source": "test"}
        ) as dense,
        KeyframeWriter(tmp_path / "kf", layout, augment_every=5) as kf,
    ):
        for ep in eps:
            views, requested = stored(ep)
            assert dense.add_episode(ep, views) == 1
            views, requested = stored(ep)
            assert kf.frame_indices(ep) == [0, 4, 5, 8, 10, 11]
            assert kf.add_episode(ep, views) == 3  # chains from 0, 5, 10
            assert sorted(set(requested)) == [0, 4, 5, 8, 10, 11]  # only decision frames are rendered

    ds = LeRobotDataset("local/dense", root=tmp_path / "dense", depth_output_unit="m", video_backend="pyav")
    assert ds.meta.total_episodes == 2 and len(ds) == 2 * T
    assert ds.meta.features["observation.images.front_depth"]["info"]["is_depth_map"]
    assert ds.meta.features["observation.images.front"]["info"]["sigma.extrinsics"] == np.eye(4).tolist()
    cols = ds.hf_dataset.with_format(None).select_columns(
        ["action", "sigma.is_keyframe", "sigma.next_keyframe_index"]
    )[:T]
    np.testing.assert_allclose(np.array(cols["action"]), eps[0].actions, atol=1e-7)
    assert np.flatnonzero(np.array(cols["sigma.is_keyframe"]).ravel()).tolist() == list(KEYFRAMES)
    assert np.array(cols["sigma.next_keyframe_index"]).ravel().tolist() == [4] * 4 + [8] * 4 + [11] * 4
    item = ds[T + 5]  # episode 1, frame 5
    assert item["task"] == "instruction 1"
    depth_err = np.abs(item["observation.images.wrist_depth"].numpy()[0] - eps[1].images["wrist"].depth[5])
    assert depth_err.max() < 2e-3  # 12-bit log-quantised video depth
    np.testing.assert_allclose(
        item["observation.camera.wrist.extrinsics"].numpy(), eps[1].images["wrist"].extrinsics[5]
    )

    kds = LeRobotDataset("local/kf", root=tmp_path / "kf", depth_output_unit="m", video_backend="pyav")
    assert kds.meta.total_episodes == 6
    first = [kds[i] for i in range(4)]  # episode 0 = chain from frame 0: frames 0, 4, 8, 11
    assert [int(x["sigma.source_frame"]) for x in first] == [0, 4, 8, 11]
    poses = eps[0].keyframe_poses()
    np.testing.assert_allclose(np.stack([x["action"].numpy() for x in first]), poses[[0, 1, 2, 2]], atol=1e-7)
    for i in range(3):  # the goal of frame i is frame i+1
        np.testing.assert_allclose(
            first[i]["action"][:3].numpy(), first[i + 1]["observation.state"][:3].numpy()
        )
    # image depth is exact, RGB lossless
    np.testing.assert_array_equal(
        first[1]["observation.images.front_depth"].numpy()[0], eps[0].images["front"].depth[4]
    )
    np.testing.assert_array_equal(
        (first[1]["observation.images.front"].numpy() * 255).round().astype(np.uint8).transpose(1, 2, 0),
        eps[0].images["front"].rgb[4],
    )

    side = read_sidecar(tmp_path / "kf")
    assert side["kind"] == "keyframe" and side["num_episodes"] == 6 and side["augment_every"] == 5
    assert [e["chain_start"] for e in side["episodes"][:3]] == [0, 5, 10]
    assert side["episodes"][1]["source_frames"] == [5, 8, 11]
    assert side["conventions"]["quaternion"].startswith("xyzw, unit; keyframe actions w >= 0")
    assert {"robosuite", "mujoco", "lerobot", "sigma"} <= set(side)
    assert read_sidecar(tmp_path / "dense")["source"] == "test"


def test_rgb_only_dense_dataset_is_what_stock_image_policies_take(tmp_path):
    """``DatasetLayout(depth=False)``: no depth feature, calibration kept, every visual feature 3-channel."""
    from lerobot.configs.types import FeatureType
    from lerobot.utils.feature_utils import dataset_to_policy_features

    ep = make_episode(0)
    with DenseWriter(tmp_path / "rgb", DatasetLayout(CAMS, H, W, depth=False)) as dense:
        dense.add_episode(ep, stored(ep)[0])
    ds = LeRobotDataset("local/rgb", root=tmp_path / "rgb", video_backend="pyav")
    visual = {
        k: f for k, f in dataset_to_policy_features(ds.meta.features).items() if f.type is FeatureType.VISUAL
    }
    assert sorted(visual) == [f"observation.images.{c}" for c in sorted(CAMS)]
    assert all(f.shape == (3, H, W) for f in visual.values())
    assert ds[3]["observation.camera.wrist.extrinsics"].shape == (4, 4)
    assert read_sidecar(tmp_path / "rgb")["depth"] is False


def test_error_mid_episode_keeps_earlier_episodes_readable(tmp_path):
    layout = DatasetLayout(CAMS, H, W)
    good, bad = make_episode(0), make_episode(1)

    def failing(t):
        if t == 6:
            raise RuntimeError("renderer died")
        return {cam: s.frame(t) for cam, s in bad.images.items()}

    with pytest.raises(RuntimeError, match="renderer died"), KeyframeWriter(tmp_path / "kf", layout) as kf:
        kf.add_episode(good, stored(good)[0])
        kf.add_episode(bad, lambda t: failing(t if t < 8 else 6))
    ds = LeRobotDataset("local/kf", root=tmp_path / "kf", video_backend="pyav")
    assert ds.meta.total_episodes == 1 and len(ds) == 4
    assert json.loads((tmp_path / "kf" / "meta" / "sigma.json").read_text())["num_episodes"] == 1


def test_bad_input_is_named(tmp_path):
    layout = DatasetLayout(("front", "missing"), H, W)
    ep = make_episode(0)
    with KeyframeWriter(tmp_path / "kf", layout) as kf, pytest.raises(KeyError, match="camera 'missing'"):
        kf.add_episode(ep, stored(ep)[0])
    with pytest.raises(FileExistsError):
        KeyframeWriter(tmp_path / "kf", layout)


def test_fast_fingerprints_write_the_same_data_and_stay_deterministic(tmp_path, monkeypatch):
    """The writers save episodes under ``fast_fingerprints``: same Parquet contents as stock LeRobot, and the same
    fingerprint string when the same episodes are written to the same place again."""
    import contextlib
    import shutil

    import pyarrow.parquet as pq

    from sigma_data import writers

    layout = DatasetLayout(CAMS, H, W)

    def write(root, fast: bool):
        with monkeypatch.context() as patch:
            if not fast:
                patch.setattr(writers, "fast_fingerprints", contextlib.nullcontext)
            with KeyframeWriter(root, layout) as w:
                for seed in (0, 1):
                    ep = make_episode(seed)
                    w.add_episode(ep, stored(ep)[0])
        (table_file,) = sorted((root / "data").rglob("*.parquet"))
        table = pq.read_table(table_file)
        return table, json.loads(table.schema.metadata[b"huggingface"])["fingerprint"]

    root = tmp_path / "kf"
    fast, fingerprint = write(root, fast=True)
    shutil.rmtree(root)
    again, fingerprint_again = write(root, fast=True)
    shutil.rmtree(root)
    stock, stock_fingerprint = write(root, fast=False)
    assert fast.equals(again) and fingerprint == fingerprint_again
    assert fast.equals(stock) and fingerprint != stock_fingerprint  # only the hash function differs


def test_slow_video_encoders_drop_no_frames(tmp_path, monkeypatch):
    """LeRobot drops a frame when an encoder queue stays full (30 frames) for 0.1 s; the writer waits for its
    encoders instead, so every video has as many frames as its episode even when encoding is far slower."""
    import time

    import av
    from lerobot.datasets import video_utils

    quantize = video_utils.quantize_depth

    def slow_quantize(*args, **kwargs):
        time.sleep(0.12)  # longer than the 0.1 s LeRobot waits on a full queue before it drops the frame
        return quantize(*args, **kwargs)

    monkeypatch.setattr(video_utils, "quantize_depth", slow_quantize)
    n = 48  # > LeRobot's default queue of 30 frames
    short = make_episode(0)
    cam = short.images["front"]
    ep = Episode(
        task="lift",
        variation="lift_cube",
        instruction="long",
        states=np.resize(short.states, (n, short.states.shape[1])),
        actions=np.resize(short.actions, (n, short.actions.shape[1])),
        keyframes=[Keyframe(n - 1, False, False, "final")],
        images={
            "front": CameraStream(
                *(
                    np.resize(a, (n, *a.shape[1:]))
                    for a in (cam.rgb, cam.depth, cam.intrinsics, cam.extrinsics)
                )
            )
        },
    )
    with DenseWriter(tmp_path / "dense", DatasetLayout(("front",), H, W)) as dense:
        views, _ = stored(ep)
        dense.add_episode(ep, views)
    ds = LeRobotDataset("local/dense", root=tmp_path / "dense", depth_output_unit="m", video_backend="pyav")
    for key in ("observation.images.front", "observation.images.front_depth"):
        with av.open(str(ds.root / ds.meta.get_video_file_path(0, key))) as video:
            assert sum(1 for _ in video.decode(video=0)) == n, key
