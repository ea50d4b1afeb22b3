"""The identity probe: the cross-validated logistic regression, and the probe on a real checkpoint and dataset."""

from __future__ import annotations

import json

import numpy as np
import pytest

from benchmarks.bench_identity import IdentityConfig, main, probe_accuracy
from tests.pipelines.checkpoint_fixtures import save_tiny_checkpoint
from tests.sigma_policy.tiny_dataset import write_tiny_keyframe_dataset


def test_probe_reads_separable_labels_and_not_random_ones():
    rng = np.random.default_rng(0)
    labels = np.repeat(["a", "b", "c"], 60)
    groups = np.tile(np.arange(60), 3)  # scene ids: every scene has one object of each label
    centres = {"a": [3, 0, 0, 0], "b": [0, 3, 0, 0], "c": [0, 0, 3, 0]}
    features = np.stack([centres[y] for y in labels]) + rng.normal(size=(180, 4))
    assert probe_accuracy(features, labels, groups, folds=5, l2=1e-2) > 0.9
    shuffled = rng.permutation(labels)
    assert probe_accuracy(features, shuffled, groups, folds=5, l2=1e-2) < 0.55  # chance is 1/3


def test_probe_on_a_checkpoint_reads_each_cube_at_its_own_pixels(tmp_path):
    """The tiny "language" dataset: a red and a blue cube, each episode going to the one its instruction names;
    the sidecar groups the episodes in pairs (three scenes). The rendered pixels at each cube's position tell them
    apart in every scene, which holds only if the probe reads the features where the cube is."""
    root = write_tiny_keyframe_dataset(tmp_path / "lang", episodes=6, size=32, scenes="language")
    from pipelines.keyframe_sets import open_dataset

    ds = open_dataset(root)
    instructions = [ds[int(ds.meta.episodes["dataset_from_index"][e])]["task"] for e in range(6)]
    sidecar = {
        "episodes": [
            {
                "episode_index": e,
                "task": "reach",
                "variation": instructions[e].split()[2],
                "seed": e // 2,
                "instruction": instructions[e],
            }
            for e in range(6)
        ]
    }
    (root / "meta" / "sigma.json").write_text(json.dumps(sidecar))
    save_tiny_checkpoint(root, tmp_path / "ckpt", list(range(6)), 0)
    out = tmp_path / "identity.json"
    report = main(IdentityConfig(checkpoint=tmp_path / "ckpt", task="reach", folds=3, output=out))
    train = report["sets"]["train"]
    assert train["scenes"] == 3 and train["objects"] == 6 and train["variations"] == ["blue", "red"]
    acc = train["accuracy"]
    assert acc["pixels 3x3"]["share"] == 1.0
    stages = {"pixels of its patch, pooled", "patch embedding", "view token", "fused token", "local features"}
    assert stages <= set(acc) and all(0 <= a["share"] <= 1 for a in acc.values())
    assert json.loads(out.read_text())["sets"]["train"]["objects"] == 6
    with pytest.raises(ValueError, match="no scene of task 'lift'"):
        main(IdentityConfig(checkpoint=tmp_path / "ckpt", task="lift", output=out))
