"""Torch-only benchmark of the sigma training step and action latency (no LeRobot, no text encoder needed).

Per training step: render current and goal clouds (``--points`` per sample) into 5 views, run the network with the
contrastive heads, the BC + contrastive losses, backward and a LAMB step. Inference: render one cloud, forward,
heatmap argmax over the 3D grid. Language tokens are random (B, 77, 384) MiniLM-shaped tensors.

    python benchmarks/bench_network.py --config paper --device cuda --batch-size 32
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import types
from pathlib import Path

import torch
import torch.nn.functional as F

ROOT = Path(__file__).resolve().parents[1]


def import_without_lerobot() -> None:
    """Import the torch-only sigma_policy modules without running the package __init__ (which needs LeRobot)."""
    pkg = types.ModuleType("sigma_policy")
    pkg.__path__ = [str(ROOT / "sigma_policy")]
    sys.modules.setdefault("sigma_policy", pkg)
    try:
        import lerobot.optim.optimizers  # noqa: F401
    except ImportError:  # minimal stand-in so that sigma_policy.lamb imports

        class _Cfg:
            @classmethod
            def register_subclass(cls, name):
                return lambda c: c

        for name in ("lerobot", "lerobot.optim", "lerobot.optim.optimizers"):
            sys.modules[name] = types.ModuleType(name)
        sys.modules["lerobot.optim.optimizers"].OptimizerConfig = _Cfg
        sys.modules["lerobot.optim.optimizers"].OptimizerParams = object


PAPER = {
    "img_size": 220,
    "patch_size": 11,
    "im_channels": 64,
    "final_dim": 64,
    "attn_dim": 512,
    "attn_heads": 8,
    "attn_dim_head": 64,
    "num_view_layers": 2,
    "num_query_layers": 2,
    "num_fusion_layers": 4,
    "decoder_kernel": 11,
}

SMALL = {
    "img_size": 64,
    "patch_size": 8,
    "im_channels": 16,
    "final_dim": 16,
    "attn_dim": 128,
    "attn_heads": 4,
    "attn_dim_head": 32,
    "num_view_layers": 1,
    "num_query_layers": 1,
    "num_fusion_layers": 2,
    "decoder_kernel": 3,
    "attn_dropout": 0.0,
}


def main() -> None:
    import_without_lerobot()
    from sigma_policy.contrastive import contrastive_losses
    from sigma_policy.lamb import Lamb
    from sigma_policy.network import NetworkConfig, SigmaNetwork
    from sigma_policy.renderer import VirtualViewRenderer

    ap = argparse.ArgumentParser()
    ap.add_argument("--config", choices=["paper", "small"], default="paper")
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--batch-size", type=int, default=32)
    ap.add_argument("--points", type=int, default=65536)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--no-bf16", action="store_true")
    ap.add_argument("--compile", action="store_true")
    ap.add_argument("--channels-last", action="store_true", help="NHWC conv activations and weights")
    ap.add_argument("--lamb-loop", action="store_true", help="per-parameter LAMB update instead of foreach")
    ap.add_argument("--profile", action="store_true", help="print the top kernels of two profiled steps")
    args = ap.parse_args()
    dev, b = args.device, args.batch_size
    cfg = NetworkConfig(**(PAPER if args.config == "paper" else SMALL), channels_last=args.channels_last)
    net = SigmaNetwork(cfg, 384, 384).to(dev)
    if args.channels_last:
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

    def step():
        img, goal = renderer(*cloud(b)), renderer(*cloud(b))
        with amp:
            out = fwd(img, tok, sent, goal)
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
                out = fwd(img, tok[:1])
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
        "channels_last": args.channels_last,
        "lamb": "loop" if args.lamb_loop else "foreach",
        "train_samples_per_s": round(train_sps, 1),
        "action_ms": round(1000 * times[len(times) // 2], 2),
    }
    if gpu:
        res["peak_mem_gb"] = round(torch.cuda.max_memory_allocated() / 2**30, 1)
    print(json.dumps(res))


if __name__ == "__main__":
    main()
