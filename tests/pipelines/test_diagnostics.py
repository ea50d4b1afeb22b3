"""sigma-diagnose: error definitions, and a run's learning curves from real checkpoints on a real LeRobot dataset."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from lerobot.policies.factory import make_pre_post_processors

from pipelines.diagnostics import (
    DiagnoseConfig,
    action_errors,
    goal_rows,
    open_dataset,
    run_diagnose,
    summarise_errors,
)
from sigma_policy.configuration_sigma import SigmaConfig
from sigma_policy.modeling_sigma import SigmaPolicy
from sigma_policy.rotation import euler_xyz_to_quat
from tests.pipelines.viz_fixtures import read_rrd
from tests.sigma_policy.tiny_dataset import BOUNDS, write_tiny_keyframe_dataset


def _action(xyz, euler_deg, grip=1.0, coll=0.0) -> np.ndarray:
    quat = euler_xyz_to_quat(torch.tensor([euler_deg], dtype=torch.float64))[0].numpy()
    return np.array([*xyz, *quat, grip, coll])


def test_action_errors_measure_each_head_in_its_unit():
    true = np.stack([_action([0.1, 0.0, 0.9], [180, 0, 30]), _action([0.0, 0.2, 1.0], [180, 0, -170])])
    pred = np.stack(
        [
            _action([0.1, 0.03, 0.9], [180, 0, 40], grip=0.0),  # 3 cm off, 10 deg of yaw, gripper wrong
            _action([0.0, 0.2, 1.0], [-180, 0, 170], coll=1.0),  # exact pose (angles wrap), collision wrong
        ]
    )
    err = action_errors(pred, true)
    np.testing.assert_allclose(err["trans_cm"], [3.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(err["yaw_deg"], [10.0, 20.0], atol=1e-4)
    np.testing.assert_allclose(err["rot_deg"], [10.0, 20.0], atol=1e-4)
    np.testing.assert_allclose(err["roll_deg"], [0.0, 0.0], atol=1e-4)
    assert err["gripper_ok"].tolist() == [False, True]
    assert err["collision_ok"].tolist() == [True, False]


def test_summaries_count_the_tails_beyond_each_threshold():
    n = 4
    err = {
        "trans_cm": np.array([0.5, 1.5, 2.5, 9.0]),
        "rot_deg": np.array([5.0, 15.0, 25.0, 170.0]),
        **{k: np.zeros(n) for k in ("roll_deg", "pitch_deg", "yaw_deg")},
        "gripper_ok": np.ones(n, bool),
        "collision_ok": np.ones(n, bool),
    }
    s = summarise_errors(err)
    assert (s["within_1cm"], s["within_2cm"], s["within_10deg"], s["within_20deg"]) == (0.25, 0.5, 0.25, 0.5)
    assert summarise_errors({k: v[:0] for k, v in err.items()})["frames"] == 0


def _save_checkpoint(root, out, train_episodes, seed):
    torch.manual_seed(seed)
    cfg = SigmaConfig(
        device="cpu",
        scene_bounds=list(BOUNDS),
        preset="small",
        img_size=32,
        patch_size=8,
        attn_dim=64,
        attn_heads=2,
    )
    ds = open_dataset(root)
    from lerobot.policies.factory import make_policy

    policy = make_policy(cfg, ds_meta=ds.meta)
    pre, post = make_pre_post_processors(cfg, dataset_stats=ds.meta.stats)
    out.mkdir(parents=True)
    for obj in (policy, pre, post):
        obj.save_pretrained(out)
    (out / "train_config.json").write_text(
        json.dumps({"dataset": {"root": str(root), "episodes": train_episodes}})
    )
    return policy


def test_run_curves_on_training_and_held_out_episodes(tmp_path):
    root = write_tiny_keyframe_dataset(tmp_path / "tiny", episodes=4, size=32)
    run = tmp_path / "run"
    for step, seed in ((5, 0), (10, 1)):
        _save_checkpoint(root, run / "checkpoints" / f"{step:06d}" / "pretrained_model", [0, 1, 2], seed)

    report = run_diagnose(DiagnoseConfig(run=run, batch_size=4))

    # Episodes 0-2 were trained on, episode 3 is held out; each episode has 2 frames with a goal.
    assert report["sets"] == {"train": 6, "heldout": 2}
    assert [c["step"] for c in report["checkpoints"]] == [5, 10]
    for c in report["checkpoints"]:
        for name in ("train", "heldout"):
            summary = c[name]["all"]
            assert math.isfinite(summary["trans_cm_median"]) and summary["trans_cm_median"] > 0
            assert 0.0 <= summary["gripper_acc"] <= 1.0
            assert set(c[name]["per_step"]) == {"0", "1"}
    # Different weights, different errors: the numbers come from the checkpoints.
    a, b = (c["train"]["all"]["trans_cm_mean"] for c in report["checkpoints"])
    assert a != b
    out = run / "diagnostics"
    saved = json.loads((out / "diagnostics.json").read_text())
    assert saved["curves"]["steps"] == [5, 10]
    assert (out / "curves.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    rrd = read_rrd(out / "curves.rrd")
    assert rrd.rows["/diagnostics/heldout/trans_cm_median"]["Scalars:scalars"] == 2


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


def test_checkpoint_prediction_matches_select_action(tmp_path):
    """What sigma-diagnose scores is what the policy acts on in closed loop (same pre-processor, same path)."""
    from pipelines.checkpoints import load_policy
    from pipelines.diagnostics import KeyframeSet, predict_rows

    root = write_tiny_keyframe_dataset(tmp_path / "tiny", episodes=1, size=32)
    ckpt = tmp_path / "ckpt"
    _save_checkpoint(root, ckpt, [0], 0)
    policy, pre, _ = load_policy(ckpt)
    ds = open_dataset(root)
    pred, true = predict_rows(policy, pre, KeyframeSet("train", ds, [0, 1], np.array([0, 1])), batch_size=2)
    for i in (0, 1):
        item = ds[i]
        obs = {k: v for k, v in item.items() if k.startswith("observation.") or k == "task"}
        with torch.inference_mode():
            one = policy.select_action(pre(obs))[0].numpy()
        np.testing.assert_allclose(pred[i], one, atol=1e-5)
        np.testing.assert_allclose(true[i], item["action"].numpy())
    assert isinstance(policy, SigmaPolicy)


def test_instruction_swap_on_one_scene_under_two_instructions(tmp_path):
    """The "language" tiny dataset is one scene under two instructions; a sidecar gives both the same seed.
    Episodes 2-3 repeat the pair under a second task name: every task gets its scenes, and the swap is also
    reported per task."""
    from pipelines.checkpoints import load_policy
    from pipelines.diagnostics import (
        KeyframeSet,
        diagnose_checkpoint,
        instruction_swap,
        summary_line,
        swap_scenes,
    )

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
    scenes = swap_scenes(kf, per_task=1)
    assert [s.task for s in scenes] == ["reach", "touch"] and scenes[0].instructions == instructions[:2]
    assert np.linalg.norm(scenes[0].targets[0] - scenes[0].targets[1]) > 0.1  # two different cubes
    _save_checkpoint(root, tmp_path / "ckpt", [0, 1], 0)
    policy, pre, _ = load_policy(tmp_path / "ckpt")
    swap = instruction_swap(policy, pre, kf, scenes)
    assert swap["swap_scenes"] == 2 and swap["swap_nearest"] in (0.0, 0.25, 0.5, 0.75, 1.0)
    assert swap["swap_trans_cm_median"] > 0
    # the same scene twice: both tasks score the same, and their mean is the overall share
    per_task = swap["per_task"]
    spread = swap["swap_spread"]
    assert spread >= 0
    same = {"swap_scenes": 1, "swap_nearest": swap["swap_nearest"], "swap_spread": pytest.approx(spread)}
    assert per_task["reach"] == per_task["touch"] == same
    assert "per_task" not in instruction_swap(policy, pre, kf, scenes[:1])
    kf.swap = scenes
    report = {"checkpoints": [{"step": 5, **diagnose_checkpoint(policy, pre, [kf])}], "sets": {"heldout": 6}}
    line = summary_line(report | {"output_dir": "x"})
    share = f"{100 * swap['swap_nearest']:.0f}%"
    assert f"instruction swap {share} (2 scenes: reach {share}, touch {share})" in line
    assert swap_scenes(KeyframeSet("train", ds, rows, np.asarray(steps), episodes=[0, 2])) == []


def test_swap_spread_compares_how_far_apart_predictions_and_targets_are():
    """The spread's two means: every pair of rows, so three points on a line 1 and 2 apart give (1 + 2 + 3) / 3."""
    from pipelines.diagnostics import _median_or_none, mean_pairwise_distance

    line = np.array([[0.0, 0, 0], [1, 0, 0], [3, 0, 0]])
    assert mean_pairwise_distance(line) == pytest.approx(2.0)
    assert mean_pairwise_distance(line[:1]) == 0.0
    assert _median_or_none([np.nan, 0.5, 1.5, 1.0]) == 1.0 and _median_or_none([np.nan]) is None


def test_errors_per_task_on_a_dataset_that_names_its_tasks(tmp_path):
    """A multi-task dataset's errors split by the task its sidecar records per episode; without one, no split."""
    from pipelines.checkpoints import load_policy
    from pipelines.diagnostics import KeyframeSet, diagnose_checkpoint, summary_line

    root = write_tiny_keyframe_dataset(tmp_path / "tiny", episodes=3, size=32)
    _save_checkpoint(root, tmp_path / "ckpt", [0, 1, 2], 0)
    policy, pre, _ = load_policy(tmp_path / "ckpt")
    ds = open_dataset(root)
    rows, steps = goal_rows(ds)
    kf = KeyframeSet("train", ds, rows, np.asarray(steps))
    assert "per_task" not in diagnose_checkpoint(policy, pre, [kf])["train"]

    tasks = ["reach", "reach", "push"]
    sidecar = {"episodes": [{"episode_index": e, "task": tasks[e], "seed": e} for e in range(3)]}
    (root / "meta" / "sigma.json").write_text(json.dumps(sidecar))
    report = diagnose_checkpoint(policy, pre, [kf])["train"]
    per_task = report["per_task"]
    assert sorted(per_task) == ["push", "reach"]
    assert per_task["reach"]["all"]["frames"] == 4 and per_task["push"]["all"]["frames"] == 2
    assert set(per_task["push"]["per_step"]) == {"0", "1"}
    # The split partitions the frames: the frame-weighted task means are the overall mean.
    mean = sum(v["all"]["trans_cm_mean"] * v["all"]["frames"] for v in per_task.values()) / 6
    assert mean == pytest.approx(report["all"]["trans_cm_mean"])
    line = summary_line(
        {"checkpoints": [{"step": 5, "train": report}], "sets": {"train": 6}, "output_dir": "x"}
    )
    assert "push" in line and "reach" in line
