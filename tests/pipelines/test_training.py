"""``pipelines.training``: the stock ``lerobot-train`` as the pipelines run it, and resuming an interrupted run."""

from __future__ import annotations

import json
import os
import shutil

from pipelines.training import TrainRun, train
from tests.sigma_policy.tiny_dataset import BOUNDS, write_tiny_keyframe_dataset


def test_an_interrupted_run_resumes_from_its_last_checkpoint(tmp_path):
    """A run killed after its step-2 checkpoint (``last`` still points there; the step-4 one never finished)
    continues from step 2 with ``--resume=true`` instead of being cleared and retrained; its log keeps the
    interrupted run's part and appends the resumed one."""
    root = write_tiny_keyframe_dataset(tmp_path / "tiny", episodes=2, size=32)
    run = TrainRun(
        dataset_root=root,
        output_dir=tmp_path / "train",
        steps=4,
        batch_size=2,
        scene_bounds=BOUNDS,
        save_freq=2,
        extra_args=["--policy.img_size=32", "--policy.attn_dim=32", "--policy.attn_heads=2"],
    )
    assert run.resumable is None and "--resume=true" not in run.command()
    train(run, log_path=tmp_path / "train.log")
    checkpoints = run.output_dir / "checkpoints"
    # What a kill during the second checkpoint leaves: a partial step-4 directory, `last` still at step 2.
    (checkpoints / "last").unlink()
    os.symlink("000002", checkpoints / "last")
    shutil.rmtree(checkpoints / "000004" / "pretrained_model")
    record = tmp_path / "train_seconds.json"
    assert run.reuse_or_clear(record, "tiny") is None
    assert (checkpoints / "000002").is_dir()  # kept for the resume, not cleared
    assert run.command()[1:] == [
        f"--config_path={checkpoints / 'last' / 'pretrained_model' / 'train_config.json'}",
        "--resume=true",
    ]
    ckpt, _ = train(run, log_path=tmp_path / "train.log")
    log = (tmp_path / "train.log").read_text()
    first, resumed = log.split("--resume=true", 1)
    assert first.startswith("$ ") and "--steps=4" in first and "checkpoint" in first.lower()
    assert "resum" in resumed.lower()
    state = json.loads((checkpoints / "last" / "training_state" / "training_step.json").read_text())
    assert state["step"] == 4 and (ckpt / "model.safetensors").exists()
    assert os.readlink(checkpoints / "last") == "000004"
