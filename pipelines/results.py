"""``sigma-results``: re-run the benchmarks and rebuild ``RESULTS.md`` from their reports.

Every benchmark writes a Markdown fragment (with the exact command and the machine) and a JSON file of raw
numbers to ``benchmarks/results/<name>.*`` (:func:`pipelines.reporting.write_report`). This command runs the
chosen benchmarks one after the other as subprocesses from the repository root, then stitches the fragments, in
a fixed order (experts, tolerance, ablation, compare, learning, demos, suite, collect, loader, renderer, policy),
under a short header into ``RESULTS.md``.
A fragment that does not exist yet is shown as "not measured yet" with the command that produces it, never
silently dropped; a benchmark that fails is reported with its exit status and command, and the others still run.
Numbers come only from those runs.

    sigma-results                                  # collect, loader, renderer, policy (~30 min on 2 CPU cores)
    sigma-results --include_slow true              # also experts (~45 min), tolerance (~30 min), learning (~45 min),
                                                   # demos (~50 min), suite (~70 min per seed), ablation (~1 h),
                                                   # compare (~2.5 h)
    sigma-results --stitch_only true               # run nothing, only rebuild RESULTS.md
    sigma-results --only loader,policy             # comma-separated names (also --skip)
    sigma-results --only loader --extra_args '{"loader": "--samples 5"}'   # flags appended to a command
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
    """One section of RESULTS.md and the command (run from the repository root) that writes its fragment."""

    name: str  # fragment name: benchmarks/results/<name>.md
    title: str  # section title used when the fragment is missing or the run failed
    command: str
    # Only with --include_slow (or when named in --only).
    slow: bool = False
    # The command accepts --results_dir (the fragment can go somewhere other than benchmarks/results).
    takes_results_dir: bool = True


BENCHMARKS: tuple[Benchmark, ...] = (
    Benchmark(
        "experts",
        "Scripted experts and the keyframe-replay upper bound",
        "python -m benchmarks.bench_experts --seeds 50 --workers 2",
        slow=True,
        takes_results_dir=False,
    ),
    # ~30 min: 20 expert episodes per variation of the four suite tasks, each replayed 7 times (exact, moved, turned).
    Benchmark(
        "tolerance",
        "Tolerance: keyframe replay with displaced or turned keyframes",
        "python -m benchmarks.bench_tolerance",
        slow=True,
        takes_results_dir=False,
    ),
    Benchmark(
        "ablation",
        "Contrastive-loss ablation",
        "sigma-ablate --publish true",
        slow=True,
        takes_results_dir=False,
    ),
    # ~2.5 h: collection (~8 min), sigma, ACT and Diffusion Policy (~18-21 min of lerobot-train each on 2026-11-26's
    # host), 20 evaluation episodes per variation each (stock policies' dense episodes ~6-10 min per variation).
    Benchmark(
        "compare",
        "Σ-agent vs stock LeRobot policies (same demonstrations, same evaluation seeds)",
        "sigma-compare --output_dir outputs/compare_ls --tasks '[lift,stack]' --episodes 30 --eval_episodes 20 "
        "--publish true",
        slow=True,
        takes_results_dir=False,
    ),
    # ~40 min: 6 lerobot-train runs of 600 steps, each diagnosed and evaluated closed loop (20 episodes).
    Benchmark(
        "learning",
        "Learning: the small recipe, per-head errors and closed-loop success",
        "python -m benchmarks.bench_learning",
        slow=True,
    ),
    # ~50 min: 3 lerobot-train runs of 1500 steps (10, 30, 100 demonstrations per variation of Lift + Stack),
    # each diagnosed and evaluated closed loop (30 episodes per variation).
    Benchmark(
        "demos",
        "Success against demonstrations per variation (small preset, make-demo budget)",
        "python -m benchmarks.bench_demos",
        slow=True,
    ),
    # ~80 min on an Intel Xeon with AMX-BF16 (~110 on an AMD EPYC): the five tasks, 50 demonstrations per variation,
    # one 7500-step lerobot-train run, 20 episodes per variation.
    Benchmark(
        "suite",
        "The suite on 2 CPU cores: one small policy on Lift, Stack, PickPlace, NutAssembly and Door",
        "python -m benchmarks.bench_suite",
        slow=True,
    ),
    # Times: measured on the project's 2-core machine while it was busy with training runs (quiet: less).
    # collect ~20 min (the robosuite-camera baseline alone ~25 s per episode).
    Benchmark(
        "collect",
        "Collection vs robosuite's own camera loop",
        "python -m benchmarks.bench_collect --episodes 20 --workers 2",
    ),
    # loader < 1 min (a synthetic dataset; `--root <keyframe dataset>` for a real one).
    Benchmark(
        "loader",
        "Loader: a keyframe-dataset sample as lerobot-train reads it for sigma",
        "python -m benchmarks.bench_loader --samples 40",
    ),
    # renderer ~1-2 min on CPU (adds CUDA rows where a GPU is available).
    Benchmark(
        "renderer",
        "Virtual-view renderer vs brute-force reference",
        "python -m benchmarks.bench_renderer --threads 2",
    ),
    # policy ~4 min (small preset, BC-only baseline then Σ-agent; `--config paper --device cuda` on a GPU).
    Benchmark(
        "policy",
        "Policy training and inference speed",
        "python -m benchmarks.bench_policy --config small --device cpu",
    ),
)
NAMES = tuple(b.name for b in BENCHMARKS)


@dataclass
class ResultsConfig:
    """Options of ``sigma-results``."""

    # Run only these benchmarks, comma-separated (experts, ablation, compare, learning, demos, suite, collect,
    # loader, renderer, policy); "" = all fast ones (plus the slow ones with --include_slow true).
    only: str = ""
    # Never run these, comma-separated.
    skip: str = ""
    # Also run the slow ones: experts (~45 min) and the ablation (~1 h) on 2 CPU cores.
    include_slow: bool = False
    # Run nothing; rebuild RESULTS.md from the fragments there are.
    stitch_only: bool = False
    # Extra flags appended to a benchmark's command, by name, e.g. {"loader": "--samples 5"}.
    extra_args: dict[str, str] = field(default_factory=dict)
    # Where the fragments are read from (and written to: passed to the benchmarks as --results_dir).
    results_dir: Path = RESULTS_DIR
    # The stitched report.
    output: Path = REPO / "RESULTS.md"


def _names(text: str, option: str) -> list[str]:
    """``"a, b"`` or ``"[a,b]"`` -> ``["a", "b"]``, each checked against the known benchmarks."""
    names = [n.strip() for n in text.strip().strip("[]").split(",") if n.strip()]
    unknown = [n for n in names if n not in NAMES]
    if unknown:
        raise ValueError(f"--{option}: unknown benchmark(s) {unknown}; known: {', '.join(NAMES)}")
    return names


def selected(cfg: ResultsConfig) -> list[Benchmark]:
    """The benchmarks this configuration runs, in report order."""
    only, skip = _names(cfg.only, "only"), _names(cfg.skip, "skip")
    unknown = sorted(set(cfg.extra_args) - set(NAMES))
    if unknown:
        raise ValueError(f"--extra_args: unknown benchmark(s) {unknown}; known: {', '.join(NAMES)}")
    if cfg.stitch_only:
        return []
    picked = [
        b
        for b in BENCHMARKS
        if b.name not in skip and ((b.name in only) if only else (cfg.include_slow or not b.slow))
    ]
    if Path(cfg.results_dir).resolve() != RESULTS_DIR.resolve():
        fixed = [b.name for b in picked if not b.takes_results_dir]
        if fixed:
            raise ValueError(
                f"--results_dir {cfg.results_dir}: {fixed} always write to {RESULTS_DIR}; "
                "run them with the default results_dir"
            )
    return picked


def command_for(bench: Benchmark, cfg: ResultsConfig) -> list[str]:
    """argv of ``bench`` with this interpreter (and its console scripts) and the configured extra flags."""
    argv = shlex.split(bench.command) + shlex.split(cfg.extra_args.get(bench.name, ""))
    if bench.takes_results_dir and Path(cfg.results_dir).resolve() != RESULTS_DIR.resolve():
        argv += ["--results_dir", str(Path(cfg.results_dir).resolve())]
    if argv[0] == "python":
        argv[0] = sys.executable
    else:  # a console script installed next to this interpreter (sigma-ablate)
        argv[0] = str(Path(sys.executable).with_name(argv[0]))
    return argv


def run_benchmark(bench: Benchmark, cfg: ResultsConfig) -> tuple[int, float, str]:
    """Run one benchmark from the repository root; (exit status, seconds, the command as typed).

    A negative status is the signal that killed it; 127 means the program could not be started.
    """
    argv = command_for(bench, cfg)
    shown = shlex.join([Path(argv[0]).name if argv[0] != sys.executable else "python", *argv[1:]])
    print(f"\n=== sigma-results: {bench.name}: {shown}", flush=True)
    start = time.perf_counter()
    try:
        code = subprocess.run(argv, cwd=REPO, env=dict(os.environ, HF_HUB_OFFLINE="1")).returncode
    except OSError as exc:  # the program itself is missing (a console script not installed)
        print(f"=== sigma-results: cannot start {argv[0]}: {exc}", flush=True)
        code = 127
    return code, time.perf_counter() - start, shown


def _demote(fragment: str) -> str:
    """Fragments start with a '#'/'##' title; inside RESULTS.md titles become '###' sections."""
    lines = []
    for line in fragment.splitlines():
        if line.startswith(("# ", "## ")):
            line = "### " + line.lstrip("#").strip()
        lines.append(line)
    return "\n".join(lines).strip() + "\n"


def stitch(results_dir: Path, failures: dict[str, tuple[int, str]] | None = None) -> str:
    """The text of RESULTS.md from the fragments in ``results_dir``.

    ``failures`` maps a benchmark name to (exit status, command) of a run that failed in this invocation; the
    section then says so above the previous fragment, if there is one (its numbers are from an earlier run).
    """
    failures = failures or {}
    parts = [
        "# sigma results",
        "",
        "Benchmarks and evaluation results of sigma. Every number comes from a real run of the command printed in",
        "its section, on the machine described there; speeds are ratios against a baseline measured in the same",
        "run. Absolute times depend on the machine and its load: compare ratios, or runs on the same machine.",
        "",
        "Regenerate with one command: `sigma-results` (the fast benchmarks, ~30 min on 2 CPU cores, then this file);",
        "`sigma-results --include_slow true` also re-runs the slow ones (experts, tolerance, learning, demonstrations, "
        "suite, ablation, comparison); `sigma-results "
        "--stitch_only true` only rebuilds this file from `benchmarks/results/`.",
        "",
        f"Stitched on: {machine_description()}; {time.strftime('%Y-%m-%d')}.",
        "",
    ]
    for b in BENCHMARKS:
        path = Path(results_dir) / f"{b.name}.md"
        if path.exists():
            section = _demote(path.read_text())
        else:
            section = f"### {b.title}\n\nNot measured yet: run `{b.command}`.\n"
        if b.name in failures:
            code, command = failures[b.name]
            title, _, rest = section.partition("\n")
            earlier = " The numbers below are from an earlier run." if path.exists() else ""
            note = f"**Failed** in the last `sigma-results` run (exit status {code}): `{command}`.{earlier}"
            section = f"{title}\n\n{note}\n{rest}"
        parts.append(section)
    return "\n".join(parts).rstrip() + "\n"


def run_results(cfg: ResultsConfig) -> dict:
    """Run the selected benchmarks, write ``cfg.output``; returns what ran, what failed and the wall time."""
    start = time.perf_counter()
    failures: dict[str, tuple[int, str]] = {}
    ran: list[dict] = []
    for bench in selected(cfg):
        code, seconds, shown = run_benchmark(bench, cfg)
        ran.append({"name": bench.name, "exit_status": code, "seconds": round(seconds, 1), "command": shown})
        if code != 0:
            failures[bench.name] = (code, shown)
            print(f"=== sigma-results: {bench.name} FAILED (exit status {code}): {shown}", flush=True)
    output = Path(cfg.output)
    output.write_text(stitch(cfg.results_dir, failures))
    present = [b.name for b in BENCHMARKS if (Path(cfg.results_dir) / f"{b.name}.md").exists()]
    missing = [n for n in NAMES if n not in present]
    seconds = time.perf_counter() - start
    failed = f", {len(failures)} FAILED ({', '.join(failures)})" if failures else ""
    print(
        f"\nsigma-results: {len(ran)} benchmark(s) run{failed} in {seconds / 60:.1f} min; {output} has "
        f"{len(present)}/{len(NAMES)} sections measured"
        + (f" (not measured yet: {', '.join(missing)})" if missing else "")
    )
    return {"ran": ran, "failures": failures, "missing": missing, "seconds": seconds}


def main(argv: list[str] | None = None) -> int:
    cfg = draccus.parse(ResultsConfig, args=sys.argv[1:] if argv is None else argv)
    return 1 if run_results(cfg)["failures"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
