"""Checks of the cameras: frames decode, calibration is a camera, the end effector is in view, depth is metric."""

from __future__ import annotations

import math

import numpy as np

from sigma_data.contract import STATE, depth_key, extrinsics_key, intrinsics_key, rgb_key
from sigma_data.validate.columns import sample_rows
from sigma_data.validate.report import Checker


def check_images_decode(chk: Checker, ds, features: dict, cameras: list[str], bounds: dict, cfg) -> set[int]:
    """Sampled frames of every camera stream decode; returns the dataset rows that did not."""
    keys = [k for cam in cameras for k in (rgb_key(cam), depth_key(cam)) if k in features]
    image_keys = [k for k in keys if features[k]["dtype"] == "image"]
    raw = ds.hf_dataset.with_format(None).select_columns(image_keys) if image_keys else None
    failed: set[int] = set()
    first = None
    for ep, (start, stop) in bounds.items():
        for row in sample_rows(start, stop, cfg.frames_per_episode):
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
    chk: Checker, cols: dict[str, np.ndarray], features: dict, cameras: list[str], eps: np.ndarray, cfg
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
    chk: Checker, cols: dict[str, np.ndarray], features: dict, cameras: list[str], eps: np.ndarray, cfg
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
    chk: Checker,
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
            for row in sample_rows(start, stop, cfg.frames_per_episode):
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
