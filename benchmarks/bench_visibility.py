"""Which objects can each virtual view see? Pixels per object and view, with horizontal or tilted side views,
at the start frame or later keyframes, with or without the hand's points.

A policy can only tell the objects apart where its views show them. For every scene a dataset recorded under
several instructions (PickPlace: the same scene with "milk", "bread", "cereal", "can"), the scene is rebuilt in
robosuite from its collection seed, and for each instruction the named object is counted in frame ``f`` (of
``frames``) of that instruction's episode: 0 is the start frame (the same for every instruction), 1 the hand at the
first keyframe (above the object), 2 at the second (lowered to the grasp point, open). The objects do not move
before the grasp, so their rebuilt geometry holds there. The frame's camera cloud is rendered as the policy renders
it (its box, image size and splat radius), once per side-view tilt (sigma_policy/views.py) and per
entry of ``hand_masks`` (true: also without the points inside PANDA_HAND_BOX, the Panda hand), and a pixel counts
for an object when the point it shows lies inside that object's bounding box (from its collision geometry,
``TaskSpec.points``; points within ``floor_clear_m`` of the object's bottom are left out, so the floor under it does
not count). docs/learning.md reads its tables ("PickPlace: the side views cannot see the bread or the can"; "The
hand hides what it is over"):

    python -m benchmarks.bench_visibility --checkpoint CKPT --tilts '[0,45]' --scenes 8
    python -m benchmarks.bench_visibility --checkpoint CKPT --frames '[0,1,2]' --hand_masks '[false,true]'

Any sigma checkpoint trained on the dataset will do: only its cameras, boxes and renderer settings are used.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import draccus
import numpy as np
import torch

from pipelines.instruction_swap import swap_scenes
from pipelines.keyframe_sets import keyframe_sets
from sigma_policy.pointcloud import (
    PANDA_HAND_BOX,
    bounds_mask,
    cube_to_world,
    drop_points,
    hand_points,
    world_to_cube,
)
from sigma_policy.renderer import VIEW_NAMES, VirtualViewRenderer


@dataclass
class VisibilityConfig:
    """Options of the visibility count."""

    checkpoint: Path | None = None  # a sigma pretrained_model directory trained on the dataset
    task: str = "pick_place"  # a task whose variations name objects (``TaskSpec.points``)
    tilts: list[float] = field(default_factory=lambda: [0.0, 45.0])  # side-view tilts to compare (degrees)
    # Frames of each instruction's episode counted: 0 the start, 1 the first keyframe (above the object), 2 the grasp.
    frames: list[int] = field(default_factory=lambda: [0])
    # false: the cloud as the checkpoint renders it; true: without the points inside PANDA_HAND_BOX (the Panda hand
    # and the arm above it, sigma_policy/pointcloud.py).
    hand_masks: list[bool] = field(default_factory=lambda: [False])
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
    kf = keyframe_sets(cfg.checkpoint)[0]
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
    variants = [(t, f, h) for t in cfg.tilts for f in cfg.frames for h in cfg.hand_masks]
    counts = {v: {n: [] for n in names} for v in variants}
    env = SigmaRobosuiteEnv(f"{cfg.task}:{names[0]}", cameras=("agentview",), image_size=32)
    try:
        for scene in scenes:
            env.reset(seed=scene.seed)
            objects = {n: spec.points(env.env, get_variation(spec, n)) for n in names}
            # The start frame is the same scene under every instruction: rendered once per scene.
            rendered: dict[tuple[int, int], dict[tuple[bool, float], tuple[np.ndarray, np.ndarray]]] = {}
            for row, instruction, name in zip(scene.rows, scene.instructions, scene.variations, strict=True):
                for frame in cfg.frames:
                    key = (scene.rows[0] if frame == 0 else row, frame)
                    if key not in rendered:
                        rendered[key] = _frame_views(
                            kf.dataset[row + frame], instruction, policy, pre, cfg, renderers
                        )
                    for (hand, tilt), (world, filled) in rendered[key].items():
                        px = object_pixels(world, filled, objects[name], cfg.margin_m, cfg.floor_clear_m)
                        counts[(tilt, frame, hand)][name].append(px)
    finally:
        env.close()
    report = {
        "checkpoint": str(cfg.checkpoint),
        "task": cfg.task,
        "scenes": len(scenes),
        "img_size": pcfg.img_size,
        "views": list(VIEW_NAMES),
        "mean_pixels": {
            _label(*v): {n: np.mean(c, 0).round(1).tolist() for n, c in per.items()}
            for v, per in counts.items()
        },
    }
    output = cfg.output or Path(cfg.checkpoint).parent / "visibility.json"
    output.write_text(json.dumps(report, indent=2))
    print(table(report))
    return report


def _frame_views(item: dict, instruction: str, policy, pre, cfg: VisibilityConfig, renderers: dict) -> dict:
    """What each view shows of one dataset frame (:func:`_rendered`), per ``(hand mask, tilt)`` of ``cfg``."""
    obs = {k: v[None] for k, v in item.items() if k.startswith("observation.")}
    with torch.inference_mode():
        points, colors, bounds = policy.input_cloud(pre(obs | {"task": [instruction]}))
    state = item["observation.state"][None].float()
    views = {}
    for hand in cfg.hand_masks:
        kept = drop_points(points, hand_points(points, state, PANDA_HAND_BOX)) if hand else points
        for tilt, renderer in renderers.items():
            views[(hand, tilt)] = _rendered(renderer, kept, colors, bounds[0])
    return views


def _rendered(
    renderer: VirtualViewRenderer, points: torch.Tensor, colors: torch.Tensor, bounds: torch.Tensor
):
    """World point ``(V, P, 3)`` each pixel of each view shows, and which pixels show one ``(V, P)``."""
    mask = bounds_mask(points, bounds)
    cube = torch.where(mask[..., None], world_to_cube(points, bounds), torch.zeros_like(points))
    with torch.inference_mode():
        views = renderer(cube, colors, mask)[0].float()  # (V, C, H, W)
    shown = views[:, :3].permute(0, 2, 3, 1).reshape(1, -1, 3)
    world = cube_to_world(shown, bounds).reshape(len(VIEW_NAMES), -1, 3).cpu().numpy()
    return world, (views[:, 6] > -1).reshape(len(VIEW_NAMES), -1).cpu().numpy()


def _label(tilt: float, frame: int, hand: bool) -> str:
    side = "horizontal" if float(tilt) == 0 else f"tilted {float(tilt):g}°"
    return f"{side}, frame {frame}" + (", hand dropped" if hand else "")


def table(report: dict) -> str:
    head = "| side views, frame | object | " + " | ".join(report["views"]) + " |"
    lines = [head, "|" + "---|" * (len(report["views"]) + 2)]
    for label, per in report["mean_pixels"].items():
        for name, px in per.items():
            lines.append(f"| {label} | {name} | " + " | ".join(f"{p:.1f}" for p in px) + " |")
    lines.append(
        f"\n{report['task']}: mean pixels per {report['img_size']}² view over {report['scenes']} training scenes "
        "(each object in its own instruction's episode)"
    )
    return "\n".join(lines)


if __name__ == "__main__":
    main(draccus.parse(VisibilityConfig))
