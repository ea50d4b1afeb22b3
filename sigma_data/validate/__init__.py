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

The checks live by what they look at: ``tables.py`` (structure, rows, values), ``cameras.py`` (images,
calibration, end effector in view, depth), ``episodes.py`` (keyframes, goals, continuity, language); ``report.py``
holds the options and the report, ``columns.py`` the column reads they share.
"""

from __future__ import annotations

import json
from pathlib import Path

from sigma_data.contract import (
    ACTION,
    IS_KEYFRAME,
    NEXT_KEYFRAME_INDEX,
    STATE,
    extrinsics_key,
    intrinsics_key,
    rgb_cameras,
)
from sigma_data.validate.cameras import (
    check_calibration,
    check_depth,
    check_eef_projection,
    check_images_decode,
)
from sigma_data.validate.columns import dataset_kind_or_unknown, episode_bounds, read_columns
from sigma_data.validate.episodes import (
    check_dense_keyframes,
    check_keyframe_goals,
    check_language,
    check_state_continuity,
)
from sigma_data.validate.report import Checker, CheckResult, Status, ValidateConfig, ValidationReport
from sigma_data.validate.tables import check_finite, check_plausible, check_rows, check_structure

__all__ = ["CheckResult", "Status", "ValidateConfig", "ValidationReport", "run_validate", "validate_dataset"]


def validate_dataset(cfg: ValidateConfig) -> ValidationReport:
    """Run every check on ``cfg.root`` and return the report (nothing is written)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    root = Path(cfg.root)
    if not (root / "meta" / "info.json").exists():
        raise FileNotFoundError(f"{root}: not a LeRobot dataset (no meta/info.json)")
    ds = LeRobotDataset(cfg.repo_id, root=root, depth_output_unit="m", video_backend="pyav")
    features = ds.meta.features
    cameras = rgb_cameras(features)
    kind = dataset_kind_or_unknown(root, features)
    report = ValidationReport(str(root), kind, ds.meta.total_episodes, ds.meta.total_frames, cameras)
    chk = Checker()
    report.checks = chk.results
    if not check_structure(chk, features, cameras, kind):
        return report

    numeric = ["episode_index", "frame_index", "task_index", STATE, ACTION]
    numeric += [key(c) for c in cameras for key in (intrinsics_key, extrinsics_key)]
    numeric += [k for k in (IS_KEYFRAME, NEXT_KEYFRAME_INDEX) if k in features]
    cols = read_columns(ds, numeric)
    eps = cols["episode_index"].reshape(-1)
    bounds = episode_bounds(eps)

    chk.row_starts = {ep: start for ep, (start, _stop) in bounds.items()}
    check_rows(chk, ds, cols, bounds)
    check_finite(chk, cols)
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
