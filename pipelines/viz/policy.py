"""Policy viewer: what the Σ-agent policy saw and predicted for one decision step, logged to Rerun.

Inputs follow docs/method.md §4: ``V`` orthographic virtual views (default 5: top, front, back, left,
right) of ``C = 10`` channels (0-2 xyz cube coordinates in [-1, 1], 3-5 rgb in [0, 1], 6 depth = view z minus
its mean with empty pixels at -1, 7-9 pixel location), the per-view translation heatmaps (probabilities, each
view sums to 1), the predicted and ground-truth 9-D keyframe actions ``[x, y, z, qx, qy, qz, qw, gripper_open,
ignore_collision]`` (world frame, metres, quaternion xyzw), the world point cloud and the discrete heads.

Entities under ``<root>`` (default ``policy``):

- ``views/<view>/rgb``, ``.../heatmap_overlay`` (RGBA, drawn over the rgb), ``.../markers/{peak,gt,pred}``,
  ``.../heatmap`` (raw probabilities as a tensor), ``.../depth`` and ``.../xyz``;
- ``world/point_cloud``, ``world/pred`` and ``world/gt`` (axes + labelled dot), ``world/error`` (gt -> pred);
- ``probs/rotation/{x,y,z}``, ``probs/gripper`` ([closed, open]), ``probs/collision`` ([avoid, ignore]);
- ``summary``: markdown with the instruction, poses, errors and discrete decisions.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import rerun as rr
import torch

from sigma_data.contract import KEYFRAME_ACTION_DIM

DEFAULT_VIEW_NAMES = ("top", "front", "back", "left", "right")
XYZ_CHANNELS = slice(0, 3)
RGB_CHANNELS = slice(3, 6)
DEPTH_CHANNEL = 6
MIN_CHANNELS = 7
ACTION_DIM = KEYFRAME_ACTION_DIM
PRED_COLOR = (255, 170, 0)
GT_COLOR = (0, 200, 255)
PEAK_COLOR = (255, 255, 255)
# Heatmap colour ramp (dark purple -> red -> yellow), sampled at evenly spaced heat levels.
_HEAT_RAMP = np.array([[20, 10, 60], [120, 20, 120], [220, 50, 50], [255, 150, 20], [255, 255, 120]], float)

ArrayLike = torch.Tensor | np.ndarray


@dataclass(frozen=True)
class PolicyFrameSummary:
    """Numbers shown in the summary panel (errors are None without ground truth)."""

    num_views: int
    num_points: int
    translation_error_m: float | None
    rotation_error_deg: float | None
    gripper_open_prob: float | None
    ignore_collision_prob: float | None


def _np(x: ArrayLike, name: str, dtype: type = np.float32) -> np.ndarray:
    if isinstance(x, torch.Tensor):
        x = x.detach().cpu().numpy()
    if not isinstance(x, np.ndarray):
        raise TypeError(f"{name}: expected a torch.Tensor or np.ndarray, got {type(x).__name__}")
    return x.astype(dtype, copy=False)


def _check_shape(arr: np.ndarray, shape: tuple[int | None, ...], name: str) -> None:
    ok = arr.ndim == len(shape) and all(s is None or s == a for s, a in zip(shape, arr.shape, strict=True))
    if not ok:
        want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
        raise ValueError(f"{name}: expected shape {want}, got {tuple(arr.shape)}")


def heatmap_to_rgba(heatmap: np.ndarray, max_alpha: float = 0.85) -> np.ndarray:
    """(H, W) probabilities -> (H, W, 4) uint8 overlay; heat is normalised by the view's maximum.

    Colour follows a dark-to-yellow ramp and opacity grows with sqrt(heat), so the mode is opaque and the
    tails stay visible without hiding the image.
    """
    peak = float(heatmap.max())
    heat = np.clip(heatmap / peak, 0.0, 1.0) if peak > 0 else np.zeros_like(heatmap)
    pos = heat * (len(_HEAT_RAMP) - 1)
    lo = np.floor(pos).astype(int).clip(0, len(_HEAT_RAMP) - 2)
    frac = (pos - lo)[..., None]
    rgb = _HEAT_RAMP[lo] * (1 - frac) + _HEAT_RAMP[lo + 1] * frac
    alpha = max_alpha * np.sqrt(heat)
    return np.concatenate([rgb, 255 * alpha[..., None]], axis=-1).round().astype(np.uint8)


def quaternion_angle_deg(q1_xyzw: np.ndarray, q2_xyzw: np.ndarray) -> float:
    """Geodesic angle between two unit quaternions (xyzw), degrees in [0, 180]; sign-invariant."""
    from pipelines.keyframe_errors import geodesic_deg

    return float(geodesic_deg(np.asarray(q1_xyzw)[None], np.asarray(q2_xyzw)[None])[0])


def _log_pose(
    rec: rr.RecordingStream, path: str, action: np.ndarray, color: tuple, tag: str, axis: float
) -> None:
    rec.log(
        path,
        rr.Transform3D(translation=action[:3], quaternion=rr.Quaternion(xyzw=action[3:7])),
        rr.TransformAxes3D(axis),
    )
    grip = "open" if action[7] >= 0.5 else "closed"
    coll = "ignore collisions" if action[8] >= 0.5 else "avoid collisions"
    rec.log(
        f"{path}/label",
        rr.Points3D([[0.0, 0.0, 0.0]], radii=0.01, colors=[color], labels=[f"{tag}: {grip}, {coll}"]),
    )


def _log_views(
    rec: rr.RecordingStream,
    root: str,
    views: np.ndarray,
    heatmaps: np.ndarray,
    names: list[str],
    gt_pixels: np.ndarray | None,
    pred_pixels: np.ndarray | None,
) -> None:
    for v, name in enumerate(names):
        base = f"{root}/views/{name}"
        rgb = (np.clip(views[v, RGB_CHANNELS], 0, 1) * 255).round().astype(np.uint8).transpose(1, 2, 0)
        rec.log(f"{base}/rgb", rr.Image(rgb, draw_order=0.0))
        rec.log(f"{base}/heatmap_overlay", rr.Image(heatmap_to_rgba(heatmaps[v]), draw_order=1.0))
        rec.log(f"{base}/heatmap", rr.Tensor(heatmaps[v], dim_names=["height", "width"]))
        depth = views[v, DEPTH_CHANNEL]
        shown = np.where(depth <= -1.0, 0.0, depth + 1.0).astype(np.float32)  # empty (-1) -> 0 = not drawn
        rec.log(f"{base}/depth", rr.DepthImage(shown, meter=1.0, colormap=rr.components.Colormap.Turbo))
        xyz = (
            (np.clip((views[v, XYZ_CHANNELS] + 1) / 2, 0, 1) * 255)
            .round()
            .astype(np.uint8)
            .transpose(1, 2, 0)
        )
        rec.log(f"{base}/xyz", rr.Image(xyz))

        row, col = np.unravel_index(int(np.argmax(heatmaps[v])), heatmaps[v].shape)
        peak_p = float(heatmaps[v][row, col])
        rec.log(
            f"{base}/markers/peak",
            rr.Points2D(
                [[col + 0.5, row + 0.5]], radii=1.5, colors=[PEAK_COLOR], labels=[f"peak p={peak_p:.3g}"]
            ),
        )
        for tag, pixels, color in (("gt", gt_pixels, GT_COLOR), ("pred", pred_pixels, PRED_COLOR)):
            if pixels is None:
                rec.log(f"{base}/markers/{tag}", rr.Clear(recursive=False))
            else:
                rec.log(
                    f"{base}/markers/{tag}", rr.Points2D([pixels[v]], radii=1.5, colors=[color], labels=[tag])
                )


def log_policy_frame(
    rec: rr.RecordingStream,
    views: ArrayLike,
    heatmaps: ArrayLike,
    pred_action: ArrayLike,
    gt_action: ArrayLike | None,
    cloud_xyz: ArrayLike,
    cloud_rgb: ArrayLike,
    rot_probs: ArrayLike | None,
    grip_probs: ArrayLike | None,
    collision_probs: ArrayLike | None,
    instruction: str,
    *,
    root: str = "policy",
    view_names: list[str] | None = None,
    gt_pixels: ArrayLike | None = None,
    pred_pixels: ArrayLike | None = None,
    point_budget: int = 50_000,
    step: int | None = None,
) -> PolicyFrameSummary:
    """Log one decision step of the policy.

    Args:
        rec: the Rerun recording to log into.
        views: (V, C, H, W) rendered virtual views, C >= 7 (channels as in the module docstring).
        heatmaps: (V, H, W) translation heatmap probabilities per view.
        pred_action, gt_action: (9,) keyframe actions in world coordinates; ``gt_action`` may be None (live).
        cloud_xyz: (N, 3) world points, metres. cloud_rgb: (N, 3) in [0, 1] (float) or [0, 255] (uint8).
        rot_probs: (3, num_bins) probabilities per Euler axis; grip_probs: (2,) [closed, open];
            collision_probs: (2,) [avoid, ignore]. Each may be None.
        instruction: the language instruction.
        root: entity path prefix (matches :func:`pipelines.viz.blueprints.policy_blueprint`).
        view_names: names of the V views; default top, front, back, left, right (docs/method.md §4.1 order).
        gt_pixels, pred_pixels: optional (V, 2) continuous pixel coordinates (u = column, v = row, pixel
            centres at +0.5) of the ground-truth / predicted translation in each view.
        point_budget: the cloud is evenly subsampled to at most this many points.
        step: if given, sets the ``step`` sequence timeline before logging.
    """
    views_np = _np(views, "views")
    hm = _np(heatmaps, "heatmaps")
    _check_shape(views_np, (None, None, None, None), "views")
    num_views, channels, h, w = views_np.shape
    if channels < MIN_CHANNELS:
        raise ValueError(f"views: expected >= {MIN_CHANNELS} channels (xyz, rgb, depth, ...), got {channels}")
    _check_shape(hm, (num_views, h, w), "heatmaps")
    names = list(view_names) if view_names is not None else None
    if names is None:
        names = (
            list(DEFAULT_VIEW_NAMES)
            if num_views == len(DEFAULT_VIEW_NAMES)
            else [f"view_{i}" for i in range(num_views)]
        )
    if len(names) != num_views:
        raise ValueError(f"view_names: {len(names)} names for {num_views} views")
    pred = _np(pred_action, "pred_action")
    _check_shape(pred, (ACTION_DIM,), "pred_action")
    gt = None if gt_action is None else _np(gt_action, "gt_action")
    if gt is not None:
        _check_shape(gt, (ACTION_DIM,), "gt_action")
    xyz = _np(cloud_xyz, "cloud_xyz")
    _check_shape(xyz, (None, 3), "cloud_xyz")
    rgb = _np(cloud_rgb, "cloud_rgb", dtype=np.float64)
    _check_shape(rgb, (len(xyz), 3), "cloud_rgb")
    rgb_u8 = (np.clip(rgb, 0, 1) * 255 if rgb.max(initial=0.0) <= 1.0 else np.clip(rgb, 0, 255)).round()
    pixels = {}
    for tag, px in (("gt_pixels", gt_pixels), ("pred_pixels", pred_pixels)):
        pixels[tag] = None if px is None else _np(px, tag)
        if pixels[tag] is not None:
            _check_shape(pixels[tag], (num_views, 2), tag)

    if step is not None:
        rec.set_time("step", sequence=step)

    _log_views(rec, root, views_np, hm, names, pixels["gt_pixels"], pixels["pred_pixels"])

    rec.log(f"{root}/world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    keep = (
        np.arange(len(xyz))
        if len(xyz) <= point_budget
        else np.linspace(0, len(xyz) - 1, point_budget).astype(int)
    )
    rec.log(
        f"{root}/world/point_cloud",
        rr.Points3D(xyz[keep], colors=rgb_u8[keep].astype(np.uint8), radii=0.003),
    )
    _log_pose(rec, f"{root}/world/pred", pred, PRED_COLOR, "pred", 0.08)
    trans_err = rot_err = None
    if gt is None:
        rec.log(f"{root}/world/gt", rr.Clear(recursive=True))
        rec.log(f"{root}/world/error", rr.Clear(recursive=False))
    else:
        _log_pose(rec, f"{root}/world/gt", gt, GT_COLOR, "gt", 0.06)
        trans_err = float(np.linalg.norm(pred[:3] - gt[:3]))
        rot_err = quaternion_angle_deg(pred[3:7], gt[3:7])
        rec.log(
            f"{root}/world/error",
            rr.Arrows3D(
                origins=[gt[:3]],
                vectors=[pred[:3] - gt[:3]],
                colors=[PRED_COLOR],
                radii=0.002,
                labels=[f"{1000 * trans_err:.1f} mm, {rot_err:.1f}°"],
            ),
        )

    grip_open_p = coll_p = None
    if rot_probs is not None:
        rot = _np(rot_probs, "rot_probs")
        _check_shape(rot, (3, None), "rot_probs")
        for axis, values in zip("xyz", rot, strict=True):
            rec.log(f"{root}/probs/rotation/{axis}", rr.BarChart(values, color=PRED_COLOR))
    if grip_probs is not None:
        grip = _np(grip_probs, "grip_probs")
        _check_shape(grip, (2,), "grip_probs")
        grip_open_p = float(grip[1])
        rec.log(f"{root}/probs/gripper", rr.BarChart(grip, color=PRED_COLOR))
    if collision_probs is not None:
        coll = _np(collision_probs, "collision_probs")
        _check_shape(coll, (2,), "collision_probs")
        coll_p = float(coll[1])
        rec.log(f"{root}/probs/collision", rr.BarChart(coll, color=PRED_COLOR))

    summary = PolicyFrameSummary(num_views, len(keep), trans_err, rot_err, grip_open_p, coll_p)
    rec.log(
        f"{root}/summary",
        rr.TextDocument(
            _summary_markdown(instruction, pred, gt, summary, rot_probs), media_type=rr.MediaType.MARKDOWN
        ),
    )
    return summary


def _fmt_pose(a: np.ndarray) -> str:
    return (
        f"xyz ({a[0]:.3f}, {a[1]:.3f}, {a[2]:.3f}) m, quat xyzw ({a[3]:.3f}, {a[4]:.3f}, {a[5]:.3f}, {a[6]:.3f}), "
        f"gripper {'open' if a[7] >= 0.5 else 'closed'}, {'ignore' if a[8] >= 0.5 else 'avoid'} collisions"
    )


def _summary_markdown(
    instruction: str, pred: np.ndarray, gt: np.ndarray | None, s: PolicyFrameSummary, rot_probs: Any
) -> str:
    lines = ["# Instruction", f"> {instruction}", "", f"- **pred**: {_fmt_pose(pred)}"]
    if gt is not None:
        lines.append(f"- **gt**: {_fmt_pose(gt)}")
        lines.append(
            f"- translation error **{1000 * s.translation_error_m:.1f} mm**, rotation error **{s.rotation_error_deg:.1f}°**"
        )
    if s.gripper_open_prob is not None:
        lines.append(f"- p(gripper open) = {s.gripper_open_prob:.3f}")
    if s.ignore_collision_prob is not None:
        lines.append(f"- p(ignore collision) = {s.ignore_collision_prob:.3f}")
    if rot_probs is not None:
        rot = _np(rot_probs, "rot_probs")
        peaks = ", ".join(
            f"{ax}: bin {int(np.argmax(r))} (p={float(np.max(r)):.2f})"
            for ax, r in zip("xyz", rot, strict=True)
        )
        lines.append(f"- rotation argmax ({rot.shape[1]} bins of {360 / rot.shape[1]:g}°): {peaks}")
    lines.append("- views: heatmap overlay dark→yellow; white dot = heatmap peak, cyan = gt, orange = pred")
    return "\n".join(lines)


def prediction_frame(
    policy: Any, pred: Any, instruction: str, gt_action: np.ndarray | None = None
) -> dict[str, Any]:
    """``log_policy_frame``'s keyword arguments for the first sample of a ``SigmaPrediction``: the policy's virtual
    views (V, 10, H, W) and their names, per-view heatmaps (V, H, W), the decoded 9-D world-frame prediction, the
    fused input cloud, rotation-bin / gripper / collision probabilities, and the predicted (and, given
    ``gt_action``, the true) translation projected into every view (``pred_pixels`` / ``gt_pixels``, (V, 2) as
    (u, v))."""
    from sigma_policy.pointcloud import world_to_cube

    cloud = pred.cloud_points[0]
    finite = torch.isfinite(cloud).all(-1)
    bounds = pred.bounds[:1]
    gt_pixels = None
    if gt_action is not None:
        gt_cube = world_to_cube(torch.as_tensor(gt_action[None, None, :3], device=bounds.device), bounds)
        gt_pixels = policy.renderer.project(gt_cube)[0, 0].cpu().numpy()
    return {
        "views": pred.views[0].float().cpu().numpy(),
        "view_names": policy.renderer.view_names,
        "heatmaps": pred.heatmaps[0].float().cpu().numpy(),
        "pred_action": pred.action[0].float().cpu().numpy(),
        "gt_action": gt_action,
        "cloud_xyz": cloud[finite].float().cpu().numpy(),
        "cloud_rgb": pred.cloud_colors[0][finite].float().cpu().numpy(),
        "rot_probs": pred.rotation_probs[0].cpu().numpy(),
        "grip_probs": pred.gripper_probs[0].cpu().numpy(),
        "collision_probs": pred.collision_probs[0].cpu().numpy(),
        "instruction": instruction,
        "gt_pixels": gt_pixels,
        "pred_pixels": policy.renderer.project(pred.point_cube[:1, None])[0, 0].cpu().numpy(),
    }


def policy_frame_outputs(policy: Any, batch: dict[str, Any]) -> dict[str, Any]:
    """Run ``SigmaPolicy.predict`` on a pre-processed dataset batch; see :func:`prediction_frame`. The true next
    keyframe is ``batch["action"]`` (when present) and the instruction ``batch["task"]``."""
    gt = batch.get("action")
    gt_action = None
    if gt is not None:
        gt_action = (gt[0, 0] if gt.ndim == 3 else gt[0]).float().cpu().numpy()
    tasks = batch.get("task")
    instruction = tasks[0] if isinstance(tasks, list | tuple) else str(tasks)
    return prediction_frame(policy, policy.predict(batch), instruction, gt_action)
