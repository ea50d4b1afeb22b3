"""Checks along each episode: keyframe annotations (dense), goal links (keyframe), state continuity, language."""

from __future__ import annotations

from collections import Counter, defaultdict

import numpy as np

from sigma_data.contract import (
    ACTION,
    GRIPPER_OPEN_INDEX,
    IS_KEYFRAME,
    NEXT_KEYFRAME_INDEX,
    STATE,
    STATE_QUAT,
)
from sigma_data.validate.report import Checker, ValidationReport


def check_dense_keyframes(chk: Checker, cols: dict[str, np.ndarray], bounds: dict, cfg) -> None:
    flag_key, next_key = IS_KEYFRAME, NEXT_KEYFRAME_INDEX
    if flag_key not in cols or next_key not in cols:
        missing = flag_key if flag_key not in cols else next_key
        chk.add("keyframes.present", "error", "dense dataset without keyframe annotations", field=missing)
        return
    flags = cols[flag_key].reshape(-1).astype(bool)
    nxt = cols[next_key].reshape(-1).astype(np.int64)
    gripper = cols[STATE][:, GRIPPER_OPEN_INDEX]
    problems: dict[str, tuple] = {}
    counts = []
    for ep, (start, stop) in bounds.items():
        f, n, g = flags[start:stop], nxt[start:stop], gripper[start:stop]
        length = stop - start
        kfs = np.flatnonzero(f)
        counts.append(len(kfs))
        if len(kfs) == 0:
            problems.setdefault("keyframes.present", (ep, None, flag_key, "episode has no keyframe"))
            continue
        if not f[-1]:
            problems.setdefault(
                "keyframes.present", (ep, length - 1, flag_key, "final frame is not a keyframe")
            )
        idx = np.arange(length)
        bad_link = (
            (n < 0) | (n >= length) | ((n <= idx) & (idx != length - 1)) | ~f[np.clip(n, 0, length - 1)]
        )
        if bad_link.any():
            i = int(np.flatnonzero(bad_link)[0])
            problems.setdefault(
                "keyframes.links",
                (ep, i, next_key, f"next keyframe {int(n[i])} invalid in a {length}-frame episode"),
            )
        if not np.isin(np.unique(g), (0.0, 1.0)).all():
            problems.setdefault("keyframes.labels", (ep, None, STATE, "gripper_open not in {0, 1}"))
        for t in np.flatnonzero(np.diff(g) != 0) + 1:
            if np.abs(kfs - t).min() > cfg.gripper_tolerance:
                problems.setdefault(
                    "keyframes.gripper",
                    (
                        ep,
                        int(t),
                        flag_key,
                        f"gripper change with no keyframe within {cfg.gripper_tolerance} frames",
                    ),
                )
                break
    for name in ("keyframes.present", "keyframes.links", "keyframes.labels", "keyframes.gripper"):
        if name in problems:
            ep, frame, fld, detail = problems[name]
            chk.add(name, "error", detail, ep, frame, fld)
        else:
            chk.add(
                name, "ok", f"{np.mean(counts):.1f} keyframes per episode" if name.endswith("present") else ""
            )


def check_keyframe_goals(chk: Checker, cols: dict[str, np.ndarray], bounds: dict, cfg) -> None:
    action = cols[ACTION].astype(np.float64)
    state = cols[STATE].astype(np.float64)
    problems: dict[str, tuple] = {}
    for ep, (start, stop) in bounds.items():
        if stop - start < 2:
            problems.setdefault("goals.links", (ep, None, ACTION, "episode has fewer than 2 frames: no goal"))
            continue
        a, s = action[start:stop], state[start:stop]
        err = np.linalg.norm(a[:-1, :3] - s[1:, :3], axis=1)
        if (err > cfg.goal_tolerance_m).any():
            i = int(np.argmax(err > cfg.goal_tolerance_m))
            problems.setdefault(
                "goals.links",
                (ep, i, ACTION, f"action is {err[i] * 1000:.1f} mm from frame {i + 1}'s pose (its goal)"),
            )
        grip_mismatch = a[:-1, 7] != s[1:, 7]
        if grip_mismatch.any():
            i = int(np.argmax(grip_mismatch))
            problems.setdefault(
                "goals.links", (ep, i, ACTION, f"gripper_open differs from frame {i + 1}'s gripper state")
            )
    q = action[:, 3:7]
    norm = np.linalg.norm(q, axis=1)
    neg_w = q[:, 3] < 0
    eps = np.concatenate([np.full(stop - start, ep) for ep, (start, stop) in bounds.items()])

    def where(i: int) -> tuple[int, int]:  # (episode, frame within it) of dataset row i
        return int(eps[i]), i - chk.row_starts.get(int(eps[i]), 0)

    if (np.abs(norm - 1) > 1e-3).any():
        i = int(np.argmax(np.abs(norm - 1) > 1e-3))
        problems["goals.quaternion"] = (*where(i), ACTION, f"quaternion norm {norm[i]:.4f}, expected 1")
    elif neg_w.any():
        i = int(np.argmax(neg_w))
        problems["goals.quaternion"] = (*where(i), ACTION, "quaternion has w < 0 (contract: w >= 0)")
    flags = action[:, 7:9]
    if not np.isin(flags, (0.0, 1.0)).all():
        i = int(np.flatnonzero(~np.isin(flags, (0.0, 1.0)).all(axis=1))[0])
        problems["goals.flags"] = (*where(i), ACTION, "gripper_open / ignore_collision not in {0, 1}")
    for name in ("goals.links", "goals.quaternion", "goals.flags"):
        if name in problems:
            ep, frame, fld, detail = problems[name]
            chk.add(name, "error", detail, ep, frame, fld)
        else:
            chk.add(name, "ok", "")


def check_state_continuity(chk: Checker, cols: dict[str, np.ndarray], bounds: dict) -> None:
    """Consecutive frames of an episode: the eef quaternion keeps its hemisphere (q and -q are one rotation, but
    a policy reading the state sees a jump of up to 2 per component)."""
    q = cols[STATE][:, STATE_QUAT].astype(np.float64)
    flips = 0
    first = None
    for ep, (start, stop) in bounds.items():
        dots = np.einsum("ij,ij->i", q[start + 1 : stop], q[start : stop - 1])
        bad = np.flatnonzero(dots < 0)
        flips += len(bad)
        if len(bad) and first is None:
            first = (ep, int(bad[0]) + 1)
    if first is None:
        chk.add("state.continuity", "ok", "no quaternion sign flip inside an episode")
    else:
        chk.add(
            "state.continuity",
            "error",
            f"{flips} quaternion sign flip(s) between consecutive frames; first at frame {first[1]} of the episode",
            first[0],
            first[1],
            "observation.state[3:7]",
        )


def check_language(
    chk: Checker, ds, cols: dict[str, np.ndarray], bounds: dict, report: ValidationReport
) -> None:
    tasks = ds.meta.tasks  # DataFrame indexed by task string with a task_index column
    index_to_task = {int(i): str(t) for t, i in zip(tasks.index, tasks["task_index"], strict=True)}
    task_index = cols["task_index"].reshape(-1)
    missing = [i for i, t in enumerate(task_index) if not index_to_task.get(int(t), "").strip()]
    eps = cols["episode_index"].reshape(-1)
    if missing:
        i = missing[0]
        chk.at_row(
            "language.instruction",
            "error",
            f"{len(missing)} frames without an instruction",
            eps[i],
            i,
            "task",
        )
    else:
        chk.add("language.instruction", "ok", f"{len(index_to_task)} distinct instructions")
    per_instruction: Counter = Counter()
    episode_instructions: dict[int, set[str]] = {}
    for ep, (start, stop) in bounds.items():
        names = {index_to_task.get(int(t), "") for t in np.unique(task_index[start:stop])}
        episode_instructions[ep] = names
        per_instruction.update(names)
    report.instructions = dict(sorted(per_instruction.items()))
    few = [t for t, n in per_instruction.items() if n < 2]
    chk.add(
        "language.episodes",
        "warn" if few else "ok",
        f"episodes per instruction: min {min(per_instruction.values(), default=0)}, "
        f"max {max(per_instruction.values(), default=0)}"
        + (f"; {len(few)} with a single episode" if few else ""),
    )
    splits = ds.meta.info.splits or {}
    if len(splits) < 2:
        chk.add("language.splits", "skip", f"one split ({', '.join(splits) or 'none'}): nothing to compare")
        return
    split_of: dict[str, set[str]] = defaultdict(set)
    for split, spec in splits.items():
        lo, hi = (int(x) for x in str(spec).split(":"))
        for ep in range(lo, hi):
            for t in episode_instructions.get(ep, ()):
                split_of[t].add(split)
    only_one = sorted(f"{t!r} ({next(iter(s))})" for t, s in split_of.items() if len(s) == 1)
    chk.add(
        "language.splits",
        "warn" if only_one else "ok",
        ("instructions in one split only: " + "; ".join(only_one))
        if only_one
        else "every instruction in all splits",
    )
