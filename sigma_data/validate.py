"""Check a sigma dataset (dense or keyframe) against the data contract of ``shared/DESIGN.md``.

The dataset is opened with stock ``LeRobotDataset`` (so a pass also proves LeRobot can read it); numeric columns
are read whole from the parquet rows, images are sampled (``frames_per_episode`` per episode) because decoding
every video frame is the expensive part. Every check yields one row, ``ok``/``warn``/``error``/``skip``, with
the first offending episode, frame and field; ``errors`` make ``sigma-data validate`` exit non-zero.

Checks (names as printed):

* ``structure``: state/action/camera features exist with the contract's shapes; depth features flagged.
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

Status = Literal["ok", "warn", "error", "skip"]
STATE_DIM = 10
DENSE_ACTION_DIM = 7
KEYFRAME_ACTION_DIM = 9


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

    def add(self, name: str, status: Status, detail: str, episode=None, frame=None, field=None) -> None:
        self.results.append(CheckResult(name, status, detail, episode, frame, field))


def _camera_names(features: dict) -> list[str]:
    prefix = "observation.images."
    return sorted(
        k[len(prefix) :]
        for k, f in features.items()
        if k.startswith(prefix)
        and f["dtype"] in ("image", "video")
        and not f.get("info", {}).get("is_depth_map")
    )


def _dataset_kind(root: Path, features: dict) -> str:
    sidecar = root / "meta" / "sigma.json"
    if sidecar.exists():
        kind = json.loads(sidecar.read_text()).get("kind")
        if kind in ("dense", "keyframe"):
            return kind
    action_dim = features.get("action", {}).get("shape", (0,))[0]
    return {DENSE_ACTION_DIM: "dense", KEYFRAME_ACTION_DIM: "keyframe"}.get(action_dim, "unknown")


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
    expect = {"observation.state": (STATE_DIM,)}
    if kind in ("dense", "keyframe"):
        expect["action"] = (DENSE_ACTION_DIM,) if kind == "dense" else (KEYFRAME_ACTION_DIM,)
    for cam in cameras:
        expect[f"observation.camera.{cam}.intrinsics"] = (3, 3)
        expect[f"observation.camera.{cam}.extrinsics"] = (4, 4)
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
            "structure", "error", "cannot tell dense (7-D action) from keyframe (9-D action)", field="action"
        )
        ok = False
    if not cameras:
        chk.add("structure", "error", "no RGB camera features observation.images.<cam>")
        ok = False
    depth_keys = [f"observation.images.{cam}_depth" for cam in cameras]
    rgb_only = kind == "dense" and not any(key in features for key in depth_keys)
    for key in [] if rgb_only else depth_keys:
        if key not in features:
            chk.add("structure", "error", "missing depth feature", field=key)
            ok = False
        elif not features[key].get("info", {}).get("is_depth_map"):
            chk.add("structure", "error", "depth feature lacks info.is_depth_map=True", field=key)
            ok = False
    if ok:
        what = "RGB cameras (RGB-only dense: no depth)" if rgb_only else "RGB-D cameras"
        chk.add("structure", "ok", f"{kind} dataset, {len(cameras)} {what} with calibration")
    return ok


def check_calibration(
    chk: _Checker, cols: dict[str, np.ndarray], features: dict, cameras: list[str], eps: np.ndarray, cfg
) -> None:
    for cam in cameras:
        k_key, e_key = f"observation.camera.{cam}.intrinsics", f"observation.camera.{cam}.extrinsics"
        h, w = features[f"observation.images.{cam}"]["shape"][:2]
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
            chk.add(
                "intrinsics",
                "error",
                f"K inconsistent with a {w}x{h} image: {np.round(K[i], 3).tolist()}",
                int(eps[i]),
                i,
                k_key,
            )
        elif off_centre.any():
            i = int(np.flatnonzero(off_centre)[0])
            chk.add("intrinsics", "warn", "principal point far from the image centre", int(eps[i]), i, k_key)
        else:
            chk.add(
                "intrinsics",
                "ok",
                f"f={K[0, 0, 0]:.1f}px, c=({K[0, 0, 2]:.1f},{K[0, 1, 2]:.1f})",
                field=k_key,
            )

        R = E[:, :3, :3]
        ortho = np.abs(np.einsum("nji,njk->nik", R, R) - np.eye(3)).max(axis=(1, 2))
        det = np.linalg.det(R)
        last = np.abs(E[:, 3] - [0, 0, 0, 1]).max(axis=1)
        bad = (ortho > 1e-3) | (np.abs(det - 1) > 1e-3) | (last > 1e-6) | ~np.isfinite(E).all(axis=(1, 2))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            chk.add(
                "extrinsics",
                "error",
                f"not a rigid camera-to-world transform (|RᵀR-I|={ortho[i]:.2g}, det={det[i]:.3f})",
                int(eps[i]),
                i,
                e_key,
            )
        else:
            chk.add("extrinsics", "ok", f"rotations orthonormal (max |RᵀR-I| {ortho.max():.1e})", field=e_key)


def check_eef_projection(
    chk: _Checker, cols: dict[str, np.ndarray], features: dict, cameras: list[str], eps: np.ndarray, cfg
) -> None:
    pos = cols["observation.state"][:, :3].astype(np.float64)
    for cam in cameras:
        E = cols[f"observation.camera.{cam}.extrinsics"].astype(np.float64)
        if np.abs(E - E[0]).max() > 1e-6:
            continue  # a moving (wrist) camera need not see its own gripper
        K = cols[f"observation.camera.{cam}.intrinsics"].astype(np.float64)
        h, w = features[f"observation.images.{cam}"]["shape"][:2]
        world_to_cam = np.linalg.inv(E)
        p_cam = np.einsum("nij,nj->ni", world_to_cam[:, :3, :3], pos) + world_to_cam[:, :3, 3]
        z = p_cam[:, 2]
        uv = np.einsum("nij,nj->ni", K, p_cam)[:, :2] / np.where(np.abs(z) < 1e-9, 1e-9, z)[:, None]
        inside = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
        frac = float(inside.mean())
        key = f"observation.camera.{cam}.extrinsics"
        if frac < cfg.min_eef_visible:
            i = int(np.flatnonzero(~inside)[0])
            chk.add(
                "eef.projection",
                "error",
                f"end effector inside the image in only {frac:.0%} of frames",
                int(eps[i]),
                i,
                key,
            )
        else:
            chk.add("eef.projection", "ok", f"{cam}: end effector inside the image in {frac:.0%} of frames")


def check_depth(chk: _Checker, ds, features: dict, cameras: list[str], bounds: dict, cfg) -> None:
    unit_checked = set()
    lo, hi = cfg.depth_range
    for cam in cameras:
        key = f"observation.images.{cam}_depth"
        if key not in features:  # RGB-only dense dataset (check_structure allowed it)
            continue
        unit = features[key].get("info", {}).get("depth_unit")
        if unit not in (None, "m"):
            chk.add("depth.unit", "error", f"depth stored in {unit!r}, the contract says metres", field=key)
            unit_checked.add(cam)
        worst_invalid, worst_where, out_of_range, medians = 0.0, None, None, []
        for ep, (start, stop) in bounds.items():
            for row in _sample_rows(start, stop, cfg.frames_per_episode):
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
                    row,
                    key,
                )
            else:
                chk.add("depth.unit", "ok", f"{cam}: metres (median {med:.2f} m)", field=key)
        if out_of_range:
            ep, row, dmin, dmax = out_of_range
            chk.add(
                "depth.range", "error", f"depth {dmin:.3g}..{dmax:.3g} m outside {lo}..{hi} m", ep, row, key
            )
        else:
            chk.add("depth.range", "ok", f"{cam}: within {lo}..{hi} m", field=key)
        if worst_invalid > cfg.max_invalid_depth:
            ep, row = worst_where
            chk.add(
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
    flag_key, next_key = "sigma.is_keyframe", "sigma.next_keyframe_index"
    if flag_key not in cols or next_key not in cols:
        missing = flag_key if flag_key not in cols else next_key
        chk.add("keyframes.present", "error", "dense dataset without keyframe annotations", field=missing)
        return
    flags = cols[flag_key].reshape(-1).astype(bool)
    nxt = cols[next_key].reshape(-1).astype(np.int64)
    gripper = cols["observation.state"][:, 7]
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
            problems.setdefault(
                "keyframes.labels", (ep, None, "observation.state", "gripper_open not in {0, 1}")
            )
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
    action = cols["action"].astype(np.float64)
    state = cols["observation.state"].astype(np.float64)
    problems: dict[str, tuple] = {}
    for ep, (start, stop) in bounds.items():
        if stop - start < 2:
            problems.setdefault(
                "goals.links", (ep, None, "action", "episode has fewer than 2 frames: no goal")
            )
            continue
        a, s = action[start:stop], state[start:stop]
        err = np.linalg.norm(a[:-1, :3] - s[1:, :3], axis=1)
        if (err > cfg.goal_tolerance_m).any():
            i = int(np.argmax(err > cfg.goal_tolerance_m))
            problems.setdefault(
                "goals.links",
                (ep, i, "action", f"action is {err[i] * 1000:.1f} mm from frame {i + 1}'s pose (its goal)"),
            )
        grip_mismatch = a[:-1, 7] != s[1:, 7]
        if grip_mismatch.any():
            i = int(np.argmax(grip_mismatch))
            problems.setdefault(
                "goals.links", (ep, i, "action", f"gripper_open differs from frame {i + 1}'s gripper state")
            )
    q = action[:, 3:7]
    norm_err = np.abs(np.linalg.norm(q, axis=1) - 1)
    neg_w = q[:, 3] < 0
    eps = np.concatenate([np.full(stop - start, ep) for ep, (start, stop) in bounds.items()])
    if (norm_err > 1e-3).any():
        i = int(np.argmax(norm_err > 1e-3))
        problems["goals.quaternion"] = (int(eps[i]), i, "action", f"quaternion norm {1 + norm_err[i]:.4f}")
    elif neg_w.any():
        i = int(np.argmax(neg_w))
        problems["goals.quaternion"] = (int(eps[i]), i, "action", "quaternion has w < 0 (contract: w >= 0)")
    flags = action[:, 7:9]
    if not np.isin(flags, (0.0, 1.0)).all():
        i = int(np.flatnonzero(~np.isin(flags, (0.0, 1.0)).all(axis=1))[0])
        problems["goals.flags"] = (int(eps[i]), i, "action", "gripper_open / ignore_collision not in {0, 1}")
    for name in ("goals.links", "goals.quaternion", "goals.flags"):
        if name in problems:
            ep, frame, fld, detail = problems[name]
            chk.add(name, "error", detail, ep, frame, fld)
        else:
            chk.add(name, "ok", "")


def check_state_continuity(chk: _Checker, cols: dict[str, np.ndarray], bounds: dict) -> None:
    """Consecutive frames of an episode: the eef quaternion keeps its hemisphere (q and -q are one rotation, but
    a policy reading the state sees a jump of up to 2 per component)."""
    q = cols["observation.state"][:, 3:7].astype(np.float64)
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
        chk.add(
            "language.instruction",
            "error",
            f"{len(missing)} frames without an instruction",
            int(eps[i]),
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
    cameras = _camera_names(features)
    kind = _dataset_kind(root, features)
    report = ValidationReport(str(root), kind, ds.meta.total_episodes, ds.meta.total_frames, cameras)
    chk = _Checker()
    report.checks = chk.results
    if not check_structure(chk, features, cameras, kind):
        return report

    numeric = ["episode_index", "frame_index", "task_index", "observation.state", "action"]
    numeric += [f"observation.camera.{c}.{m}" for c in cameras for m in ("intrinsics", "extrinsics")]
    numeric += [k for k in ("sigma.is_keyframe", "sigma.next_keyframe_index") if k in features]
    cols = _columns(ds, numeric)
    eps = cols["episode_index"].reshape(-1)
    bounds = _episode_bounds(eps)

    for key in ("observation.state", "action"):
        bad = ~np.isfinite(cols[key]).all(axis=1)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            chk.add("values.finite", "error", "NaN or inf", int(eps[i]), i, key)
    check_calibration(chk, cols, features, cameras, eps, cfg)
    check_eef_projection(chk, cols, features, cameras, eps, cfg)
    check_depth(chk, ds, features, cameras, bounds, cfg)
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
