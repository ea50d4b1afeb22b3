"""`sigma-compare` on a tiny budget: one collection feeds sigma (keyframe) and a stock policy (RGB-only dense),
both trained by the stock lerobot-train and evaluated on the same seeds (sigma-eval / lerobot-eval in dense
control); the table names both; a rerun reuses every stage."""

from __future__ import annotations

import json

from pipelines.compare import CompareConfig, PolicyBudget, run_compare


def test_compare_trains_and_evaluates_sigma_and_a_stock_policy_on_one_collection(tmp_path, capsys):
    cfg = CompareConfig(
        output_dir=tmp_path / "cmp",
        tasks=["lift"],
        episodes=1,
        cameras=["agentview", "robot0_eye_in_hand"],
        image_size=32,
        policies=["sigma", "diffusion"],
        sigma=PolicyBudget(steps=2, batch_size=2),
        diffusion=PolicyBudget(steps=2, batch_size=2),
        eval_episodes=1,
        max_keyframes=2,
        max_control_steps=16,
        workers=1,
    )
    text = run_compare(cfg)
    assert "| lift | lift_cube | 0/1" in text or "| lift | lift_cube | 1/1" in text
    assert "| sigma | keyframe (RGB-D) | 2 × 2 |" in text and "| diffusion | dense (RGB) | 2 × 2 |" in text
    out = json.loads((tmp_path / "cmp" / "compare.json").read_text())
    assert set(out["eval"]) == {"sigma", "diffusion"}
    # Each run's arguments as it was started (after training, the run's command is its resume command).
    assert out["trained"]["sigma"]["args"][:2] == ["--policy.type=sigma", "--policy.device=cpu"]
    assert out["trained"]["diffusion"]["args"][0] == "--policy.type=diffusion"
    for rows in out["eval"].values():
        assert [(r["task"], r["variation"], r["episodes"], r["seeds"]) for r in rows] == [
            ("lift", "lift_cube", 1, [100000])
        ]
    # The dense dataset the stock policy trained on has no depth; the keyframe dataset keeps it.
    dense = json.loads((tmp_path / "cmp" / "data" / "dense" / "meta" / "info.json").read_text())["features"]
    keyframe = json.loads((tmp_path / "cmp" / "data" / "keyframe" / "meta" / "info.json").read_text())[
        "features"
    ]
    assert not any(k.endswith("_depth") for k in dense) and "observation.images.agentview_depth" in keyframe
    capsys.readouterr()

    run_compare(cfg)  # everything reused
    log = capsys.readouterr().out
    assert "sigma: reusing the finished run" in log and "diffusion: reusing the evaluation" in log
