"""Benchmark of the sigma network's training step and action latency (no dataset, no text encoder needed).

Per training step: render current and goal clouds (``--points`` per sample) into 5 views, run the network with the
contrastive heads (the preset's architecture from ``sigma_policy/configuration_sigma.py``), the BC + contrastive losses, backward and a LAMB step. Inference: render one cloud, forward,
heatmap argmax over the 3D grid. Language tokens are random (B, 77, 384) MiniLM-shaped tensors.

    python benchmarks/bench_network.py --config paper --device cuda --batch-size 32
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time

import torch
import torch.nn.functional as F


def main() -> None:
    from sigma_policy.configuration_sigma import SigmaConfig
    from sigma_policy.contrastive import contrastive_losses
    from sigma_policy.lamb import Lamb
    from sigma_policy.network import SigmaNetwork
    from sigma_policy.renderer import VirtualViewRenderer

    ap = argparse.ArgumentParser()
    ap.add_argument("--config", choices=["paper", "small"], default="paper")
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--batch-size", type=int, default=32)
    ap.add_argument("--points", type=int, default=65536)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--no-bf16", action="store_true")
    ap.add_argument("--compile", action="store_true")
    ap.add_argument(
        "--layout",
        choices=["auto", "nhwc", "nchw"],
        default="auto",
        help="conv activations: auto = NHWC on the CPU, NCHW on CUDA (sigma_policy/layers.py ConvBlock); nhwc also "
        "turns the weights",
    )
    ap.add_argument("--lamb-loop", action="store_true", help="per-parameter LAMB update instead of foreach")
    ap.add_argument("--profile", action="store_true", help="print the top kernels of two profiled steps")
    args = ap.parse_args()
    dev, b = args.device, args.batch_size
    layout = {"auto": None, "nhwc": True, "nchw": False}[args.layout]
    cfg = dataclasses.replace(
        SigmaConfig(preset=args.config, device=dev).network_config(), channels_last=layout
    )
    net = SigmaNetwork(cfg, 384, 384).to(dev)
    if layout:
        net = net.to(memory_format=torch.channels_last)
    renderer = VirtualViewRenderer(cfg.img_size).to(dev)
    opt = Lamb(net.parameters(), lr=1e-4, weight_decay=1e-6, foreach=not args.lamb_loop)
    torch.backends.cuda.matmul.allow_tf32 = torch.backends.cudnn.allow_tf32 = True
    torch.backends.cudnn.benchmark = True
    gpu = dev.startswith("cuda")
    amp = torch.autocast("cuda", dtype=torch.bfloat16, enabled=gpu and not args.no_bf16)
    fwd = torch.compile(net) if args.compile else net
    S, V = cfg.img_size, cfg.num_views

    def cloud(n: int):
        pts = torch.rand(n, args.points, 3, device=dev) * 2 - 1
        return (
            pts,
            torch.rand(n, args.points, 3, device=dev),
            torch.ones(n, args.points, dtype=torch.bool, device=dev),
        )

    tok, sent = torch.randn(b, 77, 384, device=dev), torch.randn(b, 384, device=dev)
    proprio = torch.rand(b, cfg.proprio_dim, device=dev) if cfg.use_proprio else None

    def step():
        img, goal = renderer(*cloud(b)), renderer(*cloud(b))
        with amp:
            out = fwd(img, tok, sent, goal, proprio)
        target = torch.rand(b, V, S * S, device=dev).softmax(-1)
        loss = -(target * out.trans.float().flatten(2).log_softmax(-1)).sum(-1).mean()
        loss = loss + F.cross_entropy(
            out.rot_logits.float().flatten(0, 1), torch.randint(0, 72, (b * 3,), device=dev)
        )
        cl = contrastive_losses(out.state_feat, out.lang_feat, out.fused_feat, out.goal_feat, out.logit_scale)
        (0.5 * loss + 0.5 * cl.total).backward()
        opt.step()
        opt.zero_grad(set_to_none=True)

    def sync():
        if gpu:
            torch.cuda.synchronize()

    for _ in range(3):
        step()
    sync()
    t = time.perf_counter()
    for _ in range(args.steps):
        step()
    sync()
    train_sps = args.steps * b / (time.perf_counter() - t)
    if args.profile:
        from torch.profiler import ProfilerActivity, profile

        acts = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if gpu else [])
        with profile(activities=acts) as prof:
            for _ in range(2):
                step()
            sync()
        key = "self_cuda_time_total" if gpu else "self_cpu_time_total"
        print(prof.key_averages().table(sort_by=key, row_limit=30, max_name_column_width=60))

    net.eval()
    times = []
    with torch.no_grad():
        for i in range(25):
            sync()
            t = time.perf_counter()
            img = renderer(*cloud(1))
            with amp:
                out = fwd(img, tok[:1], proprio=None if proprio is None else proprio[:1])
            hm = out.trans.float().softmax(-1)  # stand-in for the 3D argmax: per-view argmax
            hm.flatten(2).argmax(-1)
            out.rot_logits.argmax(-1)
            sync()
            if i >= 5:
                times.append(time.perf_counter() - t)
    times.sort()
    res = {
        "config": args.config,
        "device": torch.cuda.get_device_name() if gpu else "cpu",
        "params": net.num_parameters(),
        "batch": b,
        "points": args.points,
        "bf16": gpu and not args.no_bf16,
        "compile": args.compile,
        "layout": args.layout,
        "lamb": "loop" if args.lamb_loop else "foreach",
        "train_samples_per_s": round(train_sps, 1),
        "action_ms": round(1000 * times[len(times) // 2], 2),
    }
    if gpu:
        res["peak_mem_gb"] = round(torch.cuda.max_memory_allocated() / 2**30, 1)
    print(json.dumps(res))


if __name__ == "__main__":
    main()
