"""Learning benchmark: which training recipe makes the ``small`` Σ-agent learn on 2 CPU cores, and from how many
demonstrations. Per-head errors on training and held-out keyframes (``sigma-diagnose``) and closed-loop success
(``sigma-eval``, Wilson 95% intervals) for each run, learning curves in one PNG.

One keyframe dataset of ``--episodes`` expert demonstrations (seeds from 0) and one of ``--heldout_episodes``
(seeds from 50000) are collected once; every run trains with the stock ``lerobot-train`` on the same data, seed,
steps and batch, and is evaluated on the same seeds (from 100000). Two tables:

* **recipes**: the ``small`` preset's optimiser and augmentation as they were before (lr 3e-3, LAMB trust ratio on
  every tensor, ±12.5 cm / ±45° SE(3) augmentation) and one change at a time up to the ``small`` preset now (the rows
  before it keep the heads' inputs of that time: no local features, no gripper orientation). Every
  row has the LeakyReLU heads of the preset now: the ReLU heads' collapse shows on Lift + Stack, not on Lift alone
  (``docs/learning.md``);
* **demonstrations**: the ``small`` preset trained on the first N demonstrations (``--dataset.episodes``).

Every run resumes (a finished checkpoint is not retrained, a finished evaluation not rerun).

    python -m benchmarks.bench_learning                         # ~45 min on 2 CPU cores
    python -m benchmarks.bench_learning --demos '[]' --steps 300 --eval_episodes 10   # a quicker look
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass, field
from pathlib import Path

import draccus

from sigma_data.cameras import DEFAULT_CAMERAS

os.environ.setdefault("HF_HUB_OFFLINE", "1")

PREVIOUS_AUG = ["--policy.aug_translation_range=0.125", "--policy.aug_yaw_range_deg=45"]
# The heads' inputs before the local features and the gripper orientation (the small preset of 2026-11-23).
PREVIOUS_HEADS = [
    "--policy.local_channels=0",
    "--policy.proprio_orientation=false",
    "--policy.proprio_in_heads=false",
]
# name -> (what differs from the small preset, extra lerobot-train arguments)
RECIPES: dict[str, tuple[str, list[str]]] = {
    "previous": (
        "previous optimiser and augmentation: lr 3e-3, trust ratio on every tensor, ±12.5 cm / ±45°",
        [
            "--policy.optimizer_lr=3e-3",
            "--policy.optimizer_exempt_small=false",
            *PREVIOUS_AUG,
            *PREVIOUS_HEADS,
        ],
    ),
    "optimizer": (
        "lr 1e-2, biases/norms/queries exempt from the trust ratio, ±12.5 cm / ±45°",
        [*PREVIOUS_AUG, *PREVIOUS_HEADS],
    ),
    "aug_small": (
        "same optimiser, ±5 cm / ±15°",
        ["--policy.aug_translation_range=0.05", "--policy.aug_yaw_range_deg=15", *PREVIOUS_HEADS],
    ),
    "no_aug": (
        "same optimiser, augmentation off (the small preset of 2026-11-23)",
        ["--policy.aug_yaw_range_deg=0", *PREVIOUS_HEADS],
    ),
    "small": ("the small preset now: ±45° yaw, the heads' local features and the gripper's orientation", []),
}


@dataclass
class LearningBenchConfig:
    """Options of the learning benchmark."""

    output_dir: Path = Path("outputs/bench_learning")
    task: str = "lift"
    # Training demonstrations (seeds from 0) and held-out demonstrations (seeds from 50000) per variation.
    episodes: int = 40
    heldout_episodes: int = 20
    cameras: list[str] = field(default_factory=lambda: list(DEFAULT_CAMERAS))
    image_size: int = 64
    # Training budget of every run; checkpoints saved (and diagnosed) this many times per run.
    steps: int = 600
    batch_size: int = 8
    checkpoints: int = 3
    seed: int = 0
    # Recipe runs (names from RECIPES) and demonstration counts for the small preset (the full set is the
    # "small" recipe row; [] skips the sweep).
    recipes: list[str] = field(default_factory=lambda: list(RECIPES))
    demos: list[int] = field(default_factory=lambda: [10, 20])
    # Closed-loop episodes per run (seeds from 100000) and keyframes per episode.
    eval_episodes: int = 20
    max_keyframes: int = 12
    workers: int = 2
    # Write benchmarks/results/learning.{md,json} and learning_curves.png (RESULTS.md includes them).
    publish: bool = True
    results_dir: Path | None = None


def collect_data(cfg: LearningBenchConfig) -> tuple[Path, Path]:
    from sigma_data.cameras import RenderOptions
    from sigma_data.collect import CollectConfig, CollectOutputConfig, collect

    roots = []
    for where, episodes, start in (("train", cfg.episodes, 0), ("heldout", cfg.heldout_episodes, 50_000)):
        out = cfg.output_dir / "data" / where
        if (out / "keyframe" / "meta" / "info.json").exists():
            roots.append(out / "keyframe")
            continue
        summary = collect(
            CollectConfig(
                tasks=cfg.task,
                episodes=episodes,
                start_seed=start,
                output=CollectOutputConfig(dir=out, repo_id=f"local/learning_{where}", dense=False),
                render=RenderOptions(
                    cameras=",".join(cfg.cameras), height=cfg.image_size, width=cfg.image_size
                ),
                workers=cfg.workers,
                shard_size=10,
            )
        )
        print(summary.line(), flush=True)
        roots.append(summary.outputs["keyframe"])
    return roots[0], roots[1]


def run_one(cfg: LearningBenchConfig, name: str, args: list[str], train_root: Path, held_root: Path) -> dict:
    """Train (unless done), evaluate closed loop (unless done), diagnose every checkpoint; return the numbers."""
    from benchmarks.training_runs import train_evaluate_diagnose
    from pipelines.training import TrainRun
    from sigma_data.suite import scene_bounds

    run_dir = cfg.output_dir / "runs" / name
    run = TrainRun(
        dataset_root=train_root,
        output_dir=run_dir / "train",
        steps=cfg.steps,
        batch_size=cfg.batch_size,
        scene_bounds=scene_bounds([cfg.task]),
        seed=cfg.seed,
        job_name=name,
        save_freq=max(1, cfg.steps // cfg.checkpoints),
        extra_args=args,
    )
    done = train_evaluate_diagnose(
        run,
        run_dir,
        held_root,
        [cfg.task],
        f"[learning] {name}",
        episodes=cfg.eval_episodes,
        max_keyframes=cfg.max_keyframes,
        workers=cfg.workers,
    )
    return {"name": name, "args": args} | done


def _row_numbers(result: dict) -> dict:
    last = result["diagnostics"]["checkpoints"][-1]
    train, held = last["train"]["all"], last["heldout"]["all"]
    lift = last["heldout"]["per_step"].get("3", {})
    v = result["eval"]["variations"][0]
    return {
        "train_cm": train["trans_cm_median"],
        "held_cm": held["trans_cm_median"],
        "held_1cm": held["within_1cm"],
        "held_yaw": held["yaw_deg_mean"],
        "held_grip": held["gripper_acc"],
        "held_step3_cm": lift.get("trans_cm_median", float("nan")),
        "successes": v["successes"],
        "episodes": v["episodes"],
        "ci95": v["ci95"],
        "failures": v.get("failures", {}),
    }


def _success(n: dict) -> str:
    lo, hi = n["ci95"]
    return f"{n['successes']}/{n['episodes']} ({100 * lo:.0f}–{100 * hi:.0f}%)"


def _failures(n: dict) -> str:
    return ", ".join(f"{k} {c}" for k, c in sorted(n["failures"].items(), key=lambda kv: -kv[1])) or "-"


def markdown(cfg: LearningBenchConfig, recipes: list[dict], demos: list[dict]) -> str:
    head = (
        f"Task `{cfg.task}`; {cfg.episodes} training demonstrations (seeds 0–{cfg.episodes - 1}), held-out keyframes "
        f"from {cfg.heldout_episodes} more (seeds from 50000); 4 cameras at {cfg.image_size}²; `small` preset, "
        f"{cfg.steps} `lerobot-train` steps × batch {cfg.batch_size}, seed {cfg.seed}, CPU; closed loop: "
        f"`sigma-eval`, {cfg.eval_episodes} episodes (seeds from 100000), ≤ {cfg.max_keyframes} keyframes. "
        "Errors are medians over every keyframe with a goal (step 3 = at the grasp with the gripper closed -> the "
        "lift pose 15 cm up); yaw is the mean absolute error of the yaw bin; every row has LeakyReLU heads; "
        "single runs.\n\n"
    )
    lines = [
        "| recipe | train cm | held-out cm | held-out ≤ 1 cm | held-out step 3 cm | yaw err ° | gripper | "
        "success (95% CI) | failures | train s |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in recipes:
        n = _row_numbers(r)
        lines.append(
            f"| {RECIPES[r['name']][0]} | {n['train_cm']:.2f} | {n['held_cm']:.2f} | {100 * n['held_1cm']:.0f}% "
            f"| {n['held_step3_cm']:.1f} | {n['held_yaw']:.1f} | {100 * n['held_grip']:.0f}% | {_success(n)} "
            f"| {_failures(n)} | {r['train_seconds']:.0f} |"
        )
    text = head + "\n".join(lines) + "\n"
    if demos:
        text += (
            "\nSuccess against the number of demonstrations (`small` preset, same budget; the full set is the "
            "last recipe row):\n\n| demonstrations | train cm | held-out cm | held-out ≤ 1 cm | success (95% CI) "
            "| failures |\n|---|---|---|---|---|---|\n"
        )
        for r in demos:
            n = _row_numbers(r)
            text += (
                f"| {r['demos']} | {n['train_cm']:.2f} | {n['held_cm']:.2f} | {100 * n['held_1cm']:.0f}% "
                f"| {_success(n)} | {_failures(n)} |\n"
            )
    return text


def plot(recipes: list[dict], demos: list[dict], path: Path, cfg_episodes: int) -> None:
    """Held-out translation error against step per run, and success against demonstrations (the "small" recipe
    row is the point at ``cfg_episodes``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(14, 3.6))
    for r in recipes + demos:
        curves = r["diagnostics"]["curves"]
        label = r["name"] if "demos" not in r else f"small, {r['demos']} demos"
        axes[0].plot(curves["steps"], curves["sets"]["heldout"]["trans_cm_median"], marker="o", label=label)
        axes[1].plot(curves["steps"], curves["sets"]["heldout"]["yaw_deg_mean"], marker="o", label=label)
    axes[0].set_title("held-out translation error, median (cm)", fontsize=10)
    axes[1].set_title("held-out yaw error, mean (deg)", fontsize=10)
    for ax in axes[:2]:
        ax.set_xlabel("training step")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    if demos:
        full = [(cfg_episodes, _row_numbers(r)) for r in recipes if r["name"] == "small"]
        pts = sorted([(r["demos"], _row_numbers(r)) for r in demos] + full, key=lambda p: p[0])
        xs = [d for d, _ in pts]
        ys = [n["successes"] / n["episodes"] for _, n in pts]
        err = [
            [y - n["ci95"][0] for y, (_, n) in zip(ys, pts, strict=True)],
            [n["ci95"][1] - y for y, (_, n) in zip(ys, pts, strict=True)],
        ]
        axes[2].errorbar(xs, ys, yerr=err, marker="o", capsize=3)
        axes[2].set_xscale("log")
        axes[2].minorticks_off()
        axes[2].set_xticks(xs, [str(x) for x in xs])
    axes[2].set_title("closed-loop success vs demonstrations (95% CI)", fontsize=10)
    axes[2].set_ylim(-0.05, 1.05)
    axes[2].grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def run(cfg: LearningBenchConfig) -> tuple[list[dict], list[dict]]:
    unknown = sorted(set(cfg.recipes) - set(RECIPES))
    if unknown:
        raise ValueError(f"--recipes: unknown {unknown}; known: {', '.join(RECIPES)}")
    if any(not 0 < d <= cfg.episodes for d in cfg.demos):
        raise ValueError(f"--demos must be between 1 and --episodes ({cfg.episodes}), got {cfg.demos}")
    import sigma_data  # noqa: F401  (MUJOCO_GL before robosuite)

    train_root, held_root = collect_data(cfg)
    recipes = [run_one(cfg, name, RECIPES[name][1], train_root, held_root) for name in cfg.recipes]
    demos = []
    for n in cfg.demos:
        episodes = "[" + ",".join(str(i) for i in range(n)) + "]"
        result = run_one(cfg, f"small_{n}demos", [f"--dataset.episodes={episodes}"], train_root, held_root)
        demos.append(result | {"demos": n})
    return recipes, demos


def main(argv: list[str] | None = None) -> int:
    from pipelines.reporting import RESULTS_DIR, write_report

    cfg = draccus.parse(LearningBenchConfig, args=sys.argv[1:] if argv is None else argv)
    recipes, demos = run(cfg)
    table = markdown(cfg, recipes, demos)
    print(table)
    if cfg.publish:
        out = Path(cfg.results_dir or RESULTS_DIR)
        out.mkdir(parents=True, exist_ok=True)
        plot(recipes, demos, out / "learning_curves.png", cfg.episodes)
        notes = "![held-out error per step and success per demonstrations](benchmarks/results/learning_curves.png)"
        data = {
            "recipes": [
                {k: v for k, v in r.items() if k != "eval"} | {"numbers": _row_numbers(r)} for r in recipes
            ],
            "demos": [
                {k: v for k, v in r.items() if k != "eval"} | {"numbers": _row_numbers(r)} for r in demos
            ],
        }
        write_report(
            "learning",
            "Learning: the small recipe, per-head errors and closed-loop success",
            table,
            data,
            notes=notes,
            results_dir=out,
        )
    last = next((r for r in recipes if r["name"] == "small"), recipes[-1] if recipes else None)
    if last is not None:
        n = _row_numbers(last)
        print(
            f"bench_learning: {len(recipes)} recipes, {len(demos)} demo counts; {last['name']}: held-out "
            f"{n['held_cm']:.2f} cm, {n['successes']}/{n['episodes']} episodes -> {cfg.output_dir}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
