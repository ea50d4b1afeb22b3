"""Where does a policy lose which object is which? A linear probe at each stage of the network.

An instruction can only pick an object that the network's features tell apart from the others. For every scene a
dataset recorded under several instructions (PickPlace: the same start frame with "milk", "bread", "cereal",
"can"), each variation's first keyframe target marks its object; the probe reads the features at that object's
position in the top view at each stage of a trained checkpoint, and a multinomial logistic regression (features
standardised, L2 penalty, scenes split into folds so no scene is both trained and scored) says how often the
object's variation can be read from them. The stages, in the order the network computes them:

- ``pixels 3x3``: the rendered top view's xyz, rgb and depth channels in the 3 x 3 pixels at the object;
- ``pixels of its patch``: the same channels over the whole patch that holds the object (what a patch embedding,
  a linear map of the patch, can at best keep), and ``pooled``: their per-channel maximum, minimum and mean over
  the patch (the same wherever in the patch the object lies);
- ``patch embedding``, ``view token`` (after the intra-view layers), ``query-stage token`` (after the MVQ-Former,
  still before any language): the object's token;
- ``local features`` (with ``local_channels``): the local encoder's full-resolution features at the object;
- ``fused token``: the object's token after fusion, under one instruction per scene (the same for all its objects,
  so only what the image says tells them apart).

Chance is one over the number of variations. The table and the raw numbers go to ``--output`` (JSON) and stdout;
docs/learning.md ("Where the object's identity is lost") reads them for the suite's checkpoints.

    python -m benchmarks.bench_identity \\
      --checkpoint outputs/bench_suite_scan/runs/seed0_decay6000_lr0.003/train/checkpoints/last/pretrained_model \\
      --heldout_root outputs/bench_suite_scan/heldout/data/keyframe
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import draccus
import numpy as np
import torch

from pipelines.evaluate import wilson_interval
from pipelines.instruction_swap import swap_scenes
from pipelines.keyframe_sets import keyframe_sets
from sigma_policy.pointcloud import world_to_cube

TOP_VIEW = 0  # sigma_policy.renderer.VIEW_NAMES[0]
RENDERED = 7  # xyz, rgb, depth: the channels a scene gives (the rest say which view and pixel)


@dataclass
class IdentityConfig:
    """Options of the identity probe."""

    checkpoint: Path | None = None  # a sigma pretrained_model directory
    heldout_root: Path | None = None  # held-out keyframe dataset (its scenes are probed separately)
    task: str = "pick_place"  # the multi-variation task whose objects are probed
    folds: int = 5  # scenes are split into this many folds
    l2: float = 1e-2  # L2 penalty of the logistic regression (on standardised features)
    output: Path | None = None  # JSON with every number; default: <checkpoint>/../identity.json
    device: str = "cpu"


def fit_logistic(
    x: torch.Tensor, y: torch.Tensor, classes: int, l2: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """Weights ``(D, classes)`` and biases of a multinomial logistic regression with an L2 penalty (L-BFGS)."""
    w = torch.zeros(x.shape[1], classes, dtype=x.dtype, requires_grad=True)
    b = torch.zeros(classes, dtype=x.dtype, requires_grad=True)
    opt = torch.optim.LBFGS([w, b], max_iter=200, line_search_fn="strong_wolfe")

    def closure() -> torch.Tensor:
        opt.zero_grad()
        loss = torch.nn.functional.cross_entropy(x @ w + b, y) + l2 * (w**2).sum()
        loss.backward()
        return loss

    opt.step(closure)
    return w.detach(), b.detach()


def probe_accuracy(
    features: np.ndarray, labels: np.ndarray, groups: np.ndarray, folds: int, l2: float
) -> float:
    """Share of samples whose label a multinomial logistic regression, fitted on the other folds' groups, predicts."""
    classes, y = np.unique(labels, return_inverse=True)
    fold_of = {g: i % folds for i, g in enumerate(np.unique(groups))}
    fold = np.array([fold_of[g] for g in groups])
    x_all = torch.tensor(features, dtype=torch.float64)
    y_all = torch.tensor(y)
    hits = 0
    for k in range(folds):
        train, test = fold != k, fold == k
        if not test.any() or not train.any():
            continue
        mu, sd = x_all[train].mean(0), x_all[train].std(0).clamp_min(1e-6)
        w, b = fit_logistic((x_all[train] - mu) / sd, y_all[train], len(classes), l2)
        pred = (((x_all[test] - mu) / sd) @ w + b).argmax(1)
        hits += int((pred == y_all[test]).sum())
    return hits / len(labels)


def capture(network: torch.nn.Module) -> tuple[dict[str, torch.Tensor], Callable[[], None]]:
    """Forward hooks that keep each stage's output; returns the store and a function removing the hooks."""
    store: dict[str, torch.Tensor] = {}

    def keep(name: str):
        def hook(_module, _inputs, output):
            store[name] = output.detach().float()

        return hook

    modules = {
        "patch embedding": network.patchify,
        "view token": network.view_layers[-1],
        "query-stage token": network.query_layers[-1],
        "fused token": network.fusion_layers[-1],
    }
    if getattr(network, "local_encoder", None) is not None:
        modules["local features"] = network.local_encoder
    handles = [m.register_forward_hook(keep(name)) for name, m in modules.items()]
    return store, lambda: [h.remove() for h in handles]


def probe_set(policy, pre, kf, cfg: IdentityConfig) -> dict:
    """Features of every object of every multi-instruction scene of ``cfg.task`` in ``kf``, and the probe's
    accuracy per stage."""
    net = policy.acting_network()  # the weight average of an --policy.ema_decay run, as the policy acts
    ncfg = net.cfg
    t, p, v, size = ncfg.tokens_per_side, ncfg.patch_size, ncfg.num_views, ncfg.img_size
    n_img = v * t * t
    scenes = [s for s in swap_scenes(kf.dataset, kf.episodes, per_task=10**6) if s.task == cfg.task]
    store, remove = capture(net)
    feats: dict[str, list[np.ndarray]] = {}
    labels, groups, shared = [], [], 0
    try:
        for si, scene in enumerate(scenes):
            item = kf.dataset[scene.rows[0]]
            obs = {k: val[None] for k, val in item.items() if k.startswith("observation.")}
            with torch.inference_mode():
                pred = policy.predict(pre(obs | {"task": [scene.instructions[0]]}))
            top = pred.views[0, TOP_VIEW].float()
            cube = world_to_cube(torch.tensor(scene.targets, dtype=torch.float32)[None], pred.bounds[0].cpu())
            uv = policy.renderer.project(cube)[0, :, TOP_VIEW].clamp(1, size - 2)  # (objects, 2) column, row
            cols, rows = uv[:, 0].long(), uv[:, 1].long()
            tokens = (rows // p) * t + cols // p
            shared += len(tokens) - len(set(tokens.tolist()))
            stage = {
                "patch embedding": store["patch embedding"].reshape(v, -1, t * t)[TOP_VIEW].T,
                "view token": store["view token"].reshape(v, t * t, -1)[TOP_VIEW],
                "query-stage token": store["query-stage token"][0, -n_img:][: t * t]
                if ncfg.query_attention == "self"
                else store["view token"].reshape(v, t * t, -1)[TOP_VIEW],
                "fused token": store["fused token"][0, -n_img:][: t * t],
            }
            for i, variation in enumerate(scene.variations):
                c, r, k = int(cols[i]), int(rows[i]), int(tokens[i])
                pr, pc = (k // t) * p, (k % t) * p
                patch = top[:RENDERED, pr : pr + p, pc : pc + p].reshape(RENDERED, -1)
                row = {
                    "pixels 3x3": top[:RENDERED, r - 1 : r + 2, c - 1 : c + 2],
                    "pixels of its patch": patch,
                    "pixels of its patch, pooled": torch.cat([patch.amax(1), patch.amin(1), patch.mean(1)]),
                    **{name: f[k] for name, f in stage.items()},
                }
                if "local features" in store:
                    row["local features"] = store["local features"][TOP_VIEW, :, r, c]
                for name, f in row.items():
                    feats.setdefault(name, []).append(f.reshape(-1).cpu().numpy())
                labels.append(variation)
                groups.append(si)
    finally:
        remove()
    labels_a, groups_a = np.array(labels), np.array(groups)
    out: dict = {
        "scenes": len(scenes),
        "objects": len(labels),
        "variations": sorted(set(labels)),
        "objects_sharing_a_token": shared,
        "accuracy": {},
    }
    for name, rows_ in feats.items():
        acc = probe_accuracy(np.stack(rows_), labels_a, groups_a, min(cfg.folds, len(scenes)), cfg.l2)
        lo, hi = wilson_interval(round(acc * len(labels)), len(labels))
        out["accuracy"][name] = {"share": acc, "ci95": [lo, hi]}
    return out


def table(report: dict) -> str:
    """Markdown table: one row per stage, one column per keyframe set."""
    sets = [s for s in report["sets"] if report["sets"][s]["objects"]]
    head = "| stage | " + " | ".join(
        f"{s} ({report['sets'][s]['scenes']} scenes, {report['sets'][s]['objects']} objects)" for s in sets
    )
    lines = [head + " |", "|---" * (len(sets) + 1) + "|"]
    stages = list(report["sets"][sets[0]]["accuracy"]) if sets else []
    for stage in stages:
        cells = []
        for s in sets:
            a = report["sets"][s]["accuracy"][stage]
            cells.append(f"{100 * a['share']:.0f}% ({100 * a['ci95'][0]:.0f}-{100 * a['ci95'][1]:.0f}%)")
        lines.append(f"| {stage} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(cfg: IdentityConfig) -> dict:
    from pipelines.checkpoints import load_policy

    if cfg.checkpoint is None:
        raise ValueError("--checkpoint is required (a sigma pretrained_model directory)")
    policy, pre, _ = load_policy(cfg.checkpoint, cfg.device)
    sets = keyframe_sets(cfg.checkpoint, heldout_root=cfg.heldout_root)
    report = {"checkpoint": str(cfg.checkpoint), "task": cfg.task, "sets": {}}
    for kf in sets:
        report["sets"][kf.name] = probe_set(policy, pre, kf, cfg)
    if not any(s["objects"] for s in report["sets"].values()):
        raise ValueError(f"no scene of task {cfg.task!r} was recorded under more than one instruction")
    output = cfg.output or Path(cfg.checkpoint).parent / "identity.json"
    output.write_text(json.dumps(report, indent=2))
    print(table(report))
    first = next(s for s in report["sets"].values() if s["objects"])
    acc = first["accuracy"]
    print(
        f"identity probe: {cfg.task}, {first['objects']} objects, chance {100 / len(first['variations']):.0f}%; "
        f"pixels {100 * acc['pixels 3x3']['share']:.0f}%, patch embedding {100 * acc['patch embedding']['share']:.0f}%"
        f" -> {output}"
    )
    return report


if __name__ == "__main__":
    main(draccus.parse(IdentityConfig))
