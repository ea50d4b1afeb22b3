"""`sigma-ablate`: both arms train with the stock lerobot-train on the same data and evaluate on the same seeds."""

from __future__ import annotations

import json

from pipelines.ablation import AblationConfig, run_ablation
from pipelines.training import last_logged_metrics


def test_tiny_ablation_runs_both_arms_and_resumes(tmp_path):
    cfg = AblationConfig(
        output_dir=tmp_path / "ablation",
        tasks=["lift"],
        episodes=2,
        cameras=["agentview"],
        image_size=32,
        steps=2,
        batch_size=2,
        eval_episodes=1,
        max_keyframes=2,
        workers=1,
    )
    text = run_ablation(cfg)
    out = cfg.output_dir
    # The arms differ in the loss only, and both were really trained and evaluated.
    configs = {
        arm: json.loads((out / "train" / arm / "checkpoints/last/pretrained_model/config.json").read_text())
        for arm in ("baseline", "contrastive")
    }
    assert (
        configs["baseline"]["use_contrastive"] is False and configs["contrastive"]["use_contrastive"] is True
    )
    for key in ("preset", "scene_bounds", "use_proprio", "img_size"):
        assert configs["baseline"][key] == configs["contrastive"][key]
    evals = {arm: json.loads((out / "eval" / arm / "results.json").read_text()) for arm in configs}
    assert evals["baseline"]["variations"][0]["seeds"] == evals["contrastive"]["variations"][0]["seeds"]
    assert "| lift | lift_cube |" in text and "baseline (BC only)" in text
    metrics = json.loads((out / "train" / "contrastive.json").read_text())["last_metrics"]
    assert "contrastive_goal_loss" in metrics and metrics["step"] == 2

    # A second run reuses the finished arms and evaluations instead of retraining.
    ckpt = out / "train" / "baseline" / "checkpoints/last/pretrained_model/model.safetensors"
    stamp = ckpt.stat().st_mtime_ns
    assert run_ablation(cfg) == text
    assert ckpt.stat().st_mtime_ns == stamp


def test_last_logged_metrics_reads_lerobots_log_line(tmp_path):
    log = tmp_path / "train.log"
    log.write_text(
        "INFO 2026-11-22 11:29:46 ot_train.py:641 step:50 smpl:400 ep:80 epch:6.67 loss:8.933 "
        "trans_loss:6.933 lr:2.9e-03 contrastive_goal_loss:2.080\n"
        "INFO 2026-11-22 11:30:46 ot_train.py:641 step:1K smpl:8K ep:1K epch:13.33 loss:6.294 "
        "trans_loss:5.489 lr:1.5e-03 contrastive_goal_loss:1.075\n"
    )
    m = last_logged_metrics(log)
    assert m["step"] == 1000 and m["loss"] == 6.294 and m["lr"] == 1.5e-3
    assert m["contrastive_goal_loss"] == 1.075


def test_unknown_or_repeated_arms_are_refused_before_anything_is_written(tmp_path):
    import pytest

    for arms in (["baseline", "centered"], ["centred", "centred"], []):
        cfg = AblationConfig(output_dir=tmp_path / "ablation", arms=arms)
        with pytest.raises(ValueError, match="--arms must name distinct arms"):
            run_ablation(cfg)
        assert not cfg.output_dir.exists()


def test_every_arm_is_a_column_of_the_report(tmp_path):
    from pipelines.ablation import report

    arms = ["baseline", "uncentred", "centred"]
    cfg = AblationConfig(output_dir=tmp_path, tasks=["lift"], arms=arms)
    row = {"task": "lift", "variation": "lift_cube", "successes": 3, "episodes": 4, "success_rate": 0.75}
    evals = {
        arm: {"variations": [row | {"ci95": [0.3, 0.95], "seeds": [100000, 100003]}], "mean_success": 0.75}
        for arm in arms
    }
    trained = {arm: {"train_seconds": 60.0, "threads": 1, "last_metrics": {"bc_loss": 1.0}} for arm in arms}
    (tmp_path / "meta").mkdir()
    (tmp_path / "meta" / "sigma.json").write_text(json.dumps({"num_episodes": 4}))
    text = report(cfg, tmp_path, trained, evals)
    header = next(line for line in text.splitlines() if line.startswith("| task |"))
    assert header.count("|") == 2 + len(arms) + 1
    assert "Σ-agent, centred features" in header and "Σ-agent, uncentred features" in header
    assert "centred `--policy.use_contrastive=true --policy.contrastive_center=true`" in text
