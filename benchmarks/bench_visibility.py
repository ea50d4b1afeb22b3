"""Which objects can each virtual view see? Pixels per object and view, with horizontal or tilted side views.

A policy can only tell the objects apart where its views show them. For the start frame of every scene a
dataset recorded under several instructions (PickPlace: the same scene with "milk", "bread", "cereal", "can"),
the scene is rebuilt in robosuite from its collection seed, the frame's camera cloud is rendered as the policy
renders it (its box, image size and splat radius), once per side-view tilt (sigma_policy/views.py), and a pixel
counts for an object when the point it shows lies inside that object's bounding box (from its collision geometry,
``TaskSpec.points``; points within ``floor_clear_m`` of the object's bottom are left out, so the floor under it does
not count). docs/learning.md ("PickPlace: the side views cannot see the bread or the can") reads its table:

    python -m benchmarks.bench_visibility --checkpoint CKPT --tilts '[0,45]' --scenes 8

Any sigma checkpoint trained on the dataset will do: only its cameras, boxes and renderer settings are used.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import draccus
import numpy as np
import torch

from pipelines.diagnostics import DiagnoseConfig, keyframe_sets
from pipelines.instruction_swap import swap_scenes
from sigma_policy.pointcloud import bounds_mask, cube_to_world, world_to_cube
from sigma_policy.renderer import VIEW_NAMES, VirtualViewRenderer


@dataclass
class VisibilityConfig:
    """Options of the visibility count."""

    checkpoint: Path | None = None  # a sigma pretrained_model directory trained on the dataset
    task: str = "pick_place"  # a task whose variations name objects (``TaskSpec.points``)
    tilts: list[float] = field(default_factory=lambda: [0.0, 45.0])  # side-view tilts to compare (degrees)
    scenes: int = 8  # training scenes counted (the first of the keyframe dataset)
    margin_m: float = 0.005  # the objects' boxes are grown by this much
    floor_clear_m: float = 0.005  # points this close above an object's bottom are not counted (the floor)
    output: Path | None = None  # JSON with every count; default: <checkpoint>/../visibility.json
    device: str = "cpu"


def object_pixels(
    world: np.ndarray, filled: np.ndarray, points: np.ndarray, margin_m: float, floor_clear_m: float
) -> np.ndarray:
    """Pixels per view ``(V,)`` whose shown point ``world (V, P, 3)`` (``filled (V, P)``) lies inside the bounding
    box of an object's ``points (N, 3)``, grown by ``margin_m``, above its bottom by ``floor_clear_m``."""
    lo, hi = points.min(0) - margin_m, points.max(0) + margin_m
    lo[2] = points[:, 2].min() + floor_clear_m
    return (np.all((world >= lo) & (world <= hi), -1) & filled).sum(-1)


def main(cfg: VisibilityConfig) -> dict:
    from pipelines.checkpoints import load_policy
    from sigma_data.sim_env import SigmaRobosuiteEnv
    from sigma_data.suite import get_task, get_variation

    if cfg.checkpoint is None:
        raise ValueError("--checkpoint is required (a sigma pretrained_model directory)")
    spec = get_task(cfg.task)
    if spec.points is None:
        raise ValueError(f"task {cfg.task!r} has no object geometry (TaskSpec.points) to count pixels of")
    policy, pre, _ = load_policy(cfg.checkpoint, cfg.device)
    kf = keyframe_sets(DiagnoseConfig(checkpoint=cfg.checkpoint), cfg.checkpoint)[0]
    scenes = [s for s in swap_scenes(kf.dataset, kf.episodes, per_task=10**6) if s.task == cfg.task][
        : cfg.scenes
    ]
    if not scenes:
        raise ValueError(f"no scene of task {cfg.task!r} was recorded under more than one instruction")
    pcfg = policy.config
    renderers = {
        t: VirtualViewRenderer(pcfg.img_size, pcfg.render_radius_px, side_tilt_deg=t) for t in cfg.tilts
    }
    names = [v.name for v in spec.variations]
    counts = {t: {n: [] for n in names} for t in cfg.tilts}
    env = SigmaRobosuiteEnv(f"{cfg.task}:{names[0]}", cameras=("agentview",), image_size=32)
    try:
        for scene in scenes:
            env.reset(seed=scene.seed)
            item = kf.dataset[scene.rows[0]]
            obs = {k: v[None] for k, v in item.items() if k.startswith("observation.")}
            with torch.inference_mode():
                points, colors, bounds = policy.input_cloud(pre(obs | {"task": [scene.instructions[0]]}))
            bounds = bounds[0]
            mask = bounds_mask(points, bounds)
            cube = torch.where(mask[..., None], world_to_cube(points, bounds), torch.zeros_like(points))
            objects = {n: spec.points(env.env, get_variation(spec, n)) for n in names}
            for tilt, renderer in renderers.items():
                with torch.inference_mode():
                    views = renderer(cube, colors, mask)[0].float()  # (V, C, H, W)
                shown = views[:, :3].permute(0, 2, 3, 1).reshape(1, -1, 3)
                world = cube_to_world(shown, bounds).reshape(len(VIEW_NAMES), -1, 3).cpu().numpy()
                filled = (views[:, 6] > -1).reshape(len(VIEW_NAMES), -1).cpu().numpy()
                for n, pts in objects.items():
                    counts[tilt][n].append(object_pixels(world, filled, pts, cfg.margin_m, cfg.floor_clear_m))
    finally:
        env.close()
    report = {
        "checkpoint": str(cfg.checkpoint),
        "task": cfg.task,
        "scenes": len(scenes),
        "img_size": pcfg.img_size,
        "views": list(VIEW_NAMES),
        "mean_pixels": {
            str(t): {n: np.mean(c, 0).round(1).tolist() for n, c in per.items()} for t, per in counts.items()
        },
    }
    output = cfg.output or Path(cfg.checkpoint).parent / "visibility.json"
    output.write_text(json.dumps(report, indent=2))
    print(table(report))
    return report


def table(report: dict) -> str:
    head = "| side views | object | " + " | ".join(report["views"]) + " |"
    lines = [head, "|" + "---|" * (len(report["views"]) + 2)]
    for tilt, per in report["mean_pixels"].items():
        label = "horizontal" if float(tilt) == 0 else f"tilted {float(tilt):g}°"
        for name, px in per.items():
            lines.append(f"| {label} | {name} | " + " | ".join(f"{p:.1f}" for p in px) + " |")
    lines.append(
        f"\n{report['task']}: mean pixels per {report['img_size']}² view over {report['scenes']} training scenes"
    )
    return "\n".join(lines)


if __name__ == "__main__":
    main(draccus.parse(VisibilityConfig))
