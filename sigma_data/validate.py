"""Check a sigma dataset (dense or keyframe) against the data contract of ``docs/data_contract.md``.

The dataset is opened with stock ``LeRobotDataset`` (so a pass also proves LeRobot can read it); numeric columns
are read whole from the parquet rows, images are sampled (``frames_per_episode`` per episode) because decoding
every video frame is the expensive part. Every check yields one row, ``ok``/``warn``/``error``/``skip``, with
the first offending episode, frame and field; ``errors`` make ``sigma-data validate`` exit non-zero.

Checks (names as printed):

* ``structure``: state/action/camera features exist with the contract's shapes; depth features flagged.
* ``rows.count``: each episode's rows are its frames 0..n-1, as many as ``meta/episodes`` lists.
* ``values.finite``, ``values.plausible``: no NaN/inf; positions within 5 m of the origin, unit state
  quaternions, finger joints in range, dense end-effector speed below ``max_eef_speed``;
  ``values.action_range`` warns about dense actions outside robosuite's [-1, 1] OSC input.
* ``images.decode``: the sampled frames of every camera stream decode (the first failure names its frame).
* ``depth.unit``, ``depth.range``, ``depth.invalid``: depth in metres (LeRobot's ``depth_unit``, plausible
  values), inside ``depth_range``, and at most ``max_invalid_depth`` of the pixels <= 0 or non-finite.
* ``intrinsics``: positive focal lengths, last row (0, 0, 1), principal point inside the image, near its centre.
* ``extrinsics``: rotation orthonormal with det +1, last row (0, 0, 0, 1).
* ``eef.projection``: the end-effector projects inside every fixed camera's image.
* ``keyframes.*`` (dense): keyframes present, the final frame one of them, next-keyframe links forward and inside
  the episode, and every gripper change within ``gripper_tolerance`` frames of a keyframe.
* ``goals.*`` (keyframe): each action is the next frame's pose (the goal link stays inside the episode),
  quaternions unit with w >= 0, flags binary.
* ``state.continuity``: the state's quaternion never jumps to the other hemisphere between two frames of an
  episode (dot product of consecutive ``observation.state[3:7]`` >= 0; see ``sigma_data/episode.py``).
* ``language.*``: every frame has an instruction; episodes per instruction; instructions found in one split only.
"""

from __future__ import annotations

import json
import math
from collections import Counter, defaultdict
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from sigma_data.contract import (
    ACTION,
    DENSE_ACTION_DIM,
    GRIPPER_OPEN_INDEX,
    IS_DEPTH_MAP,
    IS_KEYFRAME,
    KEYFRAME_ACTION_DIM,
    NEXT_KEYFRAME_INDEX,
    STATE,
    STATE_DIM,
    STATE_QUAT,
    WORKSPACE_LIMIT_M,
    dataset_kind,
    depth_key,
    extrinsics_key,
    implausible_state,
    intrinsics_key,
    rgb_cameras,
    rgb_key,
)

Status = Literal["ok", "warn", "error", "skip"]


@dataclass
class ValidateConfig:
    """Options of ``sigma-data validate``."""

    # Dataset directory (a LeRobot v3 root: meta/, data/, videos/).
    root: Path
    # Any name; used only as LeRobot's repo_id for a local root.
    repo_id: str = "local/sigma"
    # Where to write the JSON report (default: <root>/meta/sigma_validation.json).
    report: Path | None = None
    # Images decoded per episode for the depth/calibration checks (first, last and evenly spaced ones).
    frames_per_episode: int = 6
    # Plausible metric depth for a tabletop scene, metres.
    depth_range: tuple[float, float] = (0.01, 10.0)
    # Largest tolerated fraction of invalid (<= 0, NaN, inf) depth pixels per camera.
    max_invalid_depth: float = 0.25
    # A dense episode's end effector faster than this between two frames is an error, m/s (a Panda: ~1.7).
    max_eef_speed: float = 3.0
    # A gripper change must have a keyframe within this many frames (dense datasets).
    gripper_tolerance: int = 3
    # Keyframe datasets: |action[i][:3] - pose of frame i+1| must be below this, metres.
    goal_tolerance_m: float = 2e-3
    # Fraction of frames in which the end effector must project inside each fixed camera.
    min_eef_visible: float = 0.9


@dataclass
class CheckResult:
    name: str
    status: Status
    detail: str
    episode: int | None = None
    frame: int | None = None
    field: str | None = None


@dataclass
class ValidationReport:
    root: str
    kind: str
    num_episodes: int
    num_frames: int
    cameras: list[str]
    checks: list[CheckResult] = field(default_factory=list)
    instructions: dict[str, int] = field(default_factory=dict)  # instruction -> number of episodes

    @property
    def num_errors(self) -> int:
        return sum(c.status == "error" for c in self.checks)

    @property
    def num_warnings(self) -> int:
        return sum(c.status == "warn" for c in self.checks)

    def to_json(self) -> dict:
        out = asdict(self)
        out["num_errors"], out["num_warnings"] = self.num_errors, self.num_warnings
        return out

    def table(self) -> str:
        """A plain-text table for people: one row per check."""
        rows = [("check", "status", "where", "detail")]
        for c in self.checks:
            where = " ".join(
                p
                for p in (
                    f"ep {c.episode}" if c.episode is not None else "",
                    f"frame {c.frame}" if c.frame is not None else "",
                    c.field or "",
                )
                if p
            )
            rows.append(
                (c.name, c.status.upper() if c.status in ("error", "warn") else c.status, where, c.detail)
            )
        widths = [max(len(r[i]) for r in rows) for i in range(3)]
        lines = [
            f"{r[0]:<{widths[0]}}  {r[1]:<{widths[1]}}  {r[2]:<{widths[2]}}  {r[3]}".rstrip() for r in rows
        ]
        lines.insert(1, "-" * min(120, sum(widths) + 30))
        return "\n".join(lines)


class _Checker:
    """Collects results; one instance per validation run."""

    def __init__(self) -> None:
        self.results: list[CheckResult] = []
        self.row_starts: dict[int, int] = {}  # episode -> its first row in the dataset

    def add(self, name: str, status: Status, detail: str, episode=None, frame=None, field=None) -> None:
        """``frame`` is the frame within ``episode`` (0 = its first frame), not the dataset-wide row."""
        self.results.append(CheckResult(name, status, detail, episode, frame, field))

    def at_row(self, name: str, status: Status, detail: str, episode: int, row: int, field=None) -> None:
        """:meth:`add` for a dataset-wide ``row`` of ``episode``."""
        self.add(name, status, detail, int(episode), int(row) - self.row_starts.get(int(episode), 0), field)


def _dataset_kind(root: Path, features: dict) -> str:
    try:
        return dataset_kind(root, features)
    except ValueError:
        return "unknown"  # reported by check_structure


def _columns(ds, names: list[str]) -> dict[str, np.ndarray]:
    table = ds.hf_dataset.with_format(None).select_columns(names)[:]
    return {k: np.asarray(v) for k, v in table.items()}


def _episode_bounds(episode_index: np.ndarray) -> dict[int, tuple[int, int]]:
    """Episode -> [start, stop) row range (rows are stored episode-contiguous)."""
    bounds: dict[int, tuple[int, int]] = {}
    for ep in np.unique(episode_index):
        rows = np.flatnonzero(episode_index == ep)
        bounds[int(ep)] = (int(rows[0]), int(rows[-1]) + 1)
    return bounds


def _sample_rows(start: int, stop: int, n: int) -> list[int]:
    rows = np.linspace(start, stop - 1, max(1, min(n, stop - start))).round().astype(int)
    return sorted(set(rows.tolist()))


def check_structure(chk: _Checker, features: dict, cameras: list[str], kind: str) -> bool:
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


def check_rows(chk: _Checker, ds, cols: dict[str, np.ndarray], bounds: dict) -> None:
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


def check_plausible(
    chk: _Checker, cols: dict[str, np.ndarray], bounds: dict, kind: str, fps: float, cfg
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


def check_images_decode(chk: _Checker, ds, features: dict, cameras: list[str], bounds: dict, cfg) -> set[int]:
    """Sampled frames of every camera stream decode; returns the dataset rows that did not."""
    keys = [k for cam in cameras for k in (rgb_key(cam), depth_key(cam)) if k in features]
    image_keys = [k for k in keys if features[k]["dtype"] == "image"]
    raw = ds.hf_dataset.with_format(None).select_columns(image_keys) if image_keys else None
    failed: set[int] = set()
    first = None
    for ep, (start, stop) in bounds.items():
        for row in _sample_rows(start, stop, cfg.frames_per_episode):
            for key in image_keys:
                try:
                    value = raw[row][key]  # datasets opens the PNG/TIFF lazily: load() decodes it
                    if hasattr(value, "load"):
                        value.load()
                except Exception as exc:
                    failed.add(row)
                    first = first or (ep, row, key, f"image does not decode ({type(exc).__name__}: {exc})")
            if len(image_keys) < len(keys) and row not in failed:
                try:
                    ds[row]
                except Exception as exc:  # a video frame (LeRobot decodes every video key of a row together)
                    failed.add(row)
                    first = first or (
                        ep,
                        row,
                        None,
                        f"video frames do not decode ({type(exc).__name__}: {exc})",
                    )
    if first:
        ep, row, key, detail = first
        more = f" ({len(failed)} sampled rows in all)" if len(failed) > 1 else ""
        chk.at_row("images.decode", "error", detail + more, ep, row, key)
    else:
        chk.add("images.decode", "ok", f"{len(keys)} camera streams decode at the sampled frames")
    return failed


def check_calibration(
    chk: _Checker, cols: dict[str, np.ndarray], features: dict, cameras: list[str], eps: np.ndarray, cfg
) -> None:
    for cam in cameras:
        k_key, e_key = intrinsics_key(cam), extrinsics_key(cam)
        h, w = features[rgb_key(cam)]["shape"][:2]
        K = cols[k_key].astype(np.float64)
        E = cols[e_key].astype(np.float64)
        bad = (
            (K[:, 0, 0] <= 0)
            | (K[:, 1, 1] <= 0)
            | (np.abs(K[:, 2] - [0, 0, 1]).max(axis=1) > 1e-6)
            | (K[:, 0, 2] <= 0)
            | (K[:, 0, 2] >= w)
            | (K[:, 1, 2] <= 0)
            | (K[:, 1, 2] >= h)
            | ~np.isfinite(K).all(axis=(1, 2))
        )
        off_centre = (np.abs(K[:, 0, 2] - w / 2) > 0.25 * w) | (np.abs(K[:, 1, 2] - h / 2) > 0.25 * h)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            chk.at_row(
                "intrinsics",
                "error",
                f"K inconsistent with a {w}x{h} image: {np.round(K[i], 3).tolist()}",
                eps[i],
                i,
                k_key,
            )
        elif off_centre.any():
            i = int(np.flatnonzero(off_centre)[0])
            chk.at_row("intrinsics", "warn", "principal point far from the image centre", eps[i], i, k_key)
        else:
            chk.add(
                "intrinsics",
                "ok",
                f"f={K[0, 0, 0]:.1f}px, c=({K[0, 0, 2]:.1f},{K[0, 1, 2]:.1f})",
                field=k_key,
            )

        finite = np.isfinite(E).all(axis=(1, 2))
        R = np.where(finite[:, None, None], E[:, :3, :3], np.eye(3))
        ortho = np.abs(np.einsum("nji,njk->nik", R, R) - np.eye(3)).max(axis=(1, 2))
        det = np.linalg.det(R)
        last = np.abs(np.where(finite[:, None], E[:, 3], [0, 0, 0, 1]) - [0, 0, 0, 1]).max(axis=1)
        bad = (ortho > 1e-3) | (np.abs(det - 1) > 1e-3) | (last > 1e-6) | ~finite
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            if not finite[i]:
                detail = "NaN or inf in the camera-to-world transform"
            elif last[i] > 1e-6:
                detail = f"last row {np.round(E[i, 3], 4).tolist()}, expected [0, 0, 0, 1]"
            else:
                detail = f"not a rigid camera-to-world transform (|RᵀR-I|={ortho[i]:.2g}, det={det[i]:.3f})"
            chk.at_row("extrinsics", "error", detail, eps[i], i, e_key)
        else:
            chk.add("extrinsics", "ok", f"rotations orthonormal (max |RᵀR-I| {ortho.max():.1e})", field=e_key)


def check_eef_projection(
    chk: _Checker, cols: dict[str, np.ndarray], features: dict, cameras: list[str], eps: np.ndarray, cfg
) -> None:
    pos = cols[STATE][:, :3].astype(np.float64)
    for cam in cameras:
        E = cols[extrinsics_key(cam)].astype(np.float64)
        if np.abs(E - E[0]).max() > 1e-6:
            continue  # a moving (wrist) camera need not see its own gripper
        K = cols[intrinsics_key(cam)].astype(np.float64)
        h, w = features[rgb_key(cam)]["shape"][:2]
        world_to_cam = np.linalg.inv(E)
        p_cam = np.einsum("nij,nj->ni", world_to_cam[:, :3, :3], pos) + world_to_cam[:, :3, 3]
        z = p_cam[:, 2]
        uv = np.einsum("nij,nj->ni", K, p_cam)[:, :2] / np.where(np.abs(z) < 1e-9, 1e-9, z)[:, None]
        inside = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
        frac = float(inside.mean())
        key = extrinsics_key(cam)
        if frac < cfg.min_eef_visible:
            i = int(np.flatnonzero(~inside)[0])
            chk.at_row(
                "eef.projection",
                "error",
                f"end effector inside the image in only {frac:.0%} of frames",
                eps[i],
                i,
                key,
            )
        else:
            chk.add("eef.projection", "ok", f"{cam}: end effector inside the image in {frac:.0%} of frames")


def check_depth(
    chk: _Checker,
    ds,
    features: dict,
    cameras: list[str],
    bounds: dict,
    cfg,
    skip_rows: set[int] = frozenset(),
) -> None:
    unit_checked = set()
    lo, hi = cfg.depth_range
    for cam in cameras:
        key = depth_key(cam)
        if key not in features:  # RGB-only dense dataset (check_structure allowed it)
            continue
        unit = features[key].get("info", {}).get("depth_unit")
        if unit not in (None, "m"):
            chk.add("depth.unit", "error", f"depth stored in {unit!r}, the contract says metres", field=key)
            unit_checked.add(cam)
        worst_invalid, worst_where, out_of_range, medians = 0.0, None, None, []
        for ep, (start, stop) in bounds.items():
            for row in _sample_rows(start, stop, cfg.frames_per_episode):
                if row in skip_rows:  # did not decode (images.decode reports it)
                    continue
                depth = ds[row][key].numpy().astype(np.float64)  # (1, H, W), metres (depth_output_unit="m")
                valid = np.isfinite(depth) & (depth > 0)
                invalid = 1.0 - float(valid.mean())
                if invalid > worst_invalid:
                    worst_invalid, worst_where = invalid, (ep, row)
                if valid.any():
                    d = depth[valid]
                    medians.append((float(np.median(d)), ep, row))
                    if out_of_range is None and (d.min() < lo or d.max() > hi):
                        out_of_range = (ep, row, float(d.min()), float(d.max()))
        if cam not in unit_checked:
            med = float(np.median([m[0] for m in medians])) if medians else math.nan
            implausible = [m for m in medians if not lo <= m[0] <= hi]
            if implausible or not medians:
                _, ep, row = implausible[0] if implausible else (None, None, None)
                chk.add(
                    "depth.unit",
                    "error",
                    f"median depth {med:.3g} is not a plausible metric depth (mm stored as m?)",
                    ep,
                    None if row is None else row - chk.row_starts.get(ep, 0),
                    key,
                )
            else:
                chk.add("depth.unit", "ok", f"{cam}: metres (median {med:.2f} m)", field=key)
        if out_of_range:
            ep, row, dmin, dmax = out_of_range
            chk.at_row(
                "depth.range", "error", f"depth {dmin:.3g}..{dmax:.3g} m outside {lo}..{hi} m", ep, row, key
            )
        else:
            chk.add("depth.range", "ok", f"{cam}: within {lo}..{hi} m", field=key)
        if worst_invalid > cfg.max_invalid_depth:
            ep, row = worst_where
            chk.at_row(
                "depth.invalid",
                "error",
                f"{worst_invalid:.0%} invalid pixels (limit {cfg.max_invalid_depth:.0%})",
                ep,
                row,
                key,
            )
        else:
            chk.add("depth.invalid", "ok", f"{cam}: at most {worst_invalid:.1%} invalid pixels", field=key)


def check_dense_keyframes(chk: _Checker, cols: dict[str, np.ndarray], bounds: dict, cfg) -> None:
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


def check_keyframe_goals(chk: _Checker, cols: dict[str, np.ndarray], bounds: dict, cfg) -> None:
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


def check_state_continuity(chk: _Checker, cols: dict[str, np.ndarray], bounds: dict) -> None:
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
    chk: _Checker, ds, cols: dict[str, np.ndarray], bounds: dict, report: ValidationReport
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


def validate_dataset(cfg: ValidateConfig) -> ValidationReport:
    """Run every check on ``cfg.root`` and return the report (nothing is written)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    root = Path(cfg.root)
    if not (root / "meta" / "info.json").exists():
        raise FileNotFoundError(f"{root}: not a LeRobot dataset (no meta/info.json)")
    ds = LeRobotDataset(cfg.repo_id, root=root, depth_output_unit="m", video_backend="pyav")
    features = ds.meta.features
    cameras = rgb_cameras(features)
    kind = _dataset_kind(root, features)
    report = ValidationReport(str(root), kind, ds.meta.total_episodes, ds.meta.total_frames, cameras)
    chk = _Checker()
    report.checks = chk.results
    if not check_structure(chk, features, cameras, kind):
        return report

    numeric = ["episode_index", "frame_index", "task_index", STATE, ACTION]
    numeric += [key(c) for c in cameras for key in (intrinsics_key, extrinsics_key)]
    numeric += [k for k in (IS_KEYFRAME, NEXT_KEYFRAME_INDEX) if k in features]
    cols = _columns(ds, numeric)
    eps = cols["episode_index"].reshape(-1)
    bounds = _episode_bounds(eps)

    chk.row_starts = {ep: start for ep, (start, _stop) in bounds.items()}
    check_rows(chk, ds, cols, bounds)
    for key in (STATE, ACTION):
        bad = ~np.isfinite(cols[key]).all(axis=1)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            chk.at_row("values.finite", "error", "NaN or inf", eps[i], i, key)
    check_plausible(chk, cols, bounds, kind, ds.meta.fps, cfg)
    undecodable = check_images_decode(chk, ds, features, cameras, bounds, cfg)
    check_calibration(chk, cols, features, cameras, eps, cfg)
    check_eef_projection(chk, cols, features, cameras, eps, cfg)
    check_depth(chk, ds, features, cameras, bounds, cfg, undecodable)
    if kind == "dense":
        check_dense_keyframes(chk, cols, bounds, cfg)
    else:
        check_keyframe_goals(chk, cols, bounds, cfg)
    check_state_continuity(chk, cols, bounds)
    check_language(chk, ds, cols, bounds, report)
    return report


def run_validate(cfg: ValidateConfig) -> int:
    """CLI body: print the table, write the JSON report, return the exit code (1 on errors)."""
    report = validate_dataset(cfg)
    out = Path(cfg.report) if cfg.report else Path(cfg.root) / "meta" / "sigma_validation.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report.to_json(), indent=2))
    print(report.table())
    verdict = "FAILED" if report.num_errors else "passed"
    print(
        f"validate {verdict}: {report.kind} dataset {cfg.root}, {report.num_episodes} episodes, "
        f"{report.num_frames} frames, {report.num_errors} errors, {report.num_warnings} warnings; report {out}"
    )
    return 1 if report.num_errors else 0
