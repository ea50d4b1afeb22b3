"""Run the stock ``lerobot-train`` (used by the demo, the ablation and the policy comparison).

Training always goes through LeRobot's own CLI in a subprocess, exactly as a user would run it, so what the
pipelines measure is what ``lerobot-train --policy.type=sigma`` does.
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

# sigma options that training fills in from the dataset when left unset: not compared when a run is reused.
RESOLVED_AT_TRAINING = frozenset(
    {"preset", "scene_bounds", "instruction_bounds", "instruction_tasks", "cameras"}
)
# Arguments that do not change what a run learns: a run trained on a GPU machine is diagnosed and evaluated on a CPU
# one with the same options (docs/gpu.md).
NOT_COMPARED = frozenset({"policy.device"})


@dataclass
class TrainRun:
    """One ``lerobot-train`` run: its inputs, and where its checkpoint and log go.

    ``policy_type="sigma"`` trains sigma on a keyframe dataset (``preset`` and ``scene_bounds`` apply); any other
    type is a stock LeRobot policy (``act``, ``diffusion``...) configured only by ``extra_args``."""

    dataset_root: Path
    output_dir: Path
    steps: int
    batch_size: int
    scene_bounds: tuple[float, ...] | None = None
    preset: str = "small"
    policy_type: str = "sigma"
    device: str = "cpu"
    seed: int = 0
    job_name: str = "sigma"
    # Save a checkpoint every this many steps (None = only at the end); sigma-diagnose scores each one.
    save_freq: int | None = None
    # DataLoader workers. 0 reads each batch in the training process: on 2 CPU cores workers would take cores from
    # the update. On a GPU machine that read took as long as the update itself (65-77 ms per batch of 8 on an
    # H200's host, docs/gpu.md), so runs there read in workers.
    num_workers: int = 0
    # Extra ``--policy.*`` (or any lerobot-train) arguments, e.g. ["--policy.use_contrastive=false"].
    extra_args: list[str] = field(default_factory=list)

    @property
    def checkpoint(self) -> Path:
        return self.output_dir / "checkpoints" / "last" / "pretrained_model"

    @property
    def resumable(self) -> Path | None:
        """The run's last complete checkpoint with its training state (LeRobot moves the ``last`` link only
        after a checkpoint is written), from which ``lerobot-train --resume=true`` continues; else None."""
        last = self.output_dir / "checkpoints" / "last"
        config = last / "pretrained_model" / "train_config.json"
        return last if (last / "training_state").is_dir() and config.exists() else None

    def reuse_or_clear(self, record: Path, name: str) -> dict | None:
        """A pipeline's stage record of this run (``record``, JSON) when the run finished and saved its checkpoint;
        otherwise None, after clearing ``output_dir`` (lerobot-train refuses an existing one without
        ``--resume``) unless an interrupted run left a checkpoint to resume from (:attr:`resumable`)."""
        if record.exists() and (self.checkpoint / "config.json").exists():
            self.check_same_options(self.checkpoint / "train_config.json")
            print(f"{name}: reusing the finished run in {self.output_dir}", flush=True)
            return json.loads(record.read_text())
        if self.resumable is not None:
            self.check_same_options(self.resumable / "pretrained_model" / "train_config.json")
            print(f"{name}: resuming the interrupted run from {self.resumable.resolve()}", flush=True)
        elif self.output_dir.exists():
            shutil.rmtree(self.output_dir)
        return None

    def check_same_options(self, train_config: Path) -> None:
        """Refuse to reuse or resume a run whose saved ``train_config.json`` disagrees with this run's
        ``--policy.*`` (but the device), ``--steps``, ``--batch_size`` or ``--seed`` arguments (the output
        directory's name does not say how its run was trained: a benchmark rerun with other ``--policy_args`` would
        otherwise trust the old checkpoint)."""
        if not train_config.exists():
            return
        saved = json.loads(train_config.read_text())
        policy = saved.get("policy", {})
        if self.policy_type == "sigma":
            from sigma_policy.compat import drop_retired

            # a run trained with an option sigma has since removed is refused, naming it (sigma_policy/compat.py)
            policy = _introduced_values() | drop_retired(policy, str(train_config))
        arguments = self.arguments()
        for arg in arguments:
            key, _, value = arg.removeprefix("--").partition("=")
            if key == "policy.preset" and self.policy_type == "sigma":
                self._check_same_preset(value, arguments, policy, train_config)
                continue
            if key in NOT_COMPARED:
                continue
            if key.startswith("policy."):
                where, name = policy, key.removeprefix("policy.")
            elif key in ("steps", "seed", "batch_size"):
                where, name = saved, key
            else:
                continue
            if name in where and not _same_value(value, where[name]):
                raise ValueError(
                    f"{train_config} was trained with --{key}={json.dumps(where[name])}, this run asks for "
                    f"--{key}={value}: delete {self.output_dir} or choose another output directory"
                )

    def _check_same_preset(self, preset: str, arguments: list[str], saved: dict, train_config: Path) -> None:
        """Every sigma option that no argument sets still means a value: the preset's for a field the preset
        fills, the dataclass default for the rest. It must equal the saved one, so a ``suite`` run reuses a
        ``small`` run given the suite's options one by one (the published suite runs) and refuses a ``small`` run
        that left one of them at its default, or a run trained with an option (``first_keyframe_weight=3``) that
        this run leaves at its default. Fields resolved from the dataset at training (the boxes, the cameras) are
        not compared."""
        from sigma_policy.configuration_sigma import PRESETS

        given = {
            a.removeprefix("--policy.").partition("=")[0] for a in arguments if a.startswith("--policy.")
        }
        fills = PRESETS.get(preset, {})
        for f in _compared_fields():
            if f.name in given:
                continue
            if f.name in fills:
                value, means = fills[f.name], f"this run's --policy.preset={preset} means"
            else:
                value, means = _default(f), "this run leaves it at its default"
            if f.name in saved and not _same_value(json.dumps(value), saved[f.name]):
                raise ValueError(
                    f"{train_config} was trained with --policy.{f.name}={json.dumps(saved[f.name])}, {means} "
                    f"{json.dumps(value)}: delete {self.output_dir} or choose another output directory"
                )

    def command(self) -> list[str]:
        """The ``lerobot-train`` command line: a fresh run (:meth:`arguments`), or ``--resume=true`` from
        :attr:`resumable` (the saved ``train_config.json`` then holds every option)."""
        script = Path(sys.executable).with_name("lerobot-train")
        # Without the console script (LeRobot unpacked onto PYTHONPATH, docs/gpu.md), its module.
        executable = (
            [str(script)] if script.exists() else [sys.executable, "-m", "lerobot.scripts.lerobot_train"]
        )
        if self.resumable is not None:
            config = self.resumable / "pretrained_model" / "train_config.json"
            return [*executable, f"--config_path={config}", "--resume=true"]
        return [*executable, *self.arguments()]

    def arguments(self) -> list[str]:
        """The ``lerobot-train`` arguments of this run as a fresh start (a resumed run continues with them)."""
        policy = [f"--policy.type={self.policy_type}", f"--policy.device={self.device}"]
        if self.policy_type == "sigma":
            policy.append(f"--policy.preset={self.preset}")
            if self.scene_bounds is not None:
                policy.append(f"--policy.scene_bounds=[{','.join(f'{v:g}' for v in self.scene_bounds)}]")
        else:
            policy.append("--policy.push_to_hub=false")
        return [
            *policy,
            f"--dataset.root={self.dataset_root}",
            f"--dataset.repo_id=local/{Path(self.dataset_root).name}",
            "--dataset.video_backend=pyav",
            f"--output_dir={self.output_dir}",
            f"--job_name={self.job_name}",
            f"--steps={self.steps}",
            f"--batch_size={self.batch_size}",
            f"--num_workers={self.num_workers}",
            f"--log_freq={max(1, self.steps // 20)}",
            f"--save_freq={self.save_freq or self.steps}",
            "--wandb.enable=false",
            f"--seed={self.seed}",
            *self.extra_args,
        ]


def _default(f: Any) -> Any:
    """The default of dataclass field ``f``."""
    return f.default if f.default is not dataclasses.MISSING else f.default_factory()


def _compared_fields() -> list[Any]:
    """The sigma options a reused run is compared on: SigmaConfig's own fields, less those training resolves from
    the dataset (:data:`RESOLVED_AT_TRAINING`) and LeRobot's common policy fields (device, hub settings...)."""
    from lerobot.configs.policies import PreTrainedConfig

    from sigma_policy.configuration_sigma import SigmaConfig

    skip = RESOLVED_AT_TRAINING | {f.name for f in dataclasses.fields(PreTrainedConfig)}
    return [f for f in dataclasses.fields(SigmaConfig) if f.name not in skip]


def _introduced_values() -> dict[str, Any]:
    """Every sigma option at the value it was introduced with: what a run trained before the option existed did.
    That is its default, or the ``paper`` preset's value for a field the presets fill (new options arrive off)."""
    from sigma_policy.configuration_sigma import PRESETS

    values = {f.name: PRESETS["paper"].get(f.name, _default(f)) for f in _compared_fields()}
    return json.loads(json.dumps(values))  # as a train_config.json stores them (tuples as lists)


def _same_value(arg: str, stored: object) -> bool:
    """Whether a command-line value (``true``, ``0.003``, ``[-0.4,0.5]``, ``cpu``) means the value a
    ``train_config.json`` stored."""
    try:
        parsed = json.loads(arg)
    except json.JSONDecodeError:
        return arg == str(stored)
    if isinstance(parsed, list) and isinstance(stored, list):
        return len(parsed) == len(stored) and all(
            _same_value(json.dumps(a), b) for a, b in zip(parsed, stored, strict=False)
        )
    if isinstance(parsed, (int, float)) and isinstance(stored, (int, float)) and not isinstance(stored, bool):
        return abs(float(parsed) - float(stored)) <= 1e-9 * max(1.0, abs(float(stored)))
    return parsed == stored


def start(run: TrainRun, log_path: Path | None = None, threads: int | None = None) -> subprocess.Popen:
    """Start ``lerobot-train``; its output goes to ``log_path`` (or this terminal). ``threads`` caps torch.
    A run resumed from an interrupted one's checkpoint appends to the log, after the interrupted run's part."""
    env = dict(os.environ, HF_HUB_OFFLINE="1")
    if threads:
        env["OMP_NUM_THREADS"] = str(threads)
    cmd = run.command()  # a fresh start or, with a checkpoint to resume, the resume command
    if log_path is None:
        print("$ " + " ".join(cmd), flush=True)
        return subprocess.Popen(cmd, env=env)
    log_path.parent.mkdir(parents=True, exist_ok=True)
    with open(log_path, "a" if run.resumable is not None else "w") as log:
        log.write("$ " + " ".join(cmd) + "\n")
        log.flush()
        return subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT)


def wait(run: TrainRun, proc: subprocess.Popen, log_path: Path | None = None) -> Path:
    """Wait for ``proc``; return the checkpoint or raise naming the log to read."""
    code = proc.wait()
    where = f"; see {log_path}" if log_path else ""
    if code != 0:
        raise RuntimeError(f"lerobot-train ({run.job_name}) exited with status {code}{where}")
    if not (run.checkpoint / "config.json").exists():
        raise RuntimeError(
            f"lerobot-train ({run.job_name}) finished without a checkpoint at {run.checkpoint}"
        )
    return run.checkpoint


def train(run: TrainRun, log_path: Path | None = None, threads: int | None = None) -> tuple[Path, float]:
    """Run ``lerobot-train`` to completion; return (checkpoint, wall seconds)."""
    t0 = time.perf_counter()
    ckpt = wait(run, start(run, log_path, threads), log_path)
    return ckpt, time.perf_counter() - t0


_METRIC = re.compile(r"\b([a-z_]+):(-?[0-9.]+(?:e-?[0-9]+)?)\b")


def last_logged_metrics(log_path: Path) -> dict[str, float]:
    """The metrics of the last ``step:...`` line LeRobot logged (loss parts, ``logit_scale``...)."""
    last: dict[str, float] = {}
    for line in Path(log_path).read_text(errors="replace").splitlines():
        if " step:" in line and "loss:" in line:
            tail = line.split(" step:", 1)[1]
            last = {k: float(v) for k, v in _METRIC.findall(tail)}
            last["step"] = float(tail.split()[0].rstrip("K")) * (1000 if tail.split()[0].endswith("K") else 1)
    return last
