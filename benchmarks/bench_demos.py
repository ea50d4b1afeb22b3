"""Demonstrations benchmark: closed-loop success of the ``small`` Σ-agent against the number of expert
demonstrations per variation, at the ``make demo`` budget (1500 steps × batch 8 on 2 CPU cores).

One keyframe dataset of ``max(--demos)`` demonstrations per variation (seeds from 0) and one of
``--heldout_episodes`` more per variation (seeds from 50000, for the per-head errors) are collected once; the run
with N demonstrations trains with the stock ``lerobot-train`` on the first N seeds of every variation
(``--dataset.episodes``), so the sets are nested. Every run has the same seed, steps and batch, is diagnosed
(``sigma-diagnose``: translation, yaw, gripper on training and held-out keyframes) and evaluated closed loop on the
same seeds (``sigma-eval``, from 100000, Wilson 95% intervals). Every stage resumes.

    python -m benchmarks.bench_demos                     # ~50 min on 2 CPU cores
    python -m benchmarks.bench_demos --demos '[10,30]'   # the two smaller points
    python -m benchmarks.bench_demos --tasks '[pick_place]' --demos '[30,100]' --steps 2000 --checkpoints 2 \
        --heldout_episodes 10 --eval_episodes 20 --max_keyframes 16 --output_dir outputs/demos_pp --publish false \
        --policy_args '[--policy.per_task_bounds=true,--policy.use_cpu_bf16_autocast=true]'
                                                         # PickPlace alone (docs/learning.md), ~70 min
    python -m benchmarks.bench_demos --tasks '[pick_place:bread]' --demos '[100]' --steps 2000 ...
                                                         # one object's variation alone (a task:variation name)
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass, field
from pathlib import Path

import draccus

from pipelines.training import TrainRun
from sigma_data.cameras import DEFAULT_CAMERAS

os.environ.setdefault("HF_HUB_OFFLINE", "1")


@dataclass
class DemosBenchConfig:
    """Options of the demonstrations benchmark."""

    output_dir: Path = Path("outputs/bench_demos")
    # Tasks, or single variations as sigma-eval names them ("pick_place:bread": that object's episodes only).
    tasks: list[str] = field(default_factory=lambda: ["lift", "stack"])
    # Demonstrations per variation, one training run each (the largest is what is collected).
    demos: list[int] = field(default_factory=lambda: [10, 30, 100])
    # Held-out demonstrations per variation (seeds from 50000): keyframes for the per-head errors.
    heldout_episodes: int = 10
    cameras: list[str] = field(default_factory=lambda: list(DEFAULT_CAMERAS))
    image_size: int = 64
    # Training budget of every run (the make-demo budget); checkpoints saved (and diagnosed) this many times.
    steps: int = 1500
    batch_size: int = 8
    checkpoints: int = 3
    seed: int = 0
    # Further ``lerobot-train`` options of every run, after the preset (e.g. ``--policy.per_task_bounds=true``).
    policy_args: list[str] = field(default_factory=list)
    # Closed-loop episodes per variation (seeds from 100000) and keyframes per episode.
    eval_episodes: int = 30
    max_keyframes: int = 12
    workers: int = 2
    # Write benchmarks/results/demos.{md,json} and demos.png (RESULTS.md includes them).
    publish: bool = True
    results_dir: Path | None = None


def collect_data(cfg: DemosBenchConfig) -> tuple[Path, Path]:
    from benchmarks.training_runs import collect_train_and_heldout

    return collect_train_and_heldout(
        cfg.output_dir,
        cfg.tasks,
        max(cfg.demos),
        cfg.heldout_episodes,
        cfg.cameras,
        cfg.image_size,
        cfg.workers,
        "demos",
    )


def first_seeds(root: Path, n: int) -> list[int]:
    """Episode indices of the ``n`` lowest collection seeds of every variation in keyframe dataset ``root``."""
    from sigma_data.contract import read_sidecar

    by_variation: dict[tuple[str, str], list[tuple[int, int]]] = {}
    for i, ep in enumerate(read_sidecar(root).get("episodes", [])):
        key = (str(ep.get("task")), str(ep.get("variation")))
        by_variation.setdefault(key, []).append((int(ep["seed"]), int(ep.get("episode_index", i))))
    if not by_variation:
        raise ValueError(f"{root}: meta/sigma.json lists no episodes with seeds")
    return sorted(idx for eps in by_variation.values() for _, idx in sorted(eps)[:n])


def run_dir(cfg: DemosBenchConfig, n: int) -> Path:
    """Where the run with ``n`` demonstrations per variation trains, is diagnosed and is evaluated."""
    return cfg.output_dir / "runs" / (f"demos_{n}" if cfg.seed == 0 else f"demos_{n}_seed{cfg.seed}")


def train_run(cfg: DemosBenchConfig, n: int, train_root: Path, episodes: list[int]) -> TrainRun:
    """The ``lerobot-train`` run with ``n`` demonstrations per variation: ``episodes`` of ``train_root`` (the
    first ``n`` seeds of every variation, ``first_seeds``)."""
    from sigma_data.suite import scene_bounds

    return TrainRun(
        dataset_root=train_root,
        output_dir=run_dir(cfg, n) / "train",
        steps=cfg.steps,
        batch_size=cfg.batch_size,
        scene_bounds=scene_bounds(cfg.tasks),
        seed=cfg.seed,
        job_name=f"demos_{n}",
        save_freq=max(1, cfg.steps // cfg.checkpoints),
        extra_args=[*cfg.policy_args, "--dataset.episodes=[" + ",".join(map(str, episodes)) + "]"],
    )


def run_one(cfg: DemosBenchConfig, n: int, train_root: Path, held_root: Path) -> dict:
    """Train on ``n`` demonstrations per variation (unless done), evaluate (unless done), diagnose."""
    from benchmarks.training_runs import train_evaluate_diagnose

    episodes = first_seeds(train_root, n)
    run = train_run(cfg, n, train_root, episodes)
    done = train_evaluate_diagnose(
        run,
        run_dir(cfg, n),
        held_root,
        cfg.tasks,
        f"[demos] {n} per variation ({len(episodes)} episodes)",
        episodes=cfg.eval_episodes,
        max_keyframes=cfg.max_keyframes,
        workers=cfg.workers,
    )
    return {"demos": n, "episodes": len(episodes)} | done


def numbers(result: dict) -> dict:
    """The row of one run: last checkpoint's per-head errors, success per variation and pooled."""
    last = result["diagnostics"]["checkpoints"][-1]
    train, held = last["train"]["all"], last["heldout"]["all"]
    return {
        "train_cm": train["trans_cm_median"],
        "held_cm": held["trans_cm_median"],
        "held_1cm": held["within_1cm"],
        "held_yaw": held["yaw_deg_mean"],
        "held_grip": held["gripper_acc"],
    } | eval_numbers(result["eval"])


def eval_numbers(summary: dict) -> dict:
    """Of one ``sigma-eval`` summary: success per variation, pooled (with its Wilson interval), failures by kind."""
    from pipelines.evaluate import wilson_interval

    rows = summary["variations"]
    s, n = sum(r["successes"] for r in rows), sum(r["episodes"] for r in rows)
    failures: dict[str, int] = {}
    for r in rows:
        for kind, count in r.get("failures", {}).items():
            failures[kind] = failures.get(kind, 0) + count
    return {
        "variations": {
            f"{r['task']}:{r['variation']}": (r["successes"], r["episodes"], r["ci95"]) for r in rows
        },
        "successes": s,
        "episodes": n,
        "ci95": list(wilson_interval(s, n)),
        "failures": failures,
    }


def cell(s: int, n: int, ci: list[float]) -> str:
    return f"{s}/{n} ({100 * ci[0]:.0f}–{100 * ci[1]:.0f}%)"


def markdown(cfg: DemosBenchConfig, results: list[dict]) -> str:
    rows = [numbers(r) for r in results]
    names = list(rows[0]["variations"]) if rows else []
    options = "".join(f" `{a}`" for a in cfg.policy_args)
    budget = " (the `make demo` budget)" if cfg.steps == DemosBenchConfig.steps else ""
    head = (
        f"Tasks {', '.join(cfg.tasks)}; N demonstrations per variation = the N lowest collection seeds (from 0) of "
        f"one dataset, so the sets are nested; held-out keyframes from {cfg.heldout_episodes} more per variation "
        f"(seeds from 50000); 4 cameras at {cfg.image_size}²; `small` preset{options}, {cfg.steps} `lerobot-train` "
        f"steps × batch {cfg.batch_size}, seed {cfg.seed}, CPU{budget}; closed loop: `sigma-eval`, "
        f"{cfg.eval_episodes} episodes per variation (seeds from 100000), ≤ {cfg.max_keyframes} keyframes. Errors "
        "are medians over every keyframe with a goal at the last checkpoint; yaw is the mean absolute error of the "
        "yaw bin. Single runs (one training seed per row).\n\n"
    )
    lines = [
        "| demos / variation | train cm | held-out cm | held-out ≤ 1 cm | held-out yaw ° | gripper | "
        + " | ".join(names)
        + " | all (95% CI) | failures | train s |",
        "|---" * (9 + len(names)) + "|",
    ]
    for r, n in zip(results, rows, strict=True):
        cells = " | ".join(cell(*n["variations"][k]) for k in names)
        fails = ", ".join(f"{k} {c}" for k, c in sorted(n["failures"].items(), key=lambda kv: -kv[1])) or "-"
        lines.append(
            f"| {r['demos']} | {n['train_cm']:.2f} | {n['held_cm']:.2f} | {100 * n['held_1cm']:.0f}% "
            f"| {n['held_yaw']:.1f} | {100 * n['held_grip']:.0f}% | {cells} "
            f"| **{cell(n['successes'], n['episodes'], n['ci95'])}** | {fails} | {r['train_seconds']:.0f} |"
        )
    return head + "\n".join(lines) + "\n"


def plot(results: list[dict], path: Path) -> None:
    """Success per variation against demonstrations (log x, 95% intervals), and held-out errors."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [numbers(r) for r in results]
    xs = [r["demos"] for r in results]
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    for name in rows[0]["variations"]:
        ys = [n["variations"][name][0] / n["variations"][name][1] for n in rows]
        lo = [y - n["variations"][name][2][0] for y, n in zip(ys, rows, strict=True)]
        hi = [n["variations"][name][2][1] - y for y, n in zip(ys, rows, strict=True)]
        axes[0].errorbar(xs, ys, yerr=[lo, hi], marker="o", capsize=3, label=name)
    axes[0].set_ylim(-0.05, 1.05)
    axes[0].set_title("closed-loop success (95% CI)", fontsize=10)
    axes[1].plot(xs, [n["held_cm"] for n in rows], marker="o", label="translation, median (cm)")
    axes[1].plot(xs, [n["held_yaw"] / 10 for n in rows], marker="o", label="yaw, mean (10° units)")
    axes[1].set_title("held-out keyframe errors", fontsize=10)
    for ax in axes:
        ax.set_xscale("log")
        ax.minorticks_off()
        ax.set_xticks(xs, [str(x) for x in xs])
        ax.set_xlabel("demonstrations per variation")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    from pipelines.reporting import RESULTS_DIR, write_report

    cfg = draccus.parse(DemosBenchConfig, args=sys.argv[1:] if argv is None else argv)
    if not cfg.demos or any(d < 1 for d in cfg.demos):
        raise ValueError(f"--demos must list positive counts, got {cfg.demos}")
    import sigma_data  # noqa: F401  (MUJOCO_GL before robosuite)

    train_root, held_root = collect_data(cfg)
    results = [run_one(cfg, n, train_root, held_root) for n in sorted(set(cfg.demos))]
    table = markdown(cfg, results)
    print(table)
    if cfg.publish:
        out = Path(cfg.results_dir or RESULTS_DIR)
        plot(results, out / "demos.png")
        data = [{k: v for k, v in r.items() if k != "eval"} | {"numbers": numbers(r)} for r in results]
        write_report(
            "demos",
            "Success against demonstrations per variation (small preset, make-demo budget)",
            table,
            data,
            notes="![success and held-out errors per demonstrations](benchmarks/results/demos.png)",
            results_dir=out,
        )
    best = numbers(results[-1])
    print(
        f"bench_demos: {len(results)} runs; {results[-1]['demos']} per variation: "
        f"{best['successes']}/{best['episodes']} episodes -> {cfg.output_dir}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
