"""``sigma-diagnose``: per-head errors of sigma checkpoints on keyframe datasets, and learning curves.

For every frame of a keyframe dataset that has a goal (all but the last frame of each episode) the checkpoint
predicts the next keyframe, deterministically (no augmentation, no render noise: what ``sigma-eval`` acts on),
and is compared with the recorded one, head by head (``pipelines/keyframe_errors.py``): translation (cm), rotation
(geodesic and per Euler axis, degrees), gripper and collision agreement.

Errors are summarised (median, mean, 90th percentile, share within 1 cm / 2 cm / 10° / 20°) over the whole set and per
keyframe step (frame k of an episode predicts its keyframe k + 1: for Lift step 0 is the pre-grasp pose, 1 the
grasp, 2 the close, 3 the lift), which tells *where* a policy fails; on a dataset sigma collected (its
``meta/sigma.json`` names each episode's task) also per task, with each task's steps, which tells *which* task of a
multi-task policy fails, and, where a task has several variations (PickPlace's four objects), per variation: the
summary line gives each variation's first keyframe, which tells which instruction a policy has not learned (one
PickPlace checkpoint reached the milk and the cereal within 2 cm and went to another object for the bread and the
can; docs/learning.md).

**Instruction swap** (``pipelines/instruction_swap.py``): on the scenes sigma recorded under several instructions
(same task and seed), the prediction from each start frame under each instruction should land at that instruction's
target: ``swap_nearest``, ``swap_trans_cm_median`` and ``swap_spread``, over the first 10 seeds
(``--swap_scenes_per_task``) of every task that has such scenes, and per task (a suite's tasks differ: after 6000
steps one checkpoint followed the instruction in every NutAssembly scene and in 64% of its own training PickPlace
scenes).

**Gripper swap** (``pipelines/gripper_swap.py``): where the gripper closes or opens in place, the two frames before
and after see nearly the same scene and have different targets; swapping their gripper state should move the
prediction to the other frame's target: ``gripper_swap_follow`` and ``gripper_swap_spread`` over the first 20 such
pairs (``--gripper_pairs_per_task``) of every task, and per task (two of three Lift + Stack policies trained with
other seeds ignored the gripper state on Stack, and scored 48/90 against 82/90; docs/learning.md).

Pointed at a ``lerobot-train`` output directory, it diagnoses every saved checkpoint (``checkpoints/<step>/``) on
the training keyframes and on held-out keyframes, and writes learning curves: ``diagnostics.json`` (every number),
``curves.png`` and ``curves.rrd`` (Rerun scalars, one entity per metric; ``pipelines/curves.py``). Held-out
keyframes are either another dataset (``--heldout_root``, e.g. collected with other seeds) or the episodes of the
training dataset that the run did not train on (``--dataset.episodes`` in its ``train_config.json``). A rerun keeps
the scores ``diagnostics.json`` holds for the same weights (by their SHA-256), scoring options and data (the
datasets' roots, the episodes trained on and a digest of each dataset's ``meta/``, which changes when a dataset is
collected again), so a run that has saved more checkpoints since is scored only on the new ones (``--reuse false``
scores every one again).

Example::

    sigma-diagnose --run outputs/train --heldout_root outputs/heldout/keyframe
    sigma-diagnose --checkpoint outputs/train/checkpoints/last/pretrained_model --root outputs/data/keyframe
"""

from __future__ import annotations

import json
import os
import sys
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import draccus
import numpy as np

from pipelines.curves import log_curves_rerun, plot_curves
from pipelines.gripper_swap import gripper_pairs, gripper_swap
from pipelines.instruction_swap import instruction_swap, swap_scenes
from pipelines.keyframe_errors import METRICS, action_errors, split_summaries, summaries
from pipelines.keyframe_sets import KeyframeSet, goal_rows, keyframe_sets, row_labels, scored_data
from sigma_data.files import sha256, write_json_atomic


@dataclass
class DiagnoseConfig:
    """Options of ``sigma-diagnose`` (give ``--run`` or ``--checkpoint``)."""

    # A lerobot-train output directory: every checkpoint under checkpoints/ is diagnosed (learning curves).
    run: Path | None = None
    # One pretrained_model directory (instead of --run).
    checkpoint: Path | None = None
    # The training keyframe dataset (default: the one recorded in the checkpoint's train_config.json).
    root: Path | None = None
    # Held-out keyframes: another keyframe dataset (default: the training dataset's episodes not trained on).
    heldout_root: Path | None = None
    # At most this many frames per set (evenly spaced; 0 = all).
    max_frames: int = 200
    batch_size: int = 16
    # Scenes per task in the instruction swap (the first seeds recorded under several instructions).
    swap_scenes_per_task: int = 10
    # Pairs per task in the gripper swap (the first frames where the gripper closes or opens in place).
    gripper_pairs_per_task: int = 20
    device: str = "cpu"
    # For checkpoints trained with a weight average (the policy's `ema_decay`): diagnose the average (true) or the
    # trained weights (false); None: what the checkpoint acts with (the average).
    act_with_ema: bool | None = None
    # How the views' heatmaps fuse into the predicted point (the policy's `heatmap_fusion`: sum or product,
    # sigma_policy/heatmap.py); None: the checkpoint's own.
    heatmap_fusion: str | None = None
    # Where diagnostics.json, curves.png and curves.rrd go (default: <run>/diagnostics or <checkpoint>/..).
    output_dir: Path | None = None
    # Keep the scores of checkpoints that diagnostics.json already holds for the same weights (by content), scoring
    # options and data (keyframe_sets.scored_data), and score only the others: a rerun on a run that saved more
    # checkpoints, or a benchmark republishing finished runs, costs only what is new. false: score every one again.
    reuse: bool = True


# ---------------------------------------------------------------------------------------------- predict


def predict_rows(policy: Any, pre: Any, kf: KeyframeSet, batch_size: int) -> tuple[np.ndarray, np.ndarray]:
    """(predicted, recorded) actions ``(N, 9)`` for the rows of ``kf``."""
    import torch

    preds, trues = [], []
    for start in range(0, len(kf.indices), batch_size):
        items = [kf.dataset[i] for i in kf.indices[start : start + batch_size]]
        batch: dict[str, Any] = {}
        for key in items[0]:
            if key.startswith("observation.") or key == "action":
                batch[key] = torch.stack([it[key] for it in items])
        batch["task"] = [it["task"] for it in items]
        trues.append(batch["action"].numpy())
        with torch.inference_mode():
            preds.append(policy.predict(pre(batch)).action.float().cpu().numpy())
    return np.concatenate(preds), np.concatenate(trues)


def diagnose_checkpoint(
    policy: Any, pre: Any, sets: list[KeyframeSet], batch_size: int = 16
) -> dict[str, dict[str, Any]]:
    """Per set: the overall summary, one per keyframe step and, on a sigma-collected dataset, the same per task
    (``per_task``: {task: {"all", "per_step"}}) and, where a task has several variations, per variation
    (``per_variation``: {variation: {"all", "per_step"}}); the instruction swap where the set has its scenes."""
    out: dict[str, dict[str, Any]] = {}
    for kf in sets:
        pred, true = predict_rows(policy, pre, kf, batch_size)
        err = action_errors(pred, true)
        out[kf.name] = summaries(err, kf.steps)
        labels = row_labels(kf.dataset, kf.indices)
        if labels is not None:
            tasks, variations = labels["task"], labels["variation"]
            out[kf.name]["per_task"] = split_summaries(err, kf.steps, tasks)
            if len(set(variations.tolist())) > len(set(tasks.tolist())):  # some task has several variations
                out[kf.name]["per_variation"] = split_summaries(err, kf.steps, variations)
        if kf.swap:
            out[kf.name]["swap"] = instruction_swap(policy, pre, kf.dataset, kf.swap)
        if kf.gripper:
            out[kf.name]["gripper_swap"] = gripper_swap(policy, pre, kf.dataset, kf.gripper)
    return out


# ---------------------------------------------------------------------------------------------- runs


def run_checkpoints(run_dir: Path) -> list[tuple[int, Path]]:
    """(step, pretrained_model dir) of every numbered checkpoint of a ``lerobot-train`` output directory."""
    ckpts = []
    for d in sorted((Path(run_dir) / "checkpoints").glob("*")):
        if d.name.isdigit() and (d / "pretrained_model" / "config.json").exists():
            ckpts.append((int(d.name), d / "pretrained_model"))
    if not ckpts:
        raise FileNotFoundError(f"{run_dir}/checkpoints has no numbered checkpoint with a pretrained_model")
    return ckpts


# Options that do not change a checkpoint's scores: what is scored (its weights are keyed by content), how fast,
# and where the report goes. Every other option of DiagnoseConfig is part of a saved score's key.
NOT_SCORING = frozenset({"run", "checkpoint", "batch_size", "device", "output_dir", "reuse"})


def scoring_options(cfg: DiagnoseConfig, acting_fusion: str = "sum") -> dict[str, Any]:
    """The options that change a checkpoint's scores (every field but ``NOT_SCORING``), paths as strings; the
    heatmap fusion is the one the checkpoints act with (``acting_fusion``) unless ``--heatmap_fusion`` is given."""
    values = {f.name: getattr(cfg, f.name) for f in fields(cfg) if f.name not in NOT_SCORING}
    if values["heatmap_fusion"] is None:
        values["heatmap_fusion"] = acting_fusion
        if acting_fusion == "sum":  # reports written before the option keep matching
            del values["heatmap_fusion"]
    return {name: str(v) if isinstance(v, Path) else v for name, v in values.items()}


def saved_scores(path: Path, options: dict[str, Any]) -> tuple[dict[str, int], dict[tuple[int, str], dict]]:
    """The set sizes and the checkpoint entries, keyed by (step, weights SHA-256), of the report at ``path`` when it
    was written with the same ``options``; nothing otherwise (no report, another version's or other options)."""
    try:
        saved = json.loads(path.read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return {}, {}
    if saved.get("options") != options:
        return {}, {}
    entries = {(c["step"], c["weights_sha256"]): c for c in saved["checkpoints"] if "weights_sha256" in c}
    return saved["sets"], entries


def run_diagnose(cfg: DiagnoseConfig) -> dict[str, Any]:
    """Diagnose one checkpoint or every checkpoint of a run (those already scored alike kept, ``cfg.reuse``); write
    the report, whole or not at all; return it."""
    from tqdm import tqdm

    from pipelines.checkpoints import check_act_with_ema, load_policy

    if (cfg.run is None) == (cfg.checkpoint is None):
        raise ValueError("give exactly one of --run (a lerobot-train output dir) or --checkpoint")
    if cfg.heatmap_fusion is not None:
        from sigma_policy.heatmap import check_heatmap_fusion

        check_heatmap_fusion(cfg.heatmap_fusion, "--heatmap_fusion")
    ckpts = run_checkpoints(cfg.run) if cfg.run is not None else [(-1, Path(cfg.checkpoint))]
    out_dir = cfg.output_dir or (
        Path(cfg.run) / "diagnostics" if cfg.run else Path(cfg.checkpoint).parent / "diagnostics"
    )
    out_dir.mkdir(parents=True, exist_ok=True)
    from sigma_policy.configuration_sigma import SigmaConfig

    options = {
        **scoring_options(cfg, SigmaConfig.from_pretrained(ckpts[-1][1]).heatmap_fusion),
        "data": scored_data(ckpts[-1][1], cfg.root, cfg.heldout_root),
    }
    sizes, saved = saved_scores(out_dir / "diagnostics.json", options) if cfg.reuse else ({}, {})
    digests = [sha256(ckpt / "model.safetensors") for _, ckpt in ckpts]
    todo = [(step, ckpt, d) for (step, ckpt), d in zip(ckpts, digests, strict=True) if (step, d) not in saved]
    if todo:
        sets = keyframe_sets(ckpts[-1][1], cfg.root, cfg.heldout_root, cfg.max_frames)
        for kf in sets:
            kf.swap = swap_scenes(kf.dataset, kf.episodes, cfg.swap_scenes_per_task)
            # every goal frame: the thinned set has few neighbours
            rows, _ = goal_rows(kf.dataset, kf.episodes)
            labels = row_labels(kf.dataset, rows, ("task",))
            tasks = labels["task"].tolist() if labels is not None else ["unknown"] * len(rows)
            kf.gripper = gripper_pairs(kf.dataset, rows, tasks, cfg.gripper_pairs_per_task)
        sizes = {s.name: len(s.indices) for s in sets}
    if len(todo) < len(ckpts):
        print(
            f"sigma-diagnose: {len(ckpts) - len(todo)} of {len(ckpts)} checkpoints already scored in {out_dir}"
        )
    for step, ckpt, digest in tqdm(todo, desc="sigma-diagnose", unit="checkpoint"):
        if cfg.act_with_ema is not None:
            check_act_with_ema(ckpt)
        policy, pre, _ = load_policy(ckpt, cfg.device)
        if cfg.act_with_ema is not None:
            policy.config.act_with_ema = cfg.act_with_ema
        if cfg.heatmap_fusion is not None:
            policy.config.heatmap_fusion = cfg.heatmap_fusion
        scores = diagnose_checkpoint(policy, pre, sets, cfg.batch_size)
        saved[step, digest] = {"step": step, "weights_sha256": digest, **scores}
    entries = [{**saved[step, d], "path": str(ckpt)} for (step, ckpt), d in zip(ckpts, digests, strict=True)]
    report: dict[str, Any] = {"options": options, "sets": sizes, "checkpoints": entries}
    curves = {
        "steps": [c["step"] for c in entries],
        "sets": {name: {m: [c[name]["all"][m] for c in entries] for m in METRICS} for name in sizes},
    }
    for name in sizes:
        if all("swap" in c[name] for c in entries):
            curves["sets"][name]["swap_nearest"] = [c[name]["swap"]["swap_nearest"] for c in entries]
    report["curves"] = curves
    write_json_atomic(out_dir / "diagnostics.json", report, indent=2)
    if len(ckpts) > 1:
        plot_curves(curves, out_dir / "curves.png")
        log_curves_rerun(curves, out_dir / "curves.rrd")
    report["output_dir"] = str(out_dir)
    return report


def _share_text(label: str, result: dict[str, Any], share: str, count: int, unit: str) -> str:
    """``", <label> 80% (<count> <unit>: a 70%, b 90%)"``: a swap check's ``share`` overall and per task."""
    by_task = ", ".join(f"{t} {100 * v[share]:.0f}%" for t, v in result.get("per_task", {}).items())
    return f", {label} {100 * result[share]:.0f}% ({count} {unit}" + (f": {by_task})" if by_task else ")")


def summary_line(report: dict[str, Any]) -> str:
    last = report["checkpoints"][-1]
    parts = []
    for name in report["sets"]:
        a = last[name]["all"]
        parts.append(
            f"{name}: {a['trans_cm_median']:.2f} cm, {a['rot_deg_median']:.1f} deg, "
            f"gripper {100 * a['gripper_acc']:.0f}% ({a['frames']} frames)"
        )
        per_task = last[name].get("per_task", {})
        if len(per_task) > 1:
            parts[-1] += (
                " ["
                + ", ".join(f"{t} {v['all']['trans_cm_median']:.2f} cm" for t, v in per_task.items())
                + "]"
            )
        first = {v: s["per_step"].get("0") for v, s in last[name].get("per_variation", {}).items()}
        if any(first.values()):
            parts[-1] += (
                " [first keyframe: "
                + ", ".join(
                    f"{v} {f['trans_cm_median']:.1f} cm {f['rot_deg_median']:.0f} deg"
                    for v, f in first.items()
                    if f
                )
                + "]"
            )
        swap = last[name].get("swap")
        if swap:
            parts[-1] += _share_text("instruction swap", swap, "swap_nearest", swap["swap_scenes"], "scenes")
            if swap.get("swap_spread") is not None:
                parts[-1] += f", spread {swap['swap_spread']:.2f}"
        grip = last[name].get("gripper_swap")
        if grip:
            parts[-1] += _share_text(
                "gripper swap", grip, "gripper_swap_follow", grip["gripper_swap_pairs"], "pairs"
            )
    step = last["step"]
    at = f"step {step}" if step >= 0 else "checkpoint"
    return f"sigma-diagnose: {at}: " + "; ".join(parts) + f" -> {report['output_dir']}"


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    cfg = draccus.parse(DiagnoseConfig, args=sys.argv[1:] if argv is None else argv)
    report = run_diagnose(cfg)
    print(summary_line(report))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
