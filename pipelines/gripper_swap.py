"""The gripper-swap check: does the gripper's state, and not only the images, place the next keyframe?

Where the gripper closes or opens in place, two consecutive keyframes of an episode see nearly the same scene and
have different targets: open at the grasp, the next keyframe closes the gripper there; closed on the object, the
next one lifts it. What tells the two apart is the gripper: its entries of ``observation.state``
(``gripper_open``, ``finger_q1``, ``finger_q2``; sigma_data/contract.py) and the fingers' few pixels. For each such
pair of frames the check swaps their gripper entries, keeps everything else, and predicts again. Reported:

* ``gripper_swap_follow``: share of the swapped predictions that land nearer the other frame's target than their
  own (1 = the state decides the stage; 0 = the images do);
* ``gripper_swap_spread``: how far the swap moves a prediction over how far apart the two targets are, median
  over predictions (1 = as far as the targets, 0 = not at all);
* ``gripper_swap_pairs``, and the same per task where the pairs come from more than one.

Of three `small` policies trained on the same Lift + Stack data with seeds 0-2, the two that scored 48/90 in closed
loop did not move their Stack predictions at all (spread 0), and the one that scored 82/90 moved every one to the
other stage (docs/learning.md "The demo's policy across training draws"). ``sigma-diagnose``
(``pipelines/diagnostics.py``) runs it on the training and held-out keyframes of every checkpoint.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from typing import Any

import numpy as np

from sigma_data.contract import ACTION, GRIPPER_OPEN_INDEX, STATE

# The gripper's entries of observation.state: gripper_open and the two finger joints after it.
GRIPPER_STATE = slice(GRIPPER_OPEN_INDEX, GRIPPER_OPEN_INDEX + 3)
# A pair's two frames: the hand within this distance of itself (the gripper changed in place) ...
IN_PLACE_M = 0.01
# ... and targets at least this far apart (a swap that cannot move the target tells nothing).
TARGETS_APART_M = 0.02


@dataclass
class GripperPair:
    """Two consecutive goal frames of one episode, before and after the gripper changed in place."""

    rows: tuple[int, int]
    task: str


def gripper_pairs(dataset: Any, rows: list[int], tasks: list[str], per_task: int = 20) -> list[GripperPair]:
    """The first ``per_task`` pairs per task among ``rows`` (goal frames, in dataset order, with their ``tasks``):
    rows ``r`` and ``r + 1`` of one episode whose ``gripper_open`` differs, whose hands lie within
    :data:`IN_PLACE_M` and whose targets lie :data:`TARGETS_APART_M` or more apart."""
    data = dataset.hf_dataset.select_columns([STATE, ACTION, "episode_index", "index"])
    position = {int(i): p for p, i in enumerate(data["index"])}
    states = np.stack([np.asarray(v) for v in data[STATE]])
    targets = np.stack([np.asarray(v)[:3] for v in data[ACTION]])
    episodes = np.asarray(data["episode_index"])
    task_of = dict(zip(rows, tasks, strict=True))
    pairs: list[GripperPair] = []
    taken: dict[str, int] = defaultdict(int)
    for r in rows:
        if r + 1 not in task_of or taken[task_of[r]] == per_task:
            continue
        a, b = position[r], position[r + 1]
        if (
            episodes[a] == episodes[b]
            and states[a, GRIPPER_OPEN_INDEX] != states[b, GRIPPER_OPEN_INDEX]
            and np.linalg.norm(states[a, :3] - states[b, :3]) <= IN_PLACE_M
            and np.linalg.norm(targets[a] - targets[b]) >= TARGETS_APART_M
        ):
            pairs.append(GripperPair((r, r + 1), task_of[r]))
            taken[task_of[r]] += 1
    return pairs


def gripper_swap(policy: Any, pre: Any, dataset: Any, pairs: list[GripperPair]) -> dict[str, Any]:
    """Predict both frames of every pair with their own and with each other's gripper state (module docstring);
    overall and, with pairs of more than one task, per task. ``{}`` without pairs."""
    import torch

    follow, spread, tasks = [], [], []
    for pair in pairs:
        items = [dataset[r] for r in pair.rows]
        batch = {
            k: torch.stack([it[k] for it in items] * 2) for k in items[0] if k.startswith("observation.")
        }
        batch[STATE] = batch[STATE].clone()
        batch[STATE][2:, GRIPPER_STATE] = batch[STATE][[1, 0], GRIPPER_STATE]  # rows 2-3: the other's gripper
        batch["task"] = [it["task"] for it in items] * 2
        with torch.inference_mode():
            pred = policy.predict(pre(batch)).action[:, :3].float().cpu().numpy()
        targets = np.stack([it[ACTION][:3].numpy() for it in items])
        apart = np.linalg.norm(targets[0] - targets[1])
        for own in (0, 1):
            swapped = pred[2 + own]
            follow.append(np.linalg.norm(swapped - targets[1 - own]) < np.linalg.norm(swapped - targets[own]))
            spread.append(np.linalg.norm(swapped - pred[own]) / apart)
            tasks.append(pair.task)
    if not follow:
        return {}
    out: dict[str, Any] = {
        "gripper_swap_pairs": len(pairs),
        "gripper_swap_follow": float(np.mean(follow)),
        "gripper_swap_spread": float(np.median(spread)),
    }
    if len(set(tasks)) > 1:
        hit, moved, of = np.asarray(follow), np.asarray(spread), np.asarray(tasks)
        out["per_task"] = {
            t: {
                "gripper_swap_pairs": int((of == t).sum()) // 2,
                "gripper_swap_follow": float(hit[of == t].mean()),
                "gripper_swap_spread": float(np.median(moved[of == t])),
            }
            for t in sorted(set(tasks))
        }
    return out
