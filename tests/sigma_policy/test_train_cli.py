"""Stock ``lerobot-train --policy.type=sigma`` offline on a tiny keyframe dataset: train, checkpoint, resume,
``from_pretrained`` and processor reload."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.policies.factory import make_pre_post_processors

from sigma_policy.modeling_sigma import SigmaPolicy
from tests.sigma_policy.tiny_dataset import BOUNDS, write_tiny_keyframe_dataset

POLICY_FLAGS = [
    "--policy.type=sigma",
    "--policy.preset=small",
    "--policy.img_size=32",
    "--policy.attn_dim=64",
    "--policy.attn_heads=2",
    "--policy.device=cpu",
    f"--policy.scene_bounds=[{','.join(str(b) for b in BOUNDS)}]",
]


def lerobot_train(args: list[str]) -> subprocess.CompletedProcess:
    env = os.environ | {"HF_HUB_OFFLINE": "1", "TOKENIZERS_PARALLELISM": "false", "OMP_NUM_THREADS": "2"}
    # `python -m` is the `lerobot-train` console script; plugin discovery finds the installed lerobot_policy_sigma.
    cmd = [sys.executable, "-m", "lerobot.scripts.lerobot_train", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=600, env=env)


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> tuple[Path, Path]:
    base = tmp_path_factory.mktemp("cli")
    root = write_tiny_keyframe_dataset(base / "tiny", episodes=3, size=40)
    out = base / "run"
    proc = lerobot_train(
        [
            f"--dataset.root={root}",
            "--dataset.repo_id=local/tiny",
            *POLICY_FLAGS,
            "--steps=4",
            "--batch_size=2",
            "--num_workers=0",
            "--log_freq=1",
            "--save_freq=2",
            "--wandb.enable=false",
            f"--output_dir={out}",
        ]
    )
    assert proc.returncode == 0, proc.stderr[-4000:]
    return root, out


def test_train_writes_checkpoints_with_loss_parts(run_dir):
    _, out = run_dir
    ckpt = out / "checkpoints" / "last" / "pretrained_model"
    for name in ("config.json", "model.safetensors", "policy_preprocessor.json", "policy_postprocessor.json"):
        assert (ckpt / name).is_file(), name
    assert (out / "checkpoints" / "000002").is_dir() and (out / "checkpoints" / "000004").is_dir()
    cfg = json.loads((ckpt / "config.json").read_text())
    assert cfg["type"] == "sigma" and cfg["img_size"] == 32 and cfg["push_to_hub"] is False
    state = out / "checkpoints" / "last" / "training_state"
    assert (state / "optimizer_state.safetensors").is_file()
    train_cfg = json.loads((ckpt / "train_config.json").read_text())
    assert train_cfg["optimizer"]["type"] == "lamb"


@pytest.mark.slow
def test_resume_continues_from_the_checkpoint(run_dir):
    _, out = run_dir
    cfg_path = out / "checkpoints" / "last" / "pretrained_model" / "train_config.json"
    proc = lerobot_train(["--resume=true", f"--config_path={cfg_path}", "--steps=6", "--save_freq=2"])
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert (out / "checkpoints" / "000006" / "pretrained_model" / "model.safetensors").is_file()
    log = proc.stdout + proc.stderr
    assert "Resuming" in log or "resum" in log.lower()


def test_checkpoint_loads_for_inference_with_its_processors(run_dir):
    root, out = run_dir
    ckpt = out / "checkpoints" / "000004" / "pretrained_model"
    policy = SigmaPolicy.from_pretrained(ckpt)
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(ckpt))
    item = LeRobotDataset("local/tiny", root=root)[0]
    obs = {k: v for k, v in item.items() if k.startswith("observation.") or k == "task"}
    action = post(policy.select_action(pre(obs)))
    assert action.shape == (1, 9) and torch.isfinite(action).all()
