"""``pipelines.training``: the stock ``lerobot-train`` as the pipelines run it, and resuming an interrupted run."""

from __future__ import annotations

import json
import os
import shutil
import sys
from pathlib import Path

import pytest

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


def test_a_finished_run_is_reused_only_with_the_options_it_was_trained_with(tmp_path):
    """``reuse_or_clear`` compares the run's ``--policy.*`` (but the device), ``--steps``, ``--batch_size`` and
    ``--seed`` arguments with the saved ``train_config.json``: the same options reuse the record, another option is a
    clear error and clears nothing."""
    from sigma_policy.configuration_sigma import PRESETS

    run = TrainRun(
        dataset_root=tmp_path / "data",
        output_dir=tmp_path / "train",
        steps=6000,
        batch_size=8,
        scene_bounds=(-0.4, -0.5, 0.75, 0.6, 0.5, 1.75),
        extra_args=[
            "--policy.yaw_scan_px=24",
            "--policy.use_cpu_bf16_autocast=true",
            "--policy.optimizer_lr=0.003",
        ],
    )
    run.checkpoint.mkdir(parents=True)
    (run.checkpoint / "config.json").write_text("{}")
    saved = {
        "steps": 6000,
        "batch_size": 8,
        "seed": 0,
        "dataset": {"root": "/elsewhere"},  # not compared: a moved dataset is the same data
        "policy": {
            **PRESETS["small"],
            "type": "sigma",
            "device": "cpu",
            "preset": "small",
            "scene_bounds": [-0.4, -0.5, 0.75, 0.6, 0.5, 1.75],
            "yaw_scan_px": 24,
            "use_cpu_bf16_autocast": True,
            "optimizer_lr": 0.003,
        },
    }
    (run.checkpoint / "train_config.json").write_text(json.dumps(saved))
    record = tmp_path / "train_seconds.json"
    record.write_text(json.dumps({"seconds": 60.0}))
    assert run.reuse_or_clear(record, "suite") == {"seconds": 60.0}
    for i, changed in ((0, "--policy.yaw_scan_px=0"), (1, "--policy.use_cpu_bf16_autocast=false")):
        args = [changed if j == i else a for j, a in enumerate(run.extra_args)]
        other = TrainRun(**{**run.__dict__, "extra_args": args})
        with pytest.raises(ValueError, match=rf"was trained with --policy\..* asks for {changed}"):
            other.reuse_or_clear(record, "suite")
    with pytest.raises(ValueError, match="--steps=6000"):
        TrainRun(**{**run.__dict__, "steps": 3000}).reuse_or_clear(record, "suite")
    with pytest.raises(ValueError, match="--batch_size=8, this run asks for --batch_size=32"):
        TrainRun(**{**run.__dict__, "batch_size": 32}).reuse_or_clear(record, "suite")
    # Trained on a GPU machine, scored on a CPU one: the device is not an option of what was learned.
    assert TrainRun(**{**run.__dict__, "device": "cuda"}).reuse_or_clear(record, "suite") == {"seconds": 60.0}
    # An option the saved run predates is compared at the value it was introduced with.
    newer = TrainRun(**{**run.__dict__, "extra_args": [*run.extra_args, "--policy.first_keyframe_weight=3"]})
    with pytest.raises(ValueError, match=r"--policy\.first_keyframe_weight=1\.0, this run asks for .*=3"):
        newer.reuse_or_clear(record, "suite")
    # A run trained with an option sigma has since retired is refused by name; one that left it off is reused.
    saved["policy"] |= {"zoom_box_m": 0.0, "hand_marker": False}
    (run.checkpoint / "train_config.json").write_text(json.dumps(saved))
    assert run.reuse_or_clear(record, "suite") == {"seconds": 60.0}
    saved["policy"]["zoom_box_m"] = 0.5
    (run.checkpoint / "train_config.json").write_text(json.dumps(saved))
    with pytest.raises(
        ValueError, match=r"train_config\.json: policy\.zoom_box_m=0\.5 is an option sigma tried"
    ):
        run.reuse_or_clear(record, "suite")
    assert run.checkpoint.is_dir()  # nothing cleared


def _finished_run(
    tmp_path, preset: str, steps: int, batch_size: int, seconds: float
) -> tuple[TrainRun, Path]:
    """A run of ``preset`` whose checkpoint and stage record exist (its ``train_config.json`` is the test's to
    write), and that record."""
    run = TrainRun(
        dataset_root=tmp_path / "data",
        output_dir=tmp_path / "train",
        steps=steps,
        batch_size=batch_size,
        preset=preset,
        extra_args=[f"--policy.scheduler_decay_steps={steps}"],
    )
    run.checkpoint.mkdir(parents=True)
    (run.checkpoint / "config.json").write_text("{}")
    record = tmp_path / "train_seconds.json"
    record.write_text(json.dumps({"seconds": seconds}))
    return run, record


def test_a_preset_is_compared_by_the_values_it_fills(tmp_path):
    """``--policy.preset=suite`` reuses a run trained as ``small`` with the suite's options given one by one (the
    published suite runs), and refuses a ``small`` run that left one of them at its default, and a run trained with
    an option this run leaves at its default."""
    from sigma_policy.configuration_sigma import PRESETS

    run, record = _finished_run(tmp_path, "suite", steps=6000, batch_size=8, seconds=60.0)
    suite_options = {
        "per_task_bounds": True,
        "yaw_scan_px": 24,
        "optimizer_lr": 0.003,
        "scheduler_decay_steps": 6000,
        "proprio_film": False,  # on in today's small, off in suite
        "lang_task_contrast": False,  # the same
    }
    by_hand = PRESETS["small"] | suite_options
    saved = {
        "steps": 6000,
        "seed": 0,
        "policy": {"type": "sigma", "device": "cpu", "preset": "small", **by_hand},
    }
    (run.checkpoint / "train_config.json").write_text(json.dumps(saved))
    assert run.reuse_or_clear(record, "suite") == {"seconds": 60.0}
    saved["policy"]["yaw_scan_px"] = 0
    (run.checkpoint / "train_config.json").write_text(json.dumps(saved))
    with pytest.raises(
        ValueError, match=r"--policy\.yaw_scan_px=0, this run's --policy\.preset=suite means 24"
    ):
        run.reuse_or_clear(record, "suite")
    # An option neither given nor filled by the preset means its default.
    saved["policy"] |= {"yaw_scan_px": 24, "first_keyframe_weight": 3.0}
    (run.checkpoint / "train_config.json").write_text(json.dumps(saved))
    with pytest.raises(
        ValueError, match=r"--policy\.first_keyframe_weight=3\.0, this run leaves it at its default 1\.0"
    ):
        run.reuse_or_clear(record, "suite")
    assert run.checkpoint.is_dir()  # nothing cleared


def test_the_gpu_preset_reuses_the_suite_run_widened_by_hand(tmp_path):
    """The ``gpu`` preset's measured run was trained as ``suite`` with the wider network given one by one
    (docs/gpu.md "The gpu preset"): ``--policy.preset=gpu`` reuses it, and refuses ``suite``'s own network."""
    from sigma_policy.configuration_sigma import PRESETS

    run, record = _finished_run(tmp_path, "gpu", steps=3000, batch_size=64, seconds=425.0)
    wider = {"im_channels": 32, "final_dim": 32, "attn_dim": 256, "attn_heads": 8, "num_fusion_layers": 4}
    saved = {
        "steps": 3000,
        "seed": 0,
        "batch_size": 64,
        "policy": {
            "type": "sigma",
            "device": "cuda",
            "preset": "suite",
            **PRESETS["suite"],
            **wider,
            "scheduler_decay_steps": 3000,
        },
    }
    (run.checkpoint / "train_config.json").write_text(json.dumps(saved))
    assert run.reuse_or_clear(record, "gpu") == {"seconds": 425.0}
    saved["policy"] |= {k: PRESETS["suite"][k] for k in wider}
    (run.checkpoint / "train_config.json").write_text(json.dumps(saved))
    with pytest.raises(ValueError, match=r"this run's --policy\.preset=gpu means 32"):
        run.reuse_or_clear(record, "gpu")


def test_command_runs_the_module_where_the_console_script_is_missing(tmp_path, monkeypatch):
    """LeRobot unpacked onto PYTHONPATH (a GPU machine with no network, docs/gpu.md) has no ``lerobot-train``
    script beside the interpreter: the run starts LeRobot's module with the same arguments."""
    run = TrainRun(dataset_root=tmp_path / "data", output_dir=tmp_path / "train", steps=4, batch_size=2)
    assert run.command()[0].endswith("lerobot-train")
    python = tmp_path / "bin" / "python3"
    monkeypatch.setattr(sys, "executable", str(python))
    assert run.command() == [str(python), "-m", "lerobot.scripts.lerobot_train", *run.arguments()]
