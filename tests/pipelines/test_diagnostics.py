"""sigma-diagnose: error definitions, and a run's learning curves from real checkpoints on a real LeRobot dataset."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from pipelines.diagnostics import DiagnoseConfig, run_diagnose, scoring_options
from pipelines.keyframe_errors import action_errors, summarise_errors
from pipelines.keyframe_sets import goal_rows, open_dataset
from sigma_policy.modeling_sigma import SigmaPolicy
from sigma_policy.rotation import euler_xyz_to_quat
from tests.pipelines.checkpoint_fixtures import save_tiny_checkpoint
from tests.pipelines.viz_fixtures import read_rrd
from tests.sigma_policy.tiny_dataset import write_tiny_keyframe_dataset


def _action(xyz, euler_deg, grip=1.0, coll=0.0) -> np.ndarray:
    quat = euler_xyz_to_quat(torch.tensor([euler_deg], dtype=torch.float64))[0].numpy()
    return np.array([*xyz, *quat, grip, coll])


def test_action_errors_measure_each_head_in_its_unit():
    true = np.stack(
        [
            _action([0.1, 0.0, 0.9], [180, 0, 30]),
            _action([0.0, 0.2, 1.0], [180, 0, -170]),
            _action([0.0, 0.2, 1.0], [180, 0, 80]),
        ]
    )
    pred = np.stack(
        [
            # 3 cm off, 10 deg of yaw, gripper wrong
            _action([0.1, 0.03, 0.9], [180, 0, 40], grip=0.0),
            # 20 deg of yaw (angles wrap), collision wrong
            _action([0.0, 0.2, 1.0], [-180, 0, 170], coll=1.0),
            # the same grasp axis, the other wrist side: 175 deg of yaw, 5 modulo a half turn
            _action([0.0, 0.2, 1.0], [180, 0, -95]),
        ]
    )
    err = action_errors(pred, true)
    np.testing.assert_allclose(err["trans_cm"], [3.0, 0.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(err["yaw_deg"], [10.0, 20.0, 175.0], atol=1e-4)
    np.testing.assert_allclose(err["yaw_half_turn_deg"], [10.0, 20.0, 5.0], atol=1e-4)
    np.testing.assert_allclose(err["rot_deg"], [10.0, 20.0, 175.0], atol=1e-4)
    np.testing.assert_allclose(err["roll_deg"], [0.0, 0.0, 0.0], atol=1e-4)
    assert err["gripper_ok"].tolist() == [False, True, True]
    assert err["collision_ok"].tolist() == [True, False, True]


def test_summaries_count_the_tails_beyond_each_threshold():
    n = 4
    err = {
        "trans_cm": np.array([0.5, 1.5, 2.5, 9.0]),
        "rot_deg": np.array([5.0, 15.0, 25.0, 170.0]),
        **{k: np.zeros(n) for k in ("roll_deg", "pitch_deg", "yaw_deg", "yaw_half_turn_deg")},
        "gripper_ok": np.ones(n, bool),
        "collision_ok": np.ones(n, bool),
    }
    s = summarise_errors(err)
    assert (s["within_1cm"], s["within_2cm"], s["within_10deg"], s["within_20deg"]) == (0.25, 0.5, 0.25, 0.5)
    assert summarise_errors({k: v[:0] for k, v in err.items()})["frames"] == 0


def test_run_curves_on_training_and_held_out_episodes(tmp_path):
    root = write_tiny_keyframe_dataset(tmp_path / "tiny", episodes=4, size=32)
    run = tmp_path / "run"
    for step, seed in ((5, 0), (10, 1)):
        save_tiny_checkpoint(root, run / "checkpoints" / f"{step:06d}" / "pretrained_model", [0, 1, 2], seed)

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


def mark_first_saved_score(path):
    """Mark the first checkpoint's saved score in the report at ``path``: a kept entry keeps the mark (-1 cm), a
    rescored one loses it."""
    saved = json.loads(path.read_text())
    saved["checkpoints"][0]["train"]["all"]["trans_cm_mean"] = -1.0
    path.write_text(json.dumps(saved))


def test_a_rerun_scores_only_checkpoints_it_has_not_scored_alike(tmp_path):
    """Scores are kept for the same weights (by content) and options, and redone for anything else."""
    import shutil

    root = write_tiny_keyframe_dataset(tmp_path / "tiny", episodes=4, size=32)
    run = tmp_path / "run"
    save_tiny_checkpoint(root, run / "checkpoints" / "000005" / "pretrained_model", [0, 1, 2], 0)
    report = run_diagnose(DiagnoseConfig(run=run, batch_size=4))
    saved_path = run / "diagnostics" / "diagnostics.json"
    first = report["checkpoints"][0]["train"]["all"]["trans_cm_mean"]

    def score_of(report, step):
        return next(c for c in report["checkpoints"] if c["step"] == step)["train"]["all"]["trans_cm_mean"]

    mark_first_saved_score(saved_path)  # step 5
    save_tiny_checkpoint(root, run / "checkpoints" / "000010" / "pretrained_model", [0, 1, 2], 1)
    report = run_diagnose(DiagnoseConfig(run=run, batch_size=4))
    assert score_of(report, 5) == -1.0  # kept
    assert math.isfinite(score_of(report, 10)) and score_of(report, 10) > 0  # scored
    assert report["curves"]["steps"] == [5, 10] and report["sets"] == {"train": 6, "heldout": 2}
    assert json.loads(saved_path.read_text())["curves"]["steps"] == [5, 10]

    # Other scoring options, or --reuse false: scored again.
    report = run_diagnose(DiagnoseConfig(run=run, batch_size=4, max_frames=5))
    assert score_of(report, 5) > 0
    mark_first_saved_score(saved_path)  # step 5
    assert score_of(run_diagnose(DiagnoseConfig(run=run, batch_size=4, max_frames=5)), 5) == -1.0
    assert score_of(run_diagnose(DiagnoseConfig(run=run, batch_size=4, max_frames=5, reuse=False)), 5) > 0

    # The same step with other weights (a retrained run in the same directory): scored again.
    mark_first_saved_score(saved_path)  # step 5
    other = tmp_path / "other"
    save_tiny_checkpoint(root, other, [0, 1, 2], 2)
    shutil.copy(other / "model.safetensors", run / "checkpoints" / "000005" / "pretrained_model")
    report = run_diagnose(DiagnoseConfig(run=run, batch_size=4, max_frames=5))
    assert score_of(report, 5) > 0 and score_of(report, 5) != first


def test_a_rerun_scores_again_on_other_data_under_the_same_names(tmp_path):
    """The data a run's checkpoints name (no --root) is part of a saved score's key: other episodes trained on, or
    the dataset collected again at the same path, are scored again; the same data is kept."""
    import shutil

    root = write_tiny_keyframe_dataset(tmp_path / "tiny", episodes=4, size=32)
    run = tmp_path / "run"
    ckpt = run / "checkpoints" / "000005" / "pretrained_model"
    save_tiny_checkpoint(root, ckpt, [0, 1, 2], 0)
    saved_path = run / "diagnostics" / "diagnostics.json"

    def rerun_keeps_the_mark() -> bool:
        mark_first_saved_score(saved_path)
        report = run_diagnose(DiagnoseConfig(run=run, batch_size=4))
        return report["checkpoints"][0]["train"]["all"]["trans_cm_mean"] == -1.0

    report = run_diagnose(DiagnoseConfig(run=run, batch_size=4))
    data = report["options"]["data"]
    assert (data["root"], data["episodes"]) == (str(root), [0, 1, 2]) and len(data["meta_sha256"]) == 64
    assert rerun_keeps_the_mark()  # the same data

    config_path = ckpt / "train_config.json"
    config = json.loads(config_path.read_text())
    config["dataset"]["episodes"] = [0, 1]
    config_path.write_text(json.dumps(config))
    assert not rerun_keeps_the_mark()  # trained on other episodes
    assert json.loads(saved_path.read_text())["sets"] == {"train": 4, "heldout": 4}

    shutil.rmtree(root)
    write_tiny_keyframe_dataset(root, episodes=4, size=32, seed=7)
    assert not rerun_keeps_the_mark()  # collected again at the same path
    assert rerun_keeps_the_mark()


def test_checkpoint_prediction_matches_select_action(tmp_path):
    """What sigma-diagnose scores is what the policy acts on in closed loop (same pre-processor, same path)."""
    from pipelines.checkpoints import load_policy
    from pipelines.diagnostics import predict_rows
    from pipelines.keyframe_sets import KeyframeSet

    root = write_tiny_keyframe_dataset(tmp_path / "tiny", episodes=1, size=32)
    ckpt = tmp_path / "ckpt"
    save_tiny_checkpoint(root, ckpt, [0], 0)
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


def test_errors_per_task_on_a_dataset_that_names_its_tasks(tmp_path):
    """A multi-task dataset's errors split by the task its sidecar records per episode; without one, no split."""
    from pipelines.checkpoints import load_policy
    from pipelines.diagnostics import diagnose_checkpoint, summary_line
    from pipelines.keyframe_sets import KeyframeSet

    root = write_tiny_keyframe_dataset(tmp_path / "tiny", episodes=3, size=32)
    save_tiny_checkpoint(root, tmp_path / "ckpt", [0, 1, 2], 0)
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
    assert "per_variation" not in report  # one variation per task: the task split says it all

    # Two variations of "reach" (two objects, say): the same frames split by variation too, and the summary line
    # names each variation's first keyframe (step 0).
    for ep, variation in zip(sidecar["episodes"], ["left", "right", "push_block"], strict=True):
        ep["variation"] = variation
    (root / "meta" / "sigma.json").write_text(json.dumps(sidecar))
    report = diagnose_checkpoint(policy, pre, [kf])["train"]
    per_variation = report["per_variation"]
    assert {v: s["all"]["frames"] for v, s in per_variation.items()} == {
        "left": 2,
        "push_block": 2,
        "right": 2,
    }
    assert per_variation["push_block"] == report["per_task"]["push"]
    left = per_variation["left"]["per_step"]["0"]
    assert left["frames"] == 1
    line = summary_line(
        {"checkpoints": [{"step": 5, "train": report}], "sets": {"train": 6}, "output_dir": "x"}
    )
    assert f"first keyframe: left {left['trans_cm_median']:.1f} cm {left['rot_deg_median']:.0f} deg" in line


def test_act_with_ema_on_a_checkpoint_without_a_weight_average_is_named(tmp_path):
    root = write_tiny_keyframe_dataset(tmp_path / "tiny", episodes=1, size=32)
    ckpt = tmp_path / "ckpt"
    save_tiny_checkpoint(root, ckpt, [0], 0)
    cfg = DiagnoseConfig(checkpoint=ckpt, root=root, heldout_root=root, act_with_ema=False)
    with pytest.raises(ValueError, match=f"{ckpt} was trained without a weight average"):
        run_diagnose(cfg)


def test_a_diagnosis_is_keyed_by_the_heatmap_fusion_the_checkpoints_act_with():
    """A report scored with the sum (every report before the option) matches a sum-acting checkpoint; one that acts
    with product fusion, by its config or by ``--heatmap_fusion``, is scored apart."""
    assert "heatmap_fusion" not in scoring_options(DiagnoseConfig(), "sum")
    assert scoring_options(DiagnoseConfig(), "product")["heatmap_fusion"] == "product"
    assert scoring_options(DiagnoseConfig(heatmap_fusion="sum"), "product")["heatmap_fusion"] == "sum"
