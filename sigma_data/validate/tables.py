"""Checks of the tables: features and shapes, rows against ``meta/episodes``, finite and plausible values."""

from __future__ import annotations

import numpy as np

from sigma_data.contract import (
    ACTION,
    DENSE_ACTION_DIM,
    IS_DEPTH_MAP,
    KEYFRAME_ACTION_DIM,
    STATE,
    STATE_DIM,
    WORKSPACE_LIMIT_M,
    depth_key,
    extrinsics_key,
    implausible_state,
    intrinsics_key,
)
from sigma_data.validate.report import Checker


def check_structure(chk: Checker, features: dict, cameras: list[str], kind: str) -> bool:
    ok = True
    expect = {STATE: (STATE_DIM,)}
    if kind in ("dense", "keyframe"):
        expect[ACTION] = (DENSE_ACTION_DIM,) if kind == "dense" else (KEYFRAME_ACTION_DIM,)
    for cam in cameras:
        expect[intrinsics_key(cam)] = (3, 3)
        expect[extrinsics_key(cam)] = (4, 4)
    for key, shape in expect.items():
        if key not in features:
            chk.add("structure", "error", "missing feature", field=key)
            ok = False
        elif tuple(features[key]["shape"]) != shape:
            chk.add(
                "structure", "error", f"shape {tuple(features[key]['shape'])}, expected {shape}", field=key
            )
            ok = False
    if kind == "unknown":
        chk.add(
            "structure", "error", "cannot tell dense (7-D action) from keyframe (9-D action)", field=ACTION
        )
        ok = False
    if not cameras:
        chk.add("structure", "error", "no RGB camera features observation.images.<cam>")
        ok = False
    depth_keys = [depth_key(cam) for cam in cameras]
    rgb_only = kind == "dense" and not any(key in features for key in depth_keys)
    for key in [] if rgb_only else depth_keys:
        if key not in features:
            chk.add("structure", "error", "missing depth feature", field=key)
            ok = False
        elif not features[key].get("info", {}).get(IS_DEPTH_MAP):
            chk.add("structure", "error", "depth feature lacks info.is_depth_map=True", field=key)
            ok = False
    if ok:
        what = "RGB cameras (RGB-only dense: no depth)" if rgb_only else "RGB-D cameras"
        chk.add("structure", "ok", f"{kind} dataset, {len(cameras)} {what} with calibration")
    return ok


def check_rows(chk: Checker, ds, cols: dict[str, np.ndarray], bounds: dict) -> None:
    """Every episode's rows are its frames 0..n-1, as many as ``meta/episodes`` says (a lost row makes stock
    LeRobot index past the episode's end)."""
    frame_index = cols["frame_index"].reshape(-1)
    meta = {
        int(e["episode_index"]): int(e["length"])
        for e in ds.meta.episodes.select_columns(["episode_index", "length"])
    }
    problems = []
    for ep, (start, stop) in bounds.items():
        got = frame_index[start:stop]
        expected = meta.get(ep)
        if expected is None:
            problems.append((ep, None, f"rows of episode {ep}, which meta/episodes does not list"))
        elif stop - start != expected:
            problems.append(
                (ep, None, f"{stop - start} rows in data/, {expected} in meta/episodes (rows lost or added)")
            )
        elif not np.array_equal(got, np.arange(stop - start)):
            i = int(np.flatnonzero(got != np.arange(stop - start))[0])
            problems.append(
                (ep, i, f"frame_index {int(got[i])} where {i} was expected (rows missing or out of order)")
            )
    missing = sorted(set(meta) - set(bounds))
    if missing:
        problems.append(
            (missing[0], None, f"{len(missing)} episode(s) listed in meta/episodes have no rows in data/")
        )
    if len(frame_index) != ds.meta.total_frames and not problems:
        problems.append(
            (None, None, f"{len(frame_index)} rows, meta/info.json says {ds.meta.total_frames} frames")
        )
    if problems:
        ep, frame, detail = problems[0]
        more = f" (+{len(problems) - 1} more episodes)" if len(problems) > 1 else ""
        chk.add("rows.count", "error", detail + more, ep, frame, "frame_index")
    else:
        chk.add("rows.count", "ok", f"{len(frame_index)} rows = the frames meta/episodes lists")


def check_finite(chk: Checker, cols: dict[str, np.ndarray]) -> None:
    """No NaN or inf in the state or the action (the first offending row of each is reported)."""
    eps = cols["episode_index"].reshape(-1)
    for key in (STATE, ACTION):
        bad = ~np.isfinite(cols[key]).all(axis=1)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            chk.at_row("values.finite", "error", "NaN or inf", eps[i], i, key)


def check_plausible(
    chk: Checker, cols: dict[str, np.ndarray], bounds: dict, kind: str, fps: float, cfg
) -> None:
    """Physical plausibility: positions inside a generous workspace, unit state quaternions, finger joints in
    range, a dense episode's end effector no faster than ``max_eef_speed``, dense actions inside the OSC input
    range (robosuite clips it to [-1, 1])."""
    state = cols[STATE].astype(np.float64)
    action = cols[ACTION].astype(np.float64)
    eps = cols["episode_index"].reshape(-1)
    limit = WORKSPACE_LIMIT_M
    found: list[tuple] = []
    for i in np.flatnonzero(np.isfinite(state).all(axis=1)):  # values.finite reports the others
        problem = implausible_state(state[i])
        if problem:
            found.append((int(i), STATE, problem))
            break
    if kind == "keyframe":
        with np.errstate(invalid="ignore"):
            far_goal = np.abs(action[:, :3]).max(axis=1) > limit
        if far_goal.any():
            i = int(np.flatnonzero(far_goal)[0])
            found.append(
                (i, ACTION, f"keyframe at {np.round(action[i, :3], 3).tolist()} m, beyond {limit} m")
            )
    else:
        for start, stop in bounds.values():
            speed = np.linalg.norm(np.diff(state[start:stop, :3], axis=0), axis=1) * fps
            if (speed > cfg.max_eef_speed).any():
                t = int(np.flatnonzero(speed > cfg.max_eef_speed)[0]) + 1
                found.append(
                    (
                        start + t,
                        STATE,
                        f"end effector moves {speed[t - 1]:.3g} m/s into this frame "
                        f"(limit {cfg.max_eef_speed} m/s at {fps:g} fps)",
                    )
                )
                break
    for i, key, detail in found:
        chk.at_row("values.plausible", "error", detail, eps[i], i, key)
    if kind == "dense":
        with np.errstate(invalid="ignore"):
            outside = np.abs(action[:, :6]).max(axis=1) > 1 + 1e-6
        if outside.any():
            i = int(np.flatnonzero(outside)[0])
            chk.at_row(
                "values.action_range",
                "warn",
                f"{int(outside.sum())} dense actions outside the OSC input range "
                f"[-1, 1] (robosuite clips them): {np.round(action[i], 3).tolist()}",
                eps[i],
                i,
                ACTION,
            )
    if not found:
        chk.add(
            "values.plausible", "ok", f"positions within {limit} m, unit quaternions, finger joints in range"
        )
