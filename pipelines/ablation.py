"""``sigma-ablate``: does the contrastive loss help? The paper's ablation, on robosuite, with honest intervals.

The arms (``--arms``, two by default) share everything but the loss: the same keyframe dataset (collected once by
the scripted experts), the same training seed, steps, batch size and scene box, and the same evaluation seeds:

* ``baseline`` — the RVT-style policy (``--policy.use_contrastive=false``: BC only);
* ``contrastive`` — the Σ-agent policy (``--policy.use_contrastive=true``: BC + state↔language and
  (state, language)↔goal InfoNCE, λ = ``bc_lambda``), its features as the preset has them;
* ``centred`` / ``uncentred`` — the Σ-agent policy with ``--policy.contrastive_center`` forced on / off (the goal
  term's features minus their batch mean before normalising, sigma_policy/contrastive.py).

The default task subset is the one where the instruction decides success (Stack in both orders, PickPlace
with four objects on the table), so a policy that ignores language cannot exceed chance. The arms train with
the stock ``lerobot-train`` (in parallel, one process per arm, the cores split between them) and are evaluated
closed-loop by ``sigma-eval``. The report (success per variation with Wilson 95% intervals, the last logged
losses, training time) goes to ``<output_dir>/ablation.md`` and, with ``--publish true``, to
``benchmarks/results/ablation.md`` for ``RESULTS.md``.

Every stage resumes: collection skips finished shards, an arm with a finished checkpoint is not retrained,
an arm with evaluation results is not re-evaluated (``--fresh true`` starts over).

    sigma-ablate                                   # defaults: 10 demos/variation, 1500 steps, 10 eval episodes
    sigma-ablate --steps 200 --eval_episodes 2     # a quick look
    sigma-ablate --arms '[baseline,uncentred,centred]'
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import draccus

from sigma_data.cameras import DEFAULT_CAMERAS

os.environ.setdefault("HF_HUB_OFFLINE", "1")

# arm -> (the report's column title, the lerobot-train arguments that make it)
ARMS: dict[str, tuple[str, list[str]]] = {
    "baseline": ("baseline (BC only)", ["--policy.use_contrastive=false"]),
    "contrastive": ("contrastive (Σ-agent)", ["--policy.use_contrastive=true"]),
    "uncentred": (
        "Σ-agent, uncentred features",
        ["--policy.use_contrastive=true", "--policy.contrastive_center=false"],
    ),
    "centred": (
        "Σ-agent, centred features",
        ["--policy.use_contrastive=true", "--policy.contrastive_center=true"],
    ),
}


@dataclass
class AblationConfig:
    """Options of ``sigma-ablate``."""

    output_dir: Path = Path("outputs/ablation")
    # Tasks (all their variations); the default is where language decides success.
    tasks: list[str] = field(default_factory=lambda: ["stack", "pick_place"])
    # Expert seeds collected per variation (failed expert episodes are dropped), and camera set-up.
    episodes: int = 10
    cameras: list[str] = field(default_factory=lambda: list(DEFAULT_CAMERAS))
    image_size: int = 64
    # The arms, each a name in ARMS (baseline, contrastive, uncentred, centred); the first is the reference.
    arms: list[str] = field(default_factory=lambda: ["baseline", "contrastive"])
    # The training budget, identical for every arm.
    preset: str = "small"
    steps: int = 1500
    batch_size: int = 8
    seed: int = 0
    device: str = "cpu"
    # Evaluation episodes per variation (seeds from 100000, disjoint from the collection seeds).
    eval_episodes: int = 10
    max_keyframes: int = 10
    # Worker processes for collection and evaluation; the arms train side by side with the cores split.
    workers: int = 2
    # Discard previous checkpoints and evaluations (the collected data is always reused when it is complete).
    fresh: bool = False
    # Also write benchmarks/results/ablation.md (+ .json), the fragment RESULTS.md includes.
    publish: bool = False


def collect_stage(cfg: AblationConfig) -> Path:
    from pipelines.collecting import collect_demonstrations

    return collect_demonstrations(
        cfg.output_dir,
        cfg.tasks,
        cfg.episodes,
        cfg.cameras,
        cfg.image_size,
        cfg.workers,
        "local/sigma_ablation",
        dense=False,
    )["keyframe"]


def train_stage(cfg: AblationConfig, dataset: Path) -> dict[str, dict]:
    """Train the arms side by side (resuming finished ones); return per-arm checkpoint, seconds, metrics."""
    from pipelines.training import TrainRun, last_logged_metrics, start, wait
    from sigma_data.suite import scene_bounds

    box = scene_bounds(cfg.tasks)
    runs = {
        arm: TrainRun(
            dataset_root=dataset,
            output_dir=cfg.output_dir / "train" / arm,
            steps=cfg.steps,
            batch_size=cfg.batch_size,
            scene_bounds=box,
            preset=cfg.preset,
            device=cfg.device,
            seed=cfg.seed,
            job_name=f"ablation_{arm}",
            extra_args=args,
        )
        for arm, (_, args) in ((name, ARMS[name]) for name in cfg.arms)
    }
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    threads = max(1, cores // len(runs))
    results: dict[str, dict] = {}
    procs = {}
    for arm, run in runs.items():
        done = cfg.output_dir / "train" / f"{arm}.json"
        previous = run.reuse_or_clear(done, arm)
        if previous is not None:
            results[arm] = previous
            continue
        log = cfg.output_dir / "train" / f"{arm}.log"
        print(
            f"{arm}: lerobot-train {cfg.steps} steps x batch {cfg.batch_size}, {threads} thread(s); log {log}"
        )
        procs[arm] = (start(run, log, threads=threads), log, time.perf_counter())
    for arm, (proc, log, t0) in procs.items():
        ckpt = wait(runs[arm], proc, log)
        results[arm] = {
            "checkpoint": str(ckpt),
            "train_seconds": time.perf_counter() - t0,
            "last_metrics": last_logged_metrics(log),
            "threads": threads,
        }
        (cfg.output_dir / "train" / f"{arm}.json").write_text(json.dumps(results[arm], indent=2))
        print(f"{arm}: trained in {results[arm]['train_seconds']:.0f} s", flush=True)
    return results


def eval_stage(cfg: AblationConfig, dataset: Path, trained: dict[str, dict]) -> dict[str, dict]:
    from pipelines.evaluate import EvalConfig, markdown_table, run_eval

    summaries = {}
    for arm, info in trained.items():
        out = cfg.output_dir / "eval" / arm
        cached = out / "results.json"
        if cached.exists():
            summaries[arm] = json.loads(cached.read_text())
            print(f"{arm}: reusing the evaluation in {out}", flush=True)
            continue
        print(f"{arm}: sigma-eval, {cfg.eval_episodes} episodes per variation", flush=True)
        summaries[arm] = run_eval(
            EvalConfig(
                checkpoint=Path(info["checkpoint"]),
                tasks=cfg.tasks,
                episodes=cfg.eval_episodes,
                train_dataset=dataset,
                max_keyframes=cfg.max_keyframes,
                workers=cfg.workers,
                device=cfg.device,
                output_dir=out,
            )
        )
        print(markdown_table(summaries[arm]), flush=True)
    return summaries


def _pct(row: dict) -> str:
    lo, hi = row["ci95"]
    return f"{row['successes']}/{row['episodes']} ({100 * row['success_rate']:.0f}%, {100 * lo:.0f}–{100 * hi:.0f}%)"


def report(cfg: AblationConfig, dataset: Path, trained: dict[str, dict], evals: dict[str, dict]) -> str:
    """The Markdown comparison: per variation, every arm with Wilson 95% intervals, then training facts."""
    from sigma_data.contract import read_sidecar

    rows = {arm: {(r["task"], r["variation"]): r for r in s["variations"]} for arm, s in evals.items()}
    keys = sorted(set().union(*(r.keys() for r in rows.values())))
    lines = [
        "| task | variation | " + " | ".join(ARMS[arm][0] for arm in cfg.arms) + " |",
        "|---|---|" + "---|" * len(cfg.arms),
    ]
    for key in keys:
        cells = [_pct(rows[arm][key]) if key in rows[arm] else "-" for arm in cfg.arms]
        lines.append(f"| {key[0]} | {key[1]} | " + " | ".join(cells) + " |")
    means = [f"**{100 * evals[arm]['mean_success']:.1f}%**" for arm in cfg.arms]
    lines.append("| **mean** | | " + " | ".join(means) + " |")

    n_eps = (read_sidecar(dataset) or {}).get("num_episodes", "?")
    facts = [
        "",
        "| arm | training wall time | last logged losses |",
        "|---|---|---|",
    ]
    for arm in cfg.arms:
        m = trained[arm].get("last_metrics", {})
        parts = [
            f"{k} {m[k]:.3f}"
            for k in (
                "bc_loss",
                "trans_loss",
                "rot_loss",
                "contrastive_sl_loss",
                "contrastive_goal_loss",
                "logit_scale",
            )
            if k in m
        ]
        lines_t = (
            f"{trained[arm]['train_seconds'] / 60:.1f} min ({trained[arm].get('threads', '?')} thread(s))"
        )
        facts.append(f"| {arm} | {lines_t} | {', '.join(parts) or '-'} |")
    seeds = next(iter(evals.values()))["variations"][0]["seeds"]
    flags = "; ".join(f"{arm} `{' '.join(ARMS[arm][1])}`" for arm in cfg.arms)
    setup = (
        f"Data: {n_eps} expert episodes ({cfg.episodes} seeds per variation from 0, failed expert runs dropped), "
        f"{len(cfg.cameras)} cameras at {cfg.image_size}² ({', '.join(cfg.cameras)}), keyframe dataset "
        f"`{dataset}`. Training: `{cfg.preset}` preset, {cfg.steps} steps × batch {cfg.batch_size}, seed "
        f"{cfg.seed}, {cfg.device}, scene box of the tasks; the arms differ only in their flags: {flags}. "
        f"Evaluation: {cfg.eval_episodes} episodes per variation, seeds {seeds[0]}–{seeds[-1]} (disjoint from "
        f"the training seeds), at most {cfg.max_keyframes} keyframes per episode. Chance of the goal InfoNCE "
        f"term: log(batch) = {math.log(cfg.batch_size):.3f}."
    )
    return "\n".join([setup, "", *lines, *facts])


def run_ablation(cfg: AblationConfig) -> str:
    import sigma_data  # noqa: F401  (MUJOCO_GL before robosuite)
    from pipelines.reporting import start_run_dir, write_run_outputs

    unknown = [arm for arm in cfg.arms if arm not in ARMS]
    if unknown or len(set(cfg.arms)) != len(cfg.arms) or not cfg.arms:
        raise ValueError(f"--arms must name distinct arms of {sorted(ARMS)}, got {cfg.arms}")
    cfg.output_dir = start_run_dir(cfg.output_dir, cfg.fresh)
    t0 = time.perf_counter()
    print("=== 1/3 collect (scripted experts -> keyframe dataset) ===", flush=True)
    dataset = collect_stage(cfg)
    print(f"\n=== 2/3 train {len(cfg.arms)} arms (lerobot-train) ===", flush=True)
    trained = train_stage(cfg, dataset)
    print(f"\n=== 3/3 evaluate {len(cfg.arms)} arms (sigma-eval) ===", flush=True)
    evals = eval_stage(cfg, dataset, trained)
    text = report(cfg, dataset, trained, evals)
    write_run_outputs(
        cfg.output_dir,
        "ablation",
        "Contrastive-loss ablation (same data, seeds and budget)",
        text,
        cfg,
        {"trained": trained, "eval": {arm: s["variations"] for arm, s in evals.items()}},
        cfg.publish,
    )
    print("\n" + text)
    scores = " vs ".join(f"{arm} {100 * evals[arm]['mean_success']:.1f}%" for arm in cfg.arms)
    print(
        f"\nsigma-ablate: {scores} mean success over {len(evals[cfg.arms[0]]['variations'])} variations in "
        f"{(time.perf_counter() - t0) / 60:.1f} min -> {cfg.output_dir}/ablation.md"
    )
    return text


def main(argv: list[str] | None = None) -> int:
    cfg = draccus.parse(AblationConfig, args=sys.argv[1:] if argv is None else argv)
    run_ablation(cfg)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
