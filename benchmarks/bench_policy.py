"""Benchmark of the sigma policy: training samples/s and inference latency per action.

Measures the full policy step the trainer runs (point clouds from depth, SE(3) augmentation, rendering of current
and goal, network, losses, backward, LAMB step) and ``select_action`` on single observations, with synthetic
RGB-D batches shaped like the data contract (cameras x H x W, depth in metres) so no dataset is needed.

    python benchmarks/bench_policy.py --config small --device cpu      # small on CPU
    python benchmarks/bench_policy.py --config paper --device cuda     # paper on a GPU (bf16 autocast)

``benchmarks/bench_network.py`` is the torch-only variant (renderer + network + losses + LAMB, random language
tokens) for machines without LeRobot.

Goals (issue 6): paper >= 90 training samples/s on one H100, <= 20 ms per action; <= 1 s per action on CPU.
Numbers are machine-dependent: compare runs on the same machine only. The output ends with a one-line summary.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time

os.environ.setdefault("HF_HUB_OFFLINE", "1")

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


def bench_train(policy: SigmaPolicy, batch: dict, steps: int, warmup: int, device: str) -> float:
    cfg = policy.config
    opt = cfg.get_optimizer_preset().build(policy.get_optim_params())
    policy.train()
    for i in tqdm(range(warmup + steps), desc="train", leave=False):
        if i == warmup:
            sync(device)
            start = time.perf_counter()
        loss, _ = policy.forward(batch)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
    sync(device)
    return steps * len(batch["task"]) / (time.perf_counter() - start)


@torch.no_grad()
def bench_infer(policy: SigmaPolicy, obs: dict, reps: int, warmup: int, device: str) -> float:
    policy.eval()
    times = []
    for i in tqdm(range(warmup + reps), desc="infer", leave=False):
        sync(device)
        start = time.perf_counter()
        policy.select_action(obs)
        sync(device)
        if i >= warmup:
            times.append(time.perf_counter() - start)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--config", choices=["small", "paper"], default="small")
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--batch-size", type=int, default=None, help="default: 8 (small), 32 (paper)")
    parser.add_argument("--cameras", type=int, default=4)
    parser.add_argument("--camera-size", type=int, default=128)
    parser.add_argument("--steps", type=int, default=None)
    parser.add_argument("--reps", type=int, default=None)
    parser.add_argument("--threads", type=int, default=2, help="torch CPU threads")
    parser.add_argument("--no-contrastive", action="store_true", help="measure the BC-only step only")
    parser.add_argument(
        "--no-publish", action="store_true", help="do not write benchmarks/results/policy_*.md"
    )
    args = parser.parse_args()

    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    gpu = args.device.startswith("cuda")
    batch_size = args.batch_size or (32 if args.config == "paper" else 8)
    steps = args.steps or (20 if gpu else 5)
    reps = args.reps or (50 if gpu else 10)
    cams = [f"cam{i}" for i in range(args.cameras)]

    def measure(contrastive: bool) -> dict:
        torch.manual_seed(0)
        cfg = SigmaConfig(
            preset=args.config,
            device=args.device,
            input_features=features(cams, args.camera_size),
            output_features={"action": PolicyFeature(FeatureType.ACTION, (9,))},
            depth_unit="m",
            scene_bounds=BOUNDS,
            use_contrastive=contrastive,
        )
        policy = SigmaPolicy(cfg).to(args.device)
        train_batch = synthetic_batch(cams, args.camera_size, batch_size, 2, args.device)
        train_batch["action"] = torch.tensor(
            [[0.0, 0.05, 0.85, 1, 0, 0, 0, 1, 0]] * batch_size, device=args.device
        )
        samples_s = bench_train(policy, train_batch, steps, warmup=2 if not gpu else 5, device=args.device)
        latency = bench_infer(
            policy, synthetic_batch(cams, args.camera_size, 1, None, args.device), reps, 2, args.device
        )
        row = {
            "contrastive": contrastive,
            "params_train": policy.network.num_parameters(),
            "params_inference": policy.network.num_parameters(inference_only=True),
            "train_samples_per_s": round(samples_s, 2),
            "inference_ms_per_action": round(latency * 1000, 1),
        }
        if gpu:
            row["peak_mem_gb"] = round(torch.cuda.max_memory_allocated() / 2**30, 2)
        return row

    if gpu:
        torch.backends.cuda.matmul.allow_tf32 = True
        torch.backends.cudnn.allow_tf32 = True
        torch.backends.cudnn.benchmark = True
    # The baseline of the same run: the BC-only (RVT-style) step, which renders no goal and has no
    # contrastive heads; the ratio is the cost of contrastive IL.
    rows = [measure(False)] + ([] if args.no_contrastive else [measure(True)])
    device = torch.cuda.get_device_name() if gpu else f"cpu, {args.threads} torch threads"
    goal_ms = 20 if gpu else 1000
    base = rows[0]["train_samples_per_s"]
    lines = [
        f"`{args.config}` preset on {device}; batch {batch_size}; {args.cameras} synthetic RGB-D cameras at "
        f"{args.camera_size}²; training = clouds, SE(3) augmentation, renders, network, losses, backward, LAMB step.",
        "",
        "| variant | parameters (train / inference) | train samples/s | vs BC-only | ms per action (batch 1) |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        name = (
            "Σ-agent (BC + contrastive, current + goal render)" if r["contrastive"] else "BC only (RVT-style)"
        )
        lines.append(
            f"| {name} | {r['params_train'] / 1e6:.2f} M / {r['params_inference'] / 1e6:.2f} M | "
            f"{r['train_samples_per_s']:.2f} | {r['train_samples_per_s'] / base:.2f}x | "
            f"{r['inference_ms_per_action']:.1f} (goal <= {goal_ms} ms: "
            f"{'met' if r['inference_ms_per_action'] <= goal_ms else 'not met'}) |"
        )
    table = "\n".join(lines)
    print(json.dumps(rows, indent=2))
    print(table)
    if not args.no_publish:
        from pipelines.reporting import write_report

        write_report(
            f"policy_{args.config}_{'cuda' if gpu else 'cpu'}",
            f"Policy training and inference speed ({args.config}, {'GPU' if gpu else 'CPU'})",
            table,
            {"device": device, "batch_size": batch_size, "rows": rows},
        )
    last = rows[-1]
    print(
        f"bench_policy: {args.config} on {device}: {last['train_samples_per_s']} train samples/s "
        f"(batch {batch_size}), {last['inference_ms_per_action']} ms per action"
    )


if __name__ == "__main__":
    main()
