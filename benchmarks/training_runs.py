"""One benchmark training run, resumable stage by stage: ``lerobot-train`` (unless its checkpoint is there),
``sigma-eval`` closed loop (unless its results are there), ``sigma-diagnose`` on every checkpoint (those it has
already scored alike kept). Shared by the learning, demonstrations and suite benchmarks."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

from pipelines.training import TrainRun


def train_evaluate_diagnose(
    run: TrainRun, run_dir: Path, heldout_root: Path, tasks: list[str], label: str, **eval_options: Any
) -> dict:
    """Train ``run`` (its log and wall time in ``run_dir``), evaluate it on ``tasks`` (``eval_options``: further
    ``EvalConfig`` fields), then diagnose it on its training keyframes and on ``heldout_root``, all three on
    ``run.device``. The closed loop comes first because it is the measurement a GPU lease must bring back before
    its time ends (docs/gpu.md); the diagnosis can be redone on the CPU machine from the returned checkpoints.
    Returns ``train_seconds``, ``diagnostics`` and ``eval`` (the evaluation summary)."""
    from pipelines.diagnostics import DiagnoseConfig, run_diagnose
    from pipelines.evaluate import EvalConfig, run_eval

    seconds = train_unless_done(run, run_dir, label)
    results = run_dir / "eval" / "results.json"
    if results.exists():
        summary = json.loads(results.read_text())
    else:
        t0 = time.perf_counter()
        summary = run_eval(
            EvalConfig(
                checkpoint=run.checkpoint,
                tasks=tasks,
                train_dataset=run.dataset_root,
                output_dir=run_dir / "eval",
                device=run.device,
                **eval_options,
            )
        )
        print(f"{label}: evaluated in {time.perf_counter() - t0:.0f} s", flush=True)
    diagnostics = run_diagnose(
        DiagnoseConfig(run=run.output_dir, heldout_root=heldout_root, max_frames=200, device=run.device)
    )
    return {"train_seconds": seconds, "diagnostics": diagnostics, "eval": summary}


def train_unless_done(run: TrainRun, run_dir: Path, label: str) -> float:
    """Train ``run`` unless a finished run with the same options is there (resumed if interrupted); its log and
    wall time go to ``run_dir``. Returns the training's wall seconds."""
    from pipelines.training import train

    record = run_dir / "train_seconds.json"
    if run.reuse_or_clear(record, label) is None:
        print(f"{label}: lerobot-train {' '.join(run.extra_args)}", flush=True)
        _, seconds = train(run, log_path=run_dir / "train.log")
        record.write_text(json.dumps({"seconds": seconds}))
    return json.loads(record.read_text())["seconds"]


def collect_train_and_heldout(
    output_dir: Path,
    tasks: list[str],
    train_episodes: int,
    heldout_episodes: int,
    cameras: list[str],
    image_size: int,
    workers: int,
    name: str,
    pregrasp_jitter_m: float = 0.0,
) -> tuple[Path, Path]:
    """Keyframe datasets of training seeds (from 0) and held-out seeds (from 50000) under ``output_dir``/train and
    /heldout; a finished one is reused when it was collected with the same data options, and refused otherwise.
    ``pregrasp_jitter_m`` moves the experts' approach waypoints of the training seeds only: the held-out keyframes
    stay the experts' own. Returns the two dataset roots."""
    from pipelines.collecting import collect_demonstrations, demonstration_config
    from sigma_data.collect import option_changes

    roots = []
    for where, episodes, start in (("train", train_episodes, 0), ("heldout", heldout_episodes, 50_000)):
        out = output_dir / where
        done = out / "data" / "keyframe"
        args = (out, tasks, episodes, cameras, image_size, workers, f"local/{name}_{where}")
        options = {
            "dense": False,
            "start_seed": start,
            "pregrasp_jitter_m": pregrasp_jitter_m if where == "train" else 0.0,
        }
        if (done / "meta" / "info.json").exists():
            changes = option_changes(out / "data", demonstration_config(*args, **options))
            if changes:
                raise FileExistsError(
                    f"{out / 'data'} was collected with other options ({changes}): choose another --output_dir"
                )
        else:
            collect_demonstrations(*args, **options)
        roots.append(done)
    return roots[0], roots[1]
