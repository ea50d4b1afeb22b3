"""``sigma-results``: re-run the benchmarks and rebuild ``RESULTS.md`` from their reports.

Every benchmark writes a Markdown fragment (with the exact command and the machine) and a JSON file of raw
numbers to ``benchmarks/results/<name>.*`` (:mod:`pipelines.reporting`). This command runs the chosen benchmarks
one after the other from the repository root, then stitches the fragments, in a fixed order, under a short
header into ``RESULTS.md``. A fragment that does not exist yet is shown as "not measured yet" with the command
that produces it, never silently dropped; a benchmark that fails is reported with its exit status and the
others still run. Numbers come only from those runs.

    sigma-results                         # the fast benchmarks (~15 min on 2 CPU cores), then RESULTS.md
    sigma-results --include_slow true     # also the 50-seed expert run (~25 min) and the ablation (~1 h)
    sigma-results --stitch_only true      # only rebuild RESULTS.md from the fragments there are
    sigma-results --only '[loader]'
"""

from __future__ import annotations

import os
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import draccus

from pipelines.reporting import RESULTS_DIR, machine_description

REPO = Path(__file__).resolve().parent.parent


@dataclass(frozen=True)
class Benchmark:
    name: str  # fragment file name in benchmarks/results (without .md)
    title: str
    command: str  # run from the repository root
    slow: bool = False  # only with --include_slow
    gpu: bool = False  # only where CUDA is available


BENCHMARKS: tuple[Benchmark, ...] = (
    Benchmark(
        "experts",
        "Scripted experts and keyframe-replay upper bound",
        "python -m benchmarks.bench_experts --seeds 50 --workers 2",
        slow=True,
    ),
    Benchmark("ablation", "Contrastive-loss ablation", "sigma-ablate --publish true", slow=True),
    Benchmark("collect", "Collection", "python -m benchmarks.bench_collect --episodes 20"),
    Benchmark("loader", "Loader", "python -m benchmarks.bench_loader --samples 40"),
    Benchmark(
        "renderer_cpu",
        "Renderer (CPU)",
        "python -m benchmarks.bench_renderer --cpu_only true --output benchmarks/results/renderer_cpu.md",
    ),
    Benchmark(
        "renderer",
        "Renderer (CPU and GPU)",
        "python -m benchmarks.bench_renderer --threads 2 --output benchmarks/results/renderer.md",
        gpu=True,
    ),
    Benchmark(
        "policy_small_cpu",
        "Policy speed (small, CPU)",
        "python -m benchmarks.bench_policy --config small --device cpu",
    ),
    Benchmark(
        "policy_paper_cuda",
        "Policy speed (paper, GPU)",
        "python -m benchmarks.bench_policy --config paper --device cuda",
        gpu=True,
    ),
)


@dataclass
class ResultsConfig:
    """Options of ``sigma-results``."""

    # Run only these benchmarks (names: experts, ablation, collect, loader, renderer_cpu, renderer,
    # policy_small_cpu, policy_paper_cuda); empty = all that apply.
    only: list[str] = field(default_factory=list)
    # Never run these.
    skip: list[str] = field(default_factory=list)
    # Also run the slow ones (experts ~25 min, ablation ~1 h on 2 CPU cores).
    include_slow: bool = False
    # Run nothing; rebuild RESULTS.md from the fragments in benchmarks/results.
    stitch_only: bool = False
    # Where the fragments are and where RESULTS.md goes.
    results_dir: Path = RESULTS_DIR
    output: Path = REPO / "RESULTS.md"


def selected(cfg: ResultsConfig, cuda: bool) -> list[Benchmark]:
    names = {b.name for b in BENCHMARKS}
    unknown = sorted((set(cfg.only) | set(cfg.skip)) - names)
    if unknown:
        raise ValueError(f"unknown benchmark(s) {unknown}; known: {sorted(names)}")
    if cfg.stitch_only:
        return []
    picked = []
    for b in BENCHMARKS:
        if cfg.only:
            if b.name in cfg.only:
                picked.append(b)
        elif b.name not in cfg.skip and (cfg.include_slow or not b.slow) and (cuda or not b.gpu):
            picked.append(b)
    return picked


def run_benchmark(bench: Benchmark) -> tuple[int, float]:
    """Run one benchmark from the repository root with this interpreter's environment; (exit status, s)."""
    argv = shlex.split(bench.command)
    if argv[0] == "python":
        argv[0] = sys.executable
    else:
        argv[0] = str(Path(sys.executable).with_name(argv[0]))
    print(f"\n=== {bench.name}: {bench.command}", flush=True)
    start = time.perf_counter()
    code = subprocess.run(argv, cwd=REPO, env=dict(os.environ, HF_HUB_OFFLINE="1")).returncode
    return code, time.perf_counter() - start


def _demote(fragment: str) -> str:
    """Fragments start with '#'/'##' titles; inside RESULTS.md they become '###' sections."""
    out = []
    for line in fragment.splitlines():
        if line.startswith("# ") or line.startswith("## "):
            line = "### " + line.lstrip("#").strip()
        out.append(line)
    return "\n".join(out).strip() + "\n"


def stitch(results_dir: Path, failures: dict[str, int] | None = None) -> str:
    """The text of RESULTS.md from the fragments in ``results_dir`` (missing ones say how to make them)."""
    failures = failures or {}
    parts = [
        "# sigma results",
        "",
        "Every number below comes from a real run of the command printed with it; the machine is described in",
        "each section (the GPU sections ran on a lent H100, the rest on the project's 2-core CPU machine).",
        "Speeds are reported as ratios against a baseline measured in the same run.",
        "",
        "Regenerate: `sigma-results` (fast benchmarks, then this file), `sigma-results --include_slow true`",
        "(everything), `sigma-results --stitch_only true` (this file only). Stitched on: "
        f"{machine_description()}, {time.strftime('%Y-%m-%d')}.",
        "",
    ]
    for b in BENCHMARKS:
        path = Path(results_dir) / f"{b.name}.md"
        if b.name in failures:
            parts += [f"### {b.title}", "", f"**Failed** (exit status {failures[b.name]}): `{b.command}`", ""]
        if path.exists():
            parts.append(_demote(path.read_text()))
        elif b.name not in failures:
            where = " (needs a CUDA GPU)" if b.gpu else ""
            parts += [f"### {b.title}", "", f"Not measured yet{where}: run `{b.command}`.", ""]
    return "\n".join(parts).rstrip() + "\n"


def run_results(cfg: ResultsConfig) -> dict:
    try:
        import torch

        cuda = torch.cuda.is_available()
    except ImportError:
        cuda = False
    start = time.perf_counter()
    failures: dict[str, int] = {}
    ran = []
    for bench in selected(cfg, cuda):
        code, seconds = run_benchmark(bench)
        ran.append((bench.name, code, seconds))
        if code != 0:
            failures[bench.name] = code
    Path(cfg.output).write_text(stitch(cfg.results_dir, failures))
    summary = {"ran": ran, "failures": failures, "seconds": time.perf_counter() - start}
    fail = f", {len(failures)} failed ({', '.join(failures)})" if failures else ""
    print(
        f"\nsigma-results: {len(ran)} benchmark(s) run{fail} in {summary['seconds'] / 60:.1f} min "
        f"-> {cfg.output}"
    )
    return summary


def main(argv: list[str] | None = None) -> int:
    cfg = draccus.parse(ResultsConfig, args=sys.argv[1:] if argv is None else argv)
    return 1 if run_results(cfg)["failures"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
