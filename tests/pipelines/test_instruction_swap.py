"""The instruction swap: scenes recorded under several instructions, and how far the instruction moves the
prediction, from a real checkpoint on a real LeRobot dataset."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pipelines.keyframe_sets import goal_rows, open_dataset
from tests.pipelines.checkpoint_fixtures import save_tiny_checkpoint
from tests.sigma_policy.tiny_dataset import write_tiny_keyframe_dataset


def test_instruction_swap_on_one_scene_under_two_instructions(tmp_path):
    """The "language" tiny dataset is one scene under two instructions; a sidecar gives both the same seed.
    Episodes 2-3 repeat the pair under a second task name: every task gets its scenes, and the swap is also
    reported per task."""
    from pipelines.checkpoints import load_policy
    from pipelines.diagnostics import diagnose_checkpoint, summary_line
    from pipelines.instruction_swap import instruction_swap, swap_scenes
    from pipelines.keyframe_sets import KeyframeSet

    root = write_tiny_keyframe_dataset(tmp_path / "lang", episodes=4, size=32, scenes="language")
    ds = open_dataset(root)
    instructions = [ds[int(ds.meta.episodes["dataset_from_index"][e])]["task"] for e in range(4)]
    assert instructions[:2] == instructions[2:] and instructions[0] != instructions[1]
    sidecar = {
        "episodes": [
            {
                "episode_index": e,
                "task": "reach" if e < 2 else "touch",
                "seed": 3,
                "instruction": instructions[e],
            }
            for e in range(4)
        ]
    }
    (root / "meta" / "sigma.json").write_text(json.dumps(sidecar))
    rows, steps = goal_rows(ds)
    kf = KeyframeSet("heldout", ds, rows, np.asarray(steps))
    scenes = swap_scenes(ds, per_task=1)
    assert [s.task for s in scenes] == ["reach", "touch"] and scenes[0].instructions == instructions[:2]
    assert np.linalg.norm(scenes[0].targets[0] - scenes[0].targets[1]) > 0.1  # two different cubes
    save_tiny_checkpoint(root, tmp_path / "ckpt", [0, 1], 0)
    policy, pre, _ = load_policy(tmp_path / "ckpt")
    swap = instruction_swap(policy, pre, ds, scenes)
    assert swap["swap_scenes"] == 2 and swap["swap_nearest"] in (0.0, 0.25, 0.5, 0.75, 1.0)
    assert swap["swap_trans_cm_median"] > 0
    # where each instruction took the policy: one count per scene and instruction, the hits on the diagonal
    went_to = swap["swap_went_to"]
    assert sorted(went_to) == sorted(set(scenes[0].variations)) and len(went_to) == 2
    assert sum(sum(c.values()) for c in went_to.values()) == 4
    assert sum(c.get(v, 0) for v, c in went_to.items()) == 4 * swap["swap_nearest"]
    # the same scene twice: both tasks score the same, and their mean is the overall share
    per_task = swap["per_task"]
    spread = swap["swap_spread"]
    assert spread >= 0
    same = {"swap_scenes": 1, "swap_nearest": swap["swap_nearest"], "swap_spread": pytest.approx(spread)}
    assert per_task["reach"] == per_task["touch"] == same
    assert "per_task" not in instruction_swap(policy, pre, ds, scenes[:1])
    kf.swap = scenes
    report = {"checkpoints": [{"step": 5, **diagnose_checkpoint(policy, pre, [kf])}], "sets": {"heldout": 6}}
    line = summary_line(report | {"output_dir": "x"})
    share = f"{100 * swap['swap_nearest']:.0f}%"
    assert f"instruction swap {share} (2 scenes: reach {share}, touch {share})" in line
    assert swap_scenes(ds, episodes=[0, 2]) == []


def test_swap_spread_compares_how_far_apart_predictions_and_targets_are():
    """The spread's two means: every pair of rows, so three points on a line 1 and 2 apart give (1 + 2 + 3) / 3."""
    from pipelines.instruction_swap import _median_or_none, mean_pairwise_distance

    line = np.array([[0.0, 0, 0], [1, 0, 0], [3, 0, 0]])
    assert mean_pairwise_distance(line) == pytest.approx(2.0)
    assert mean_pairwise_distance(line[:1]) == 0.0
    assert _median_or_none([np.nan, 0.5, 1.5, 1.0]) == 1.0 and _median_or_none([np.nan]) is None
