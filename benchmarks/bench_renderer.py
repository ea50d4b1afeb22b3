"""Virtual-view renderer speed: ms per sample for a 65,536-point cloud -> 5 views x 220^2, 10 channels.

Rows: the vectorised renderer (``sigma_policy.renderer.VirtualViewRenderer``) on CPU at batch 1 and 8, the
brute-force reference renderer of the tests (every pixel tests every point, O(V H W N)) in the same run, and the
same on CUDA (renderer at batch 1, 8 and 32; reference at batch 1) when a GPU is available. The brute force
is timed on ``ref_points`` points on CPU (its cost is linear in N; the table gives the measured time and the
linear extrapolation to ``points``). Speed-ups are ratios of times measured in this run. After timing, the
renderer's output is checked against the reference on each device. The Markdown table (with the CPU affinity and
the devices) is printed and, with ``--publish true`` (default), written with the command and the machine to
``benchmarks/results/renderer.md`` (+ ``.json``), the fragment ``RESULTS.md`` includes.

    python -m benchmarks.bench_renderer                     # from the repository root
    taskset -c 0,1 python -m benchmarks.bench_renderer --threads 2   # "2 CPU cores", as the goal is stated
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import draccus
import torch

from sigma_policy.renderer import VirtualViewRenderer
from tests.sigma_policy.test_renderer import reference_render


@dataclass
class BenchRendererConfig:
    # Points per sample (65,536 = 4 cameras x 128^2, the paper's input).
    points: int = 65536
    # Output resolution (pixels per side).
    img_size: int = 220
    # Splat radius in pixels.
    radius_px: float = 1.32
    # Points used for the brute-force reference on CPU (its cost is linear in N).
    ref_points: int = 2048
    # Timed repetitions per row (the median is reported) after 2 warm-up calls.
    repeats: int = 7
    # CPU threads for torch (0 = leave torch's default).
    threads: int = 2
    # Skip the CUDA rows even if a GPU is available.
    cpu_only: bool = False
    # Write benchmarks/results/renderer.md (+ .json), the fragment RESULTS.md includes.
    publish: bool = True
    # Where the fragment goes (default: benchmarks/results).
    results_dir: Path | None = None


def _cloud(B: int, N: int, device: str) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(0)
    pts = torch.rand(B, N, 3, generator=g) * 2 - 1
    feats = torch.rand(B, N, 3, generator=g)
    mask = torch.ones(B, N, dtype=torch.bool)
    return pts.to(device), feats.to(device), mask.to(device)


def _time_ms(fn: Callable[[], object], device: str, repeats: int, warmup: int = 2) -> float:
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        if device == "cuda":
            torch.cuda.synchronize()
        t0 = time.perf_counter()
        fn()
        if device == "cuda":
            torch.cuda.synchronize()
        times.append((time.perf_counter() - t0) * 1e3)
    return sorted(times)[len(times) // 2]


def main(cfg: BenchRendererConfig) -> list[tuple[str, str, int, int, float]]:
    if cfg.threads > 0:
        torch.set_num_threads(cfg.threads)
    S, r = cfg.img_size, cfg.radius_px
    renderer_cpu = VirtualViewRenderer(img_size=S, radius_px=r)
    rows: list[tuple[str, str, int, int, float]] = []  # (what, device, batch, points, ms per sample)

    devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() and not cfg.cpu_only else [])
    for device in devices:
        renderer = renderer_cpu.to(device)
        for B in (1, 8) if device == "cpu" else (1, 8, 32):
            pts, feats, mask = _cloud(B, cfg.points, device)
            ms = _time_ms(lambda: renderer(pts, feats, mask), device, cfg.repeats) / B  # noqa: B023
            rows.append(("renderer", device, B, cfg.points, ms))
        n_ref = cfg.ref_points if device == "cpu" else cfg.points
        pts, feats, mask = _cloud(1, n_ref, device)
        got = renderer(pts, feats, mask)
        want = reference_render(pts, feats, mask, S, r)
        if not torch.allclose(got, want, rtol=0, atol=1e-5):
            raise RuntimeError(
                f"renderer and brute-force reference disagree on {device} (max diff "
                f"{(got - want).abs().max().item():.3g})"
            )
        ref_args = (pts, feats, mask, S, r)
        ms = _time_ms(lambda: reference_render(*ref_args), device, max(1, cfg.repeats // 3), 1)  # noqa: B023
        rows.append(("brute-force reference", device, 1, n_ref, ms))
        if n_ref != cfg.points:
            rows.append(
                ("brute-force reference (x N linear, est.)", device, 1, cfg.points, ms * cfg.points / n_ref)
            )

    table = "\n".join(_markdown(cfg, rows, "cuda" in devices))
    print("\n" + table)
    cpu8 = next(m for w, d, b, _, m in rows if w == "renderer" and d == "cpu" and b == 8)
    summary = f"CPU renderer at batch 8: {cpu8:.2f} ms per sample (goal <= 10 ms on 2 cores)"
    if "cuda" in devices:
        gpu32 = next(m for w, d, b, _, m in rows if w == "renderer" and d == "cuda" and b == 32)
        summary += f"; CUDA at batch 32: {gpu32:.3f} ms per sample (goal <= 0.3 ms on an H100)"
    written = ""
    if cfg.publish:
        from pipelines.reporting import write_report

        if "cuda" in devices:
            notes = "CPU and CUDA rows measured in the same run."
        elif cfg.cpu_only:
            notes = "CPU rows only: the CUDA rows were skipped (`--cpu_only true`)."
        else:
            notes = (
                "CPU rows only: CUDA was not available on this machine (run it on a GPU for the CUDA rows). "
                "Last H100 measurement (2026-11-22, the CUDA path as it is now up to refactoring): 3.645 / "
                "0.477 / 0.291 ms per sample at batch 1 / 8 / 32, brute-force reference 491 ms; see docs/gpu.md."
            )
        keys = ("what", "device", "batch", "points", "ms_per_sample")
        data = {"rows": [dict(zip(keys, r, strict=True)) for r in rows], "config": asdict(cfg)}
        path = write_report(
            "renderer", "Virtual-view renderer vs brute-force reference", table, data, notes, cfg.results_dir
        )
        written = f" Written to {path}."
    print(f"\n{summary}.{written}")
    return rows


def _markdown(
    cfg: BenchRendererConfig, rows: list[tuple[str, str, int, int, float]], cuda: bool
) -> list[str]:
    affinity = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    lines = [
        f"{cfg.points} points -> 5 x {cfg.img_size}^2 x 10 channels, radius {cfg.radius_px} px; torch "
        f"{torch.__version__}, {torch.get_num_threads()} CPU threads, CPU affinity {len(affinity)} cores "
        f"{affinity}" + (f", {torch.cuda.get_device_name()}" if cuda else "") + "; median of "
        f"{cfg.repeats} calls after 2 warm-up calls.",
        "",
        "| what | device | batch | points | ms / sample | vs renderer (same device, batch 1) |",
        "|---|---|---|---|---|---|",
    ]
    for what, device, B, n, ms in rows:
        base = next(m for w, d, b, _, m in rows if w == "renderer" and d == device and b == 1)
        lines.append(f"| {what} | {device} | {B} | {n} | {ms:.3f} | {ms / base:.2f}x |")
    return lines


if __name__ == "__main__":
    main(draccus.parse(BenchRendererConfig))
