"""The instruction-swap check: does the language, and nothing else, move the first keyframe?

sigma collects every variation of a task from the same seeds, and a seed fixes the scene, so the start frames of
e.g. "stack the red cube on the green cube" and "stack the green cube on the red cube" with one seed are the same
scene with different first targets (``meta/sigma.json`` records each episode's task, seed and instruction). For
each such scene and each of its instructions a checkpoint predicts from that one observation; the prediction should
land at that instruction's target, nearer to it than to any other instruction's. Reported:

* ``swap_nearest``: share of predictions nearest their own target (1 = follows the language, 1 / variations =
  ignores it);
* ``swap_trans_cm_median``: median distance from each prediction to its own target;
* ``swap_went_to``: per instructed variation, how often the prediction landed nearest each variation's target
  (which object "bread" takes the policy to);
* ``swap_spread``: how far apart one scene's predictions under its instructions are, over how far apart their
  targets are, median over scenes. 1 = the instruction moves the prediction as far as it moves the target, 0 = the
  same prediction whatever the instruction; so a low ``swap_nearest`` with a high spread is a wrong choice, with a
  low one the instruction ignored.

``sigma-diagnose`` (``pipelines/diagnostics.py``) runs it on the training and held-out keyframes of every
checkpoint, and ``benchmarks/bench_identity.py`` probes the same scenes' features.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sigma_data.contract import SIDECAR, read_sidecar


@dataclass
class SwapScene:
    """One scene (task, seed) seen under several instructions: the start-frame row and first target of each."""

    task: str
    seed: int
    rows: list[int]
    instructions: list[str]
    targets: np.ndarray  # (I, 3) first keyframe position per instruction
    # the variation each instruction names (the instruction itself where none is recorded)
    variations: list[str]


def swap_scenes(dataset: Any, episodes: list[int] | None = None, per_task: int = 10) -> list[SwapScene]:
    """Scenes of ``dataset`` (its ``episodes``; None = all) recorded under more than one instruction (same task and
    seed): the first ``per_task`` seeds of every task that has them, so each multi-instruction task of a suite is
    represented."""
    root = Path(dataset.root)
    if not (root / SIDECAR).exists():
        return []  # not collected by sigma: no seeds to pair scenes by
    groups: dict[tuple[str, int], list[dict]] = {}
    wanted = None if episodes is None else set(episodes)
    for ep in read_sidecar(root).get("episodes", []):
        if wanted is not None and ep["episode_index"] not in wanted:
            continue
        if ep.get("seed") is not None and not ep.get("chain_start"):
            groups.setdefault((ep["task"], int(ep["seed"])), []).append(ep)
    starts = dataset.meta.episodes["dataset_from_index"]
    scenes: list[SwapScene] = []
    taken: dict[str, int] = {}
    for (task, seed), eps in sorted(groups.items()):
        if len({e["instruction"] for e in eps}) < 2 or taken.get(task, 0) == per_task:
            continue
        taken[task] = taken.get(task, 0) + 1
        rows = [int(starts[e["episode_index"]]) for e in eps]
        targets = np.stack([dataset[r]["action"][:3].numpy() for r in rows])
        instructions = [e["instruction"] for e in eps]
        variations = [e.get("variation", e["instruction"]) for e in eps]
        scenes.append(SwapScene(task, seed, rows, instructions, targets, variations))
    return scenes


def instruction_swap(policy: Any, pre: Any, dataset: Any, scenes: list[SwapScene]) -> dict[str, Any]:
    """Predict every scene of ``dataset`` under each of its instructions (see the module docstring); overall and,
    with scenes of more than one task, per task (``per_task``: {task: {"swap_scenes", "swap_nearest",
    "swap_spread"}}). ``swap_went_to`` counts, per instructed variation, the variations whose targets the
    predictions landed nearest: ``{"bread": {"bread": 4, "can": 6}}`` says where "bread" takes the policy."""
    import torch

    nearest, errors, tasks, spreads = [], [], [], []
    went_to: dict[str, Counter] = {}
    for scene in scenes:
        item = dataset[scene.rows[0]]
        obs = {k: v[None] for k, v in item.items() if k.startswith("observation.")}
        predicted = []
        for i, instruction in enumerate(scene.instructions):
            with torch.inference_mode():
                pos = policy.predict(pre(obs | {"task": [instruction]})).action[0, :3].float().cpu().numpy()
            dist = np.linalg.norm(scene.targets - pos, axis=-1)
            landed = int(np.argmin(dist))
            nearest.append(landed == i)
            went_to.setdefault(scene.variations[i], Counter())[scene.variations[landed]] += 1
            errors.append(100 * dist[i])
            tasks.append(scene.task)
            predicted.append(pos)
        apart = mean_pairwise_distance(scene.targets)
        spreads.append(mean_pairwise_distance(np.stack(predicted)) / apart if apart > 1e-3 else np.nan)
    if not nearest:
        return {}
    out: dict[str, Any] = {
        "swap_scenes": len(scenes),
        "swap_nearest": float(np.mean(nearest)),
        "swap_trans_cm_median": float(np.median(errors)),
        "swap_spread": _median_or_none(spreads),
        "swap_went_to": {v: dict(sorted(c.items())) for v, c in sorted(went_to.items())},
    }
    if len(set(tasks)) > 1:
        hit, of = np.asarray(nearest), np.asarray(tasks)
        scene_tasks, spread = np.asarray([s.task for s in scenes]), np.asarray(spreads)
        out["per_task"] = {
            t: {
                "swap_scenes": int((scene_tasks == t).sum()),
                "swap_nearest": float(hit[of == t].mean()),
                "swap_spread": _median_or_none(spread[scene_tasks == t]),
            }
            for t in sorted(set(tasks))
        }
    return out


def _median_or_none(values: Any) -> float | None:
    """Median of the finite ``values``; None (JSON null) when there are none."""
    finite = np.asarray(values, dtype=float)
    finite = finite[np.isfinite(finite)]
    return float(np.median(finite)) if finite.size else None


def mean_pairwise_distance(points: np.ndarray) -> float:
    """Mean distance between the rows of ``points`` (N, 3), over every pair; 0 for fewer than two."""
    if len(points) < 2:
        return 0.0
    i, j = np.triu_indices(len(points), k=1)
    return float(np.linalg.norm(points[i] - points[j], axis=-1).mean())
