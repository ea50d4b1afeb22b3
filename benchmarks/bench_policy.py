"""Policy speed: training samples/s with the contrastive loss vs the BC-only step, and inference latency.

Measures the full policy step the trainer runs (point clouds from depth, SE(3) augmentation, rendering of current
and goal, network, losses, backward, LAMB step) and ``select_action`` on single observations, with synthetic
RGB-D batches shaped like the data contract (cameras x H x W, depth in metres) so no dataset is needed.

Baseline, measured in the same run: the same preset with ``use_contrastive=False`` (the BC-only, RVT-style
step: no goal render, no contrastive heads), timed alternately with the Σ-agent step so both see the same
machine load; the ratio of training samples/s is the cost of contrastive IL.
Inference latency is compared with the goal of issue 6 (<= 1 s per action on CPU, <= 20 ms on a GPU).

    python -m benchmarks.bench_policy --config small --device cpu      # small on CPU (the sigma-results run)
    python -m benchmarks.bench_policy --config paper --device cuda     # paper on a GPU
    python -m benchmarks.bench_policy --steps 2 --reps 3 --publish false

Flags are draccus-style (``--batch_size``, ``--camera_size``, ``--contrastive false`` to time the baseline only,
``--compare_layouts true`` to time the Σ-agent step with NCHW convolutions too, ``--compare_views '[top,front,left]'``
to time it rendering only those virtual views too: RVT-2's three, docs/method.md §4.1).
``benchmarks/bench_network.py`` is the torch-only variant (renderer + network + losses + LAMB, random language
tokens) for machines without LeRobot.

Goals (issue 6): paper >= 90 training samples/s on one H100, <= 20 ms per action; <= 1 s per action on CPU.
Numbers are machine-dependent: compare runs on the same machine only. The output ends with a one-line summary.
"""

from __future__ import annotations

import json
import os
import statistics
import time
from dataclasses import dataclass, field
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import draccus
import torch
from lerobot.configs.types import FeatureType, PolicyFeature
from tqdm import tqdm

from sigma_policy.configuration_sigma import SigmaConfig
from sigma_policy.modeling_sigma import SigmaPolicy

BOUNDS = [-0.3, -0.3, 0.7, 0.3, 0.3, 1.3]


def features(cameras: list[str], size: int) -> dict[str, PolicyFeature]:
    feats = {}
    for cam in cameras:
        feats[f"observation.images.{cam}"] = PolicyFeature(FeatureType.VISUAL, (3, size, size))
        feats[f"observation.images.{cam}_depth"] = PolicyFeature(FeatureType.VISUAL, (1, size, size))
        feats[f"observation.camera.{cam}.intrinsics"] = PolicyFeature(FeatureType.STATE, (3, 3))
        feats[f"observation.camera.{cam}.extrinsics"] = PolicyFeature(FeatureType.STATE, (4, 4))
    feats["observation.state"] = PolicyFeature(FeatureType.STATE, (10,))
    return feats


def synthetic_batch(cameras: list[str], size: int, batch: int, frames: int | None, device: str) -> dict:
    """Cameras 0.6 m above a table at z = 0.8 looking down, random RGB, depth with a little relief."""
    f = 0.5 * size / torch.tan(torch.deg2rad(torch.tensor(30.0)))
    K = torch.tensor([[f, 0, size / 2], [0, f, size / 2], [0, 0, 1.0]])
    shape = (batch,) if frames is None else (batch, frames)
    out: dict = {}
    for i, cam in enumerate(cameras):
        E = torch.eye(4)
        E[:3, :3] = torch.tensor([[1.0, 0, 0], [0, -1, 0], [0, 0, -1]])
        E[:3, 3] = torch.tensor([0.05 * i, 0.0, 1.4])
        out[f"observation.images.{cam}"] = torch.rand(*shape, 3, size, size, device=device)
        out[f"observation.images.{cam}_depth"] = 0.6 - 0.1 * torch.rand(*shape, 1, size, size, device=device)
        out[f"observation.camera.{cam}.intrinsics"] = K.expand(*shape, 3, 3).to(device)
        out[f"observation.camera.{cam}.extrinsics"] = E.expand(*shape, 4, 4).to(device)
    state = torch.tensor([0.0, 0.0, 0.9, 1, 0, 0, 0, 1, 0.04, 0.04])
    out["observation.state"] = state.expand(*shape, 10).to(device)
    out["task"] = [f"put the block in drawer {i % 3}" for i in range(batch)]
    return out


def sync(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize()


@dataclass
class Variant:
    """One policy under test, with its optimiser and inputs, and the step times measured so far (seconds)."""

    contrastive: bool
    # The convolutions' activation layout: "auto" (NHWC on the CPU, sigma_policy/layers.py ConvBlock) or "nchw".
    layout: str
    # The virtual views rendered (None = the preset's five).
    views: list[str] | None
    policy: SigmaPolicy
    optimizer: torch.optim.Optimizer
    train_batch: dict
    obs: dict
    train_s: list[float] = field(default_factory=list)
    infer_s: list[float] = field(default_factory=list)


def train_step(v: Variant, device: str) -> float:
    """One full training step (forward with losses, backward, optimiser step); wall seconds."""
    sync(device)
    start = time.perf_counter()
    loss, _ = v.policy.forward(v.train_batch)
    v.optimizer.zero_grad(set_to_none=True)
    loss.backward()
    v.optimizer.step()
    sync(device)
    return time.perf_counter() - start


@torch.no_grad()
def infer_step(v: Variant, device: str) -> float:
    """One ``select_action`` on a single observation; wall seconds."""
    sync(device)
    start = time.perf_counter()
    v.policy.select_action(v.obs)
    sync(device)
    return time.perf_counter() - start


@dataclass
class PolicyBenchConfig:
    # Policy preset: small | paper.
    config: str = "small"
    # Torch device: cpu, cuda, cuda:1, ...
    device: str = "cpu"
    # Training batch size (default: 8 for small, 32 for paper).
    batch_size: int | None = None
    # Synthetic RGB-D cameras and their image size in pixels (square).
    cameras: int = 4
    camera_size: int = 128
    # Timed training steps per variant (default: 5 on CPU, 20 on GPU; the median is reported), after 2 (CPU) /
    # 5 (GPU) warm-up steps.
    steps: int | None = None
    # Timed select_action calls (default: 10 on CPU, 50 on GPU; the median is reported), after 2 warm-up calls.
    reps: int | None = None
    # torch CPU threads.
    threads: int = 2
    # Also time the Σ-agent step (BC + contrastive); false = the BC-only baseline alone.
    contrastive: bool = True
    # Also time the Σ-agent step with NCHW convolution activations (the layout before 2026-12-06; on the CPU the
    # default is NHWC): the ratio is what the layout buys on this machine.
    compare_layouts: bool = False
    # Also time the Σ-agent step rendering only these virtual views (e.g. '[top,front,left]', RVT-2's three;
    # docs/method.md §4.1): the ratio is what the fewer views buy on this machine.
    compare_views: list[str] | None = None
    # Write benchmarks/results/policy.md (+ .json), the fragment RESULTS.md includes.
    publish: bool = True
    # Where the fragment goes (default: benchmarks/results).
    results_dir: Path | None = None

    def __post_init__(self) -> None:
        if self.config not in ("small", "paper"):
            raise ValueError(f"--config must be small or paper, got {self.config!r}")
        if self.device.startswith("cuda") and not torch.cuda.is_available():
            raise ValueError(f"--device {self.device}: CUDA is not available on this machine")


def build(
    cfg: PolicyBenchConfig,
    contrastive: bool,
    batch_size: int,
    layout: str = "auto",
    views: list[str] | None = None,
) -> Variant:
    """The policy of the preset (``use_contrastive``, the convolutions' ``layout`` and the virtual ``views`` as
    given), its LAMB optimiser and synthetic inputs."""
    cams = [f"cam{i}" for i in range(cfg.cameras)]
    torch.manual_seed(0)
    policy_cfg = SigmaConfig(
        preset=cfg.config,
        device=cfg.device,
        input_features=features(cams, cfg.camera_size),
        output_features={"action": PolicyFeature(FeatureType.ACTION, (9,))},
        depth_unit="m",
        scene_bounds=BOUNDS,
        use_contrastive=contrastive,
        **({"virtual_views": views} if views else {}),
    )
    policy = SigmaPolicy(policy_cfg).to(cfg.device)
    policy.network.set_conv_layout({"auto": None, "nchw": False}[layout])
    optimizer = policy_cfg.get_optimizer_preset().build(policy.get_optim_params())
    train_batch = synthetic_batch(cams, cfg.camera_size, batch_size, 2, cfg.device)
    train_batch["action"] = torch.tensor(
        [[0.0, 0.05, 0.85, 1, 0, 0, 0, 1, 0]] * batch_size, device=cfg.device
    )
    obs = synthetic_batch(cams, cfg.camera_size, 1, None, cfg.device)
    return Variant(contrastive, layout, views, policy, optimizer, train_batch, obs)


def measure(cfg: PolicyBenchConfig, variants: list[Variant], steps: int, reps: int) -> list[dict]:
    """Time training steps, then ``select_action`` calls, alternating between the variants step by step.

    Alternating (A B A B ...) exposes every variant to the same load on a shared machine, so the ratio stays
    meaningful when absolute times drift. Reports medians. GPU peak memory is taken per variant during its
    warm-up steps (2 on CPU, 5 on GPU), before the interleaved timing.
    """
    gpu = cfg.device.startswith("cuda")
    peak_gb = {}
    for i, v in enumerate(variants):
        v.policy.train()
        if gpu:
            torch.cuda.reset_peak_memory_stats()
        for _ in range(5 if gpu else 2):
            train_step(v, cfg.device)
        if gpu:
            peak_gb[i] = round(torch.cuda.max_memory_allocated() / 2**30, 2)
    for _ in tqdm(range(steps), desc="train steps (all variants)", leave=False):
        for v in variants:
            v.train_s.append(train_step(v, cfg.device))
    for v in variants:
        v.policy.eval()
    for i in tqdm(range(2 + reps), desc="select_action (all variants)", leave=False):
        for v in variants:
            seconds = infer_step(v, cfg.device)
            if i >= 2:  # 2 warm-up calls
                v.infer_s.append(seconds)
    rows = []
    for i, v in enumerate(variants):
        batch_size = len(v.train_batch["task"])
        row = {
            "contrastive": v.contrastive,
            "layout": v.layout,
            "views": v.views,
            "params_train": v.policy.network.num_parameters(),
            "params_inference": v.policy.network.num_parameters(inference_only=True),
            "train_samples_per_s": round(batch_size / statistics.median(v.train_s), 3),
            "inference_ms_per_action": round(1000 * statistics.median(v.infer_s), 2),
            "train_step_s": [round(t, 4) for t in v.train_s],
            "inference_s": [round(t, 4) for t in v.infer_s],
        }
        if gpu:
            row["peak_mem_gb"] = peak_gb[i]
        rows.append(row)
    return rows


def markdown(
    cfg: PolicyBenchConfig, rows: list[dict], device: str, batch_size: int, steps: int, reps: int
) -> str:
    goal_ms = 20 if cfg.device.startswith("cuda") else 1000
    base = rows[0]["train_samples_per_s"]
    gpu_mem = "peak GPU memory (training) | " if "peak_mem_gb" in rows[0] else ""
    lines = [
        f"`{cfg.config}` preset on {device}; training batch {batch_size}, median of {steps} timed steps; inference "
        f"batch 1, median of {reps} calls; the variants alternate step by step; {cfg.cameras} synthetic RGB-D cameras at {cfg.camera_size}². Training step = "
        "point clouds, SE(3) augmentation, renders, network, losses, backward, LAMB step.",
        "",
        f"| variant | parameters (train / inference) | train samples/s | vs BC-only | {gpu_mem}"
        f"ms per action | vs goal ({goal_ms} ms) |",
        "|---|---|---|---|---|---|" + ("---|" if gpu_mem else ""),
    ]
    for r in rows:
        name = (
            "Σ-agent (BC + contrastive, current + goal render)" if r["contrastive"] else "BC only (baseline)"
        ) + (", NCHW convolutions" if r["layout"] == "nchw" else "")
        name += f", views {', '.join(r['views'])}" if r["views"] else ""
        ms = r["inference_ms_per_action"]
        verdict = f"{ms / goal_ms:.2f}x the budget: {'met' if ms <= goal_ms else 'not met'}"
        mem = f"{r['peak_mem_gb']:.2f} GiB | " if gpu_mem else ""
        lines.append(
            f"| {name} | {r['params_train'] / 1e6:.2f} M / {r['params_inference'] / 1e6:.2f} M | "
            f"{r['train_samples_per_s']:.2f} | {r['train_samples_per_s'] / base:.2f}x | {mem}{ms:.1f} | {verdict} |"
        )
    return "\n".join(lines)


def main(cfg: PolicyBenchConfig) -> list[dict]:
    torch.set_num_threads(cfg.threads)
    gpu = cfg.device.startswith("cuda")
    batch_size = cfg.batch_size or (32 if cfg.config == "paper" else 8)
    steps = cfg.steps or (20 if gpu else 5)
    reps = cfg.reps or (50 if gpu else 10)
    if gpu:
        torch.backends.cuda.matmul.allow_tf32 = True
        torch.backends.cudnn.allow_tf32 = True
        torch.backends.cudnn.benchmark = True
    # The baseline of the same run first: the BC-only (RVT-style) step, which renders no goal and has no
    # contrastive heads; the ratio of the Σ-agent row to it is the cost of contrastive IL.
    variants = [build(cfg, c, batch_size) for c in ([False, True] if cfg.contrastive else [False])]
    if cfg.compare_layouts:
        variants.append(build(cfg, cfg.contrastive, batch_size, layout="nchw"))
    if cfg.compare_views:
        variants.append(build(cfg, cfg.contrastive, batch_size, views=cfg.compare_views))
    rows = measure(cfg, variants, steps, reps)
    device = torch.cuda.get_device_name(cfg.device) if gpu else f"CPU, {cfg.threads} torch threads"
    table = markdown(cfg, rows, device, batch_size, steps, reps)
    print(json.dumps(rows, indent=2))
    print("\n" + table)
    if cfg.publish:
        from pipelines.reporting import write_report

        write_report(
            "policy",
            f"Policy training and inference speed ({cfg.config} preset, {'GPU' if gpu else 'CPU'})",
            table,
            {
                "preset": cfg.config,
                "device": device,
                "batch_size": batch_size,
                "steps": steps,
                "reps": reps,
                "rows": rows,
            },
            notes="Training speed is compared with the BC-only step of the same preset measured in the same run "
            "(`use_contrastive=False`); inference latency with the goal of issue 6 (<= 1 s per action on CPU, "
            "<= 20 ms on a GPU). Synthetic inputs: no dataset reads are timed (see the loader section).",
            results_dir=cfg.results_dir,
        )
    last = rows[1] if cfg.contrastive else rows[0]
    overhead = (
        f", {rows[1]['train_samples_per_s'] / rows[0]['train_samples_per_s']:.2f}x BC-only"
        if cfg.contrastive
        else ""
    )
    if cfg.compare_layouts:
        nchw = next(r for r in rows if r["layout"] == "nchw")
        overhead += f", {last['train_samples_per_s'] / nchw['train_samples_per_s']:.2f}x NCHW convolutions"
    if cfg.compare_views:
        overhead += (
            f", {rows[-1]['train_samples_per_s'] / last['train_samples_per_s']:.2f}x with views "
            f"{','.join(cfg.compare_views)}"
        )
    print(
        f"bench_policy: {cfg.config} on {device}: {last['train_samples_per_s']:.2f} train samples/s "
        f"(batch {batch_size}{overhead}), {last['inference_ms_per_action']:.1f} ms per action"
    )
    return rows


if __name__ == "__main__":
    main(draccus.parse(PolicyBenchConfig))
