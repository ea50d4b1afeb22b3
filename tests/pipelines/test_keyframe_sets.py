"""``pipelines/keyframe_sets.py``: which keyframes a checkpoint is scored on, and the data a score is keyed by."""

from __future__ import annotations

import json

import pytest

from pipelines.keyframe_sets import goal_rows, keyframe_sets, open_dataset, scored_data
from tests.pipelines.checkpoint_fixtures import save_tiny_checkpoint
from tests.sigma_policy.tiny_dataset import write_tiny_keyframe_dataset


def test_goal_rows_skip_each_episodes_last_frame(tmp_path):
    root = write_tiny_keyframe_dataset(tmp_path / "tiny", episodes=3, size=32)
    ds = open_dataset(root)
    rows, steps = goal_rows(ds)
    assert len(rows) == ds.num_frames - ds.num_episodes
    assert steps == [0, 1] * 3
    assert goal_rows(ds, [1])[0] == [3, 4]
    assert len(goal_rows(ds, max_frames=4)[0]) == 4


def test_a_missing_dataset_is_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="not a LeRobot dataset"):
        open_dataset(tmp_path / "nowhere")


def test_the_held_out_set_is_the_other_dataset_or_the_episodes_not_trained_on(tmp_path):
    root = write_tiny_keyframe_dataset(tmp_path / "tiny", episodes=4, size=32)
    heldout = write_tiny_keyframe_dataset(tmp_path / "heldout", episodes=2, size=32, seed=1)
    ckpt = tmp_path / "ckpt"
    save_tiny_checkpoint(root, ckpt, [0, 1, 2], 0)

    train, rest = keyframe_sets(ckpt)  # the dataset train_config.json names, episode 3 held out
    assert (train.episodes, len(train.indices), rest.episodes, len(rest.indices)) == ([0, 1, 2], 6, [3], 2)
    assert train.steps.tolist() == [0, 1] * 3
    train, other = keyframe_sets(ckpt, heldout_root=heldout, max_frames=3)
    assert (len(train.indices), other.episodes, len(other.indices)) == (3, None, 3)  # 4 goal frames, thinned
    assert str(other.dataset.root) == str(heldout)

    data = scored_data(ckpt, heldout_root=heldout)
    assert (data["root"], data["episodes"]) == (str(root), [0, 1, 2])
    assert data["meta_sha256"] != data["heldout_meta_sha256"]
    assert scored_data(ckpt, root=heldout)["meta_sha256"] == data["heldout_meta_sha256"]

    config = json.loads((ckpt / "train_config.json").read_text())
    config["dataset"]["root"] = None
    (ckpt / "train_config.json").write_text(json.dumps(config))
    with pytest.raises(ValueError, match="names no dataset root"):
        keyframe_sets(ckpt)
