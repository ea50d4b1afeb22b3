"""Stock LeRobot policies on sigma's data and env, with no hand edits: a dense dataset collected with
``--output.dense_depth=false`` trains stock ACT with the stock ``lerobot-train``, and the stock ``lerobot-eval``
runs the checkpoint in the dense control mode of ``--env.type=sigma_robosuite`` (tiny budget: this proves the
plumbing, not the policy; ``benchmarks/bench_policies.py`` measures success)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest


def cli(name: str, *args: str, timeout: int = 600) -> subprocess.CompletedProcess:
    proc = subprocess.run(
        [str(Path(sys.executable).with_name(name)), *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env={**os.environ, "HF_HUB_OFFLINE": "1"},
    )
    assert proc.returncode == 0, f"{name} failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}"
    return proc


@pytest.mark.timeout(900)
def test_stock_act_trains_on_a_fresh_dense_dataset_and_evaluates_in_dense_mode(tmp_path):
    data = tmp_path / "data"
    cli(
        "sigma-data",
        "collect",
        "--tasks=lift",
        "--episodes=1",
        "--render.height=32",
        "--render.width=32",
        "--render.cameras=agentview,robot0_eye_in_hand",
        "--output.keyframe=false",
        "--output.dense_depth=false",
        f"--output.dir={data}",
        "--progress=false",
    )
    run = tmp_path / "act"
    cli(
        "lerobot-train",
        "--policy.type=act",
        f"--dataset.root={data / 'dense'}",
        "--dataset.repo_id=local/lift_dense",
        "--dataset.video_backend=pyav",
        "--policy.device=cpu",
        "--policy.pretrained_backbone_weights=null",  # offline: no ImageNet download
        "--policy.push_to_hub=false",
        "--policy.chunk_size=10",
        "--policy.n_action_steps=10",
        "--steps=2",
        "--batch_size=2",
        "--num_workers=0",
        "--save_freq=2",
        f"--output_dir={run}",
        "--wandb.enable=false",
    )
    ckpt = run / "checkpoints" / "last" / "pretrained_model"
    config = json.loads((ckpt / "config.json").read_text())
    assert config["type"] == "act" and config["output_features"]["action"]["shape"] == [7]
    assert not any(k.endswith("_depth") for k in config["input_features"])

    out = tmp_path / "eval"
    cli(
        "lerobot-eval",
        f"--policy.path={ckpt}",
        "--env.type=sigma_robosuite",
        "--env.control=dense",
        "--env.depth=false",
        "--env.task=lift",
        "--env.cameras=[agentview,robot0_eye_in_hand]",
        "--env.image_size=32",
        "--env.episode_length=12",
        "--eval.n_episodes=1",
        "--eval.batch_size=1",
        "--policy.device=cpu",
        "--seed=100000",
        f"--output_dir={out}",
    )
    info = json.loads((out / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 1 and "pc_success" in info["overall"]
