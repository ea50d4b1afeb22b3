"""Opening a checkpoint for evaluation: tampered processor JSON is refused before LeRobot would import the class it
names, and truncated or NaN weights are one clear error naming the file, never a hung worker pool."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.policies.factory import make_policy, make_pre_post_processors
from safetensors.torch import load_file, save_file

from pipelines.checkpoints import CheckpointError, check_checkpoint, load_policy
from pipelines.evaluate import main
from sigma_policy.configuration_sigma import SigmaConfig
from tests.sigma_policy.tiny_dataset import BOUNDS, write_tiny_keyframe_dataset


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    """A real (untrained) sigma checkpoint saved the way lerobot-train saves one."""
    root = write_tiny_keyframe_dataset(tmp_path_factory.mktemp("data") / "tiny", episodes=2, size=32)
    cfg = SigmaConfig(
        preset="small",
        img_size=32,
        patch_size=8,
        attn_dim=32,
        attn_heads=2,
        device="cpu",
        scene_bounds=list(BOUNDS),
    )
    meta = LeRobotDataset("local/tiny", root=root).meta
    policy = make_policy(cfg, ds_meta=meta)
    pre, post = make_pre_post_processors(cfg, dataset_stats=meta.stats)
    out = tmp_path_factory.mktemp("ckpt") / "pretrained_model"
    for thing in (policy, pre, post):
        thing.save_pretrained(out)
    return out


def tampered(checkpoint: Path, tmp_path: Path) -> Path:
    copy = tmp_path / "pretrained_model"
    shutil.copytree(checkpoint, copy)
    return copy


def test_a_good_checkpoint_passes_and_loads(checkpoint):
    check_checkpoint(checkpoint)
    policy, pre, post = load_policy(checkpoint)
    assert policy.config.type == "sigma" and pre is not None and post is not None


@pytest.mark.parametrize("step", [{"class": "subprocess.Popen"}, {"registry_name": "not_a_step"}])
def test_processor_steps_outside_the_registry_are_refused_before_anything_runs(
    checkpoint, tmp_path, step, capsys
):
    ckpt = tampered(checkpoint, tmp_path)
    marker = tmp_path / "executed"
    path = ckpt / "policy_preprocessor.json"
    spec = json.loads(path.read_text())
    spec["steps"].append(step | {"config": {"args": ["touch", str(marker)]}})
    path.write_text(json.dumps(spec))
    with pytest.raises(
        CheckpointError, match=r"policy_preprocessor.json: step \d+ names .* not a registered"
    ):
        load_policy(ckpt)
    assert (
        main([f"--checkpoint={ckpt}", "--episodes=1", "--workers=2", f"--output_dir={tmp_path / 'eval'}"])
        == 1
    )
    assert "not a registered processor step" in capsys.readouterr().err
    assert not marker.exists()


@pytest.mark.timeout(120)
def test_truncated_weights_are_one_clear_error_even_with_worker_processes(checkpoint, tmp_path, capsys):
    ckpt = tampered(checkpoint, tmp_path)
    weights = ckpt / "model.safetensors"
    weights.write_bytes(weights.read_bytes()[: weights.stat().st_size // 2])
    with pytest.raises(CheckpointError, match=r"model\.safetensors: cannot read the weights"):
        check_checkpoint(ckpt)
    assert (
        main([f"--checkpoint={ckpt}", "--episodes=1", "--workers=2", f"--output_dir={tmp_path / 'eval'}"])
        == 1
    )
    err = capsys.readouterr().err
    assert "model.safetensors" in err and len(err.strip().splitlines()) == 1


def test_nan_weights_are_named(checkpoint, tmp_path):
    ckpt = tampered(checkpoint, tmp_path)
    tensors = load_file(ckpt / "model.safetensors")
    name = sorted(tensors)[0]
    tensors[name] = torch.full_like(tensors[name], float("nan"))
    save_file(tensors, ckpt / "model.safetensors")
    with pytest.raises(CheckpointError, match=f"tensor '{name}' holds NaN or inf"):
        check_checkpoint(ckpt)


@pytest.mark.parametrize(
    ("option", "message"),
    [
        ("--tta_yaw_deg=[15,7]", "multiples of the 5° rotation bins, got [7.0]"),
        ("--act_with_ema=false", "was trained without a weight average (ema_decay 0)"),
        ("--heatmap_fusion=mean", "--heatmap_fusion must be one of ('sum', 'product'), got 'mean'"),
    ],
)
def test_a_test_time_option_the_checkpoint_cannot_take_is_one_clear_error_before_any_episode(
    checkpoint, tmp_path, capsys, option, message
):
    out = tmp_path / "eval"
    assert main([f"--checkpoint={checkpoint}", option, f"--output_dir={out}"]) == 1
    assert message in capsys.readouterr().err
    assert not out.exists()


def test_instruction_contrast_without_the_instructions_tasks_is_one_clear_error_before_any_episode(
    checkpoint, tmp_path, capsys
):
    """A checkpoint that does not record each instruction's task needs ``--train_dataset`` to read them from; a
    weight outside [0, 1) is refused."""
    out = tmp_path / "eval"
    assert main([f"--checkpoint={checkpoint}", "--instruction_contrast=0.3", f"--output_dir={out}"]) == 1
    assert "has no instruction_tasks" in capsys.readouterr().err
    assert main([f"--checkpoint={checkpoint}", "--instruction_contrast=1.0", f"--output_dir={out}"]) == 1
    assert "instruction_contrast must be in [0, 1)" in capsys.readouterr().err
    assert not out.exists()
