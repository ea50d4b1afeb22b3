"""The gripper swap: frame pairs where the gripper closes in place, and how far their swapped gripper state moves
the prediction, on a real LeRobot dataset with a policy that reads the state, one that ignores it, and a real
checkpoint."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from pipelines.keyframe_sets import goal_rows, open_dataset
from sigma_data.contract import GRIPPER_OPEN_INDEX, STATE
from tests.pipelines.checkpoint_fixtures import save_tiny_checkpoint
from tests.sigma_policy.tiny_dataset import LIFT_M, write_tiny_keyframe_dataset


class StagePolicy:
    """Predicts the next keyframe from ``observation.state`` alone: in place while the gripper is open, lifted
    once it is closed (``reads_gripper``), or always in place (the gripper ignored)."""

    def __init__(self, reads_gripper: bool):
        self.reads_gripper = reads_gripper

    def predict(self, batch):
        state = batch[STATE]
        action = torch.zeros(len(state), 9)
        action[:, :3] = state[:, :3]
        if self.reads_gripper:
            action[:, 2] += LIFT_M * (1 - state[:, GRIPPER_OPEN_INDEX])
        return SimpleNamespace(action=action)


@pytest.fixture(scope="module")
def grasp_lift(tmp_path_factory):
    """Three episodes of home -> above -> at the cube open -> closed in place -> lifted."""
    root = write_tiny_keyframe_dataset(
        tmp_path_factory.mktemp("gl") / "ds", episodes=3, size=32, plan="grasp_lift"
    )
    return open_dataset(root)


def test_gripper_pairs_are_the_in_place_closes(grasp_lift):
    """One pair per episode, its frames 2 (open at the cube) and 3 (closed there); none across episodes; the cap
    per task holds; a set whose rows lack the frame after the close has none."""
    from pipelines.gripper_swap import gripper_pairs

    rows, _ = goal_rows(grasp_lift)
    starts = [int(s) for s in grasp_lift.meta.episodes["dataset_from_index"]]
    pairs = gripper_pairs(grasp_lift, rows, ["reach"] * len(rows))
    assert [p.rows for p in pairs] == [(s + 2, s + 3) for s in starts]
    assert len(gripper_pairs(grasp_lift, rows, ["reach"] * len(rows), per_task=2)) == 2
    without = [r for r in rows if r - starts[0] != 3]
    assert len(gripper_pairs(grasp_lift, without, ["reach"] * len(without))) == 2


def test_gripper_swap_tells_a_policy_that_reads_the_state_from_one_that_does_not(grasp_lift):
    """Reading the state, every swapped prediction lands at the other frame's target, as far as the targets are
    apart (follow 1, spread 1); ignoring it, nothing moves (spread 0) and only the frame whose own target is the
    ignored policy's answer counts as followed (follow 0.5). Pairs of two tasks are also reported per task."""
    from pipelines.gripper_swap import gripper_pairs, gripper_swap

    rows, _ = goal_rows(grasp_lift)
    tasks = ["lift" if r < 5 else "stack" for r in rows]
    pairs = gripper_pairs(grasp_lift, rows, tasks)

    def identity(batch):
        return batch

    reads = gripper_swap(StagePolicy(True), identity, grasp_lift, pairs)
    assert reads["gripper_swap_pairs"] == 3
    assert reads["gripper_swap_follow"] == 1.0 and reads["gripper_swap_spread"] == pytest.approx(
        1.0, abs=1e-5
    )
    assert reads["per_task"]["lift"]["gripper_swap_pairs"] == 1
    assert reads["per_task"]["stack"] == {
        "gripper_swap_pairs": 2,
        "gripper_swap_follow": 1.0,
        "gripper_swap_spread": pytest.approx(1.0, abs=1e-5),
    }
    ignores = gripper_swap(StagePolicy(False), identity, grasp_lift, pairs)
    assert ignores["gripper_swap_follow"] == 0.5 and ignores["gripper_swap_spread"] == 0.0
    assert gripper_swap(StagePolicy(True), identity, grasp_lift, []) == {}


def test_sigma_diagnose_reports_the_gripper_swap(grasp_lift, tmp_path):
    """A real (untrained) checkpoint through ``diagnose_checkpoint``: the report and the summary line carry it."""
    from pipelines.checkpoints import load_policy
    from pipelines.diagnostics import diagnose_checkpoint, summary_line
    from pipelines.gripper_swap import gripper_pairs
    from pipelines.keyframe_sets import KeyframeSet

    rows, steps = goal_rows(grasp_lift)
    kf = KeyframeSet("train", grasp_lift, rows, np.asarray(steps))
    kf.gripper = gripper_pairs(grasp_lift, rows, ["reach"] * len(rows))
    save_tiny_checkpoint(grasp_lift.root, tmp_path / "ckpt", [0, 1, 2], 0)
    policy, pre, _ = load_policy(tmp_path / "ckpt")
    out = diagnose_checkpoint(policy, pre, [kf])
    grip = out["train"]["gripper_swap"]
    assert grip["gripper_swap_pairs"] == 3 and 0.0 <= grip["gripper_swap_follow"] <= 1.0
    assert grip["gripper_swap_spread"] >= 0.0 and "per_task" not in grip
    report = {"checkpoints": [{"step": 5, **out}], "sets": {"train": len(rows)}, "output_dir": "x"}
    assert f"gripper swap {100 * grip['gripper_swap_follow']:.0f}% (3 pairs)" in summary_line(report)
