"""Suite benchmark: one multi-task Σ-agent (the ``suite`` preset) trained on 2 CPU cores in about an hour,
evaluated on every variation of Lift, Stack, PickPlace, NutAssembly and Door.

One command collects the keyframe demonstrations (``--episodes`` per variation, seeds from 0) and held-out
keyframes (``--heldout_episodes`` per variation, seeds from 50000), trains the policy with the stock
``lerobot-train`` (one run per ``--seeds`` entry: a second training seed says how much of a result is the draw),
scores every checkpoint on training and held-out keyframes (``sigma-diagnose``) and evaluates the last one closed
loop on held-out seeds (``sigma-eval``, from 100000, Wilson 95% intervals, failure reasons). Every stage resumes:
finished collections, checkpoints and evaluations are reused, and an interrupted ``lerobot-train`` continues from
its last checkpoint (``--resume=true``); a run trained with other options is refused, not reused.

The ``suite`` preset (``sigma_policy/configuration_sigma.py``) is the ``small`` network with each task in its own
scene box (``per_task_bounds``: Lift and Stack are rendered in their 36 cm box, PickPlace and NutAssembly in theirs,
so adding tasks does not coarsen the views of the others), the rotation-equivariant yaw scan (``yaw_scan_px=24``,
docs/method.md §7.1: NutAssembly 15/80 over two training seeds against 2/80 without, the suite 173/360 against
151/360) and a peak learning rate of 3e-3 (``small``'s 1e-2 underfit on four tasks with its 2000-step decay and
diverged with the decay stretched; docs/learning.md). The cosine decay is stretched over the whole run
(``--policy.scheduler_decay_steps`` = ``--steps``) unless ``--schedule_steps`` says otherwise; each schedule trains
into its own run directory (``runs/seed<S>_decay<D>_lr<LR>``, then ``_batch<B>`` for a batch other than 8 and
``_<preset>`` for a preset other than ``suite``).

    python -m benchmarks.bench_suite                                  # one training seed
    python -m benchmarks.bench_suite --seeds '[0,1]'                  # both seeds
    python -m benchmarks.bench_suite --seeds '[0,1]' --ensemble true  # and the two as one policy (method.md §14.4)
    python -m benchmarks.bench_suite --preset small --lr 0.01 --schedule_steps 2000 --policy_args '[]'
                                                                      # the small preset's recipe, for comparison
    python -m benchmarks.bench_suite --preset gpu --device cuda --workers 16 \
        --output_dir outputs/bench_suite_gpu --publish false          # on a GPU (docs/gpu.md: 7 min of training)
    python -m benchmarks.bench_suite --preset gpu --device cpu \
        --output_dir outputs/bench_suite_gpu --publish false          # score here a run trained on a GPU machine

``--steps`` and ``--batch_size`` default to the budget the preset was measured at (``PRESET_BUDGETS``: 7500 steps
at batch 8, ``gpu`` 3000 at batch 64). On a CPU without native bf16 the network trains in float32, where a step
costs about twice as much, so there the CPU presets default to 30 demonstrations per variation and 4500 steps
(``FLOAT32_BUDGET``), which keep one training seed's run, collection to table, within 2 hours on 2 cores
(docs/learning.md "The suite in float32"), with each task's instructions contrasted (``FLOAT32_ARGS``, docs/learning.md
"The suite in float32, with the instructions contrasted"); the run's first line says which budget it chose.

The defaults are the best five-task recipe for the Σ-agent measured on 2 CPU cores (docs/learning.md "50
demonstrations per variation at 7500 steps, a third draw" and, for the fourth draw, "Contrastive vs BC-only at the
benchmark's defaults, in pairs": 212/400, 215/400, 209/400 and 205/400): 50 demonstrations per variation and 7500
steps in bf16 autocast (``--policy.use_cpu_bf16_autocast``, a no-op on CPUs without native bf16), which trained in
55-56 minutes per seed on a 2-core Intel Xeon with AMX-BF16 and 63-83 on an AMD EPYC; collection took 11 and 23
minutes, evaluation 5 and 7 (RESULTS.md). The same recipe without the contrastive terms (``--policy_args
'[--policy.use_cpu_bf16_autocast=true,--policy.use_contrastive=false]'``) scored 3 points higher in pairs (the second
section). Until 2026-12-04 the defaults were four tasks (no Door), 30 demonstrations and 6000 steps: ``--tasks
'[lift,stack,pick_place,nut_assembly]' --episodes 30 --steps 6000``.
"""

from __future__ import annotations

import json
import os
import re
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import draccus

from sigma_data.cameras import DEFAULT_CAMERAS

if TYPE_CHECKING:
    from pipelines.training import TrainRun

os.environ.setdefault("HF_HUB_OFFLINE", "1")

# What the suite trains with beyond its preset: bf16 autocast on CPUs that have it (docs/learning.md "Training speed").
SUITE_ARGS = ["--policy.use_cpu_bf16_autocast=true"]

# The training budget each preset was measured at (`--steps`, `--batch_size` when not given): the CPU presets 7500
# steps at batch 8 (docs/learning.md), `gpu` 3000 at batch 64, the length of its own decay (docs/gpu.md).
PRESET_BUDGETS: dict[str, tuple[int, int]] = {"gpu": (3000, 64)}
DEFAULT_BUDGET = (7500, 8)
DEFAULT_EPISODES = 50
# On a CPU without native bf16 the step runs in float32 and costs about twice as much, so the CPU presets default to
# fewer demonstrations per variation and steps: the budget that keeps one training seed's whole run (collection to
# table) within 2 hours on 2 cores (docs/learning.md "The suite in float32").
FLOAT32_BUDGET = (30, 4500)  # (episodes, steps)
# ... and contrast each task's instructions (docs/method.md §5.3), as the float32 demo does (`small`): 4500 float32
# steps read Stack's order only in part without it (docs/learning.md "The suite in float32, with the instructions
# contrasted"). Added to `--policy_args` unless they name the option.
FLOAT32_ARGS = ["--policy.lang_task_contrast=true"]
STAGES = ("collect", "train", "evaluate")


@dataclass
class SuiteBenchConfig:
    """Options of the suite benchmark."""

    output_dir: Path = Path("outputs/bench_suite")
    tasks: list[str] = field(default_factory=lambda: ["lift", "stack", "pick_place", "nut_assembly", "door"])
    # Training demonstrations per variation (seeds from 0) and held-out ones (seeds from 50000); None: 50, or 30 where
    # the CPU trains in float32 (FLOAT32_BUDGET).
    episodes: int | None = None
    heldout_episodes: int = 5
    # Radius (m) of the random horizontal offset of the experts' approach waypoints in the training demonstrations
    # (`sigma-data collect --pregrasp_jitter_m`, DART-style data; docs/learning.md); 0: the experts' own.
    pregrasp_jitter_m: float = 0.0
    cameras: list[str] = field(default_factory=lambda: list(DEFAULT_CAMERAS))
    image_size: int = 64
    # Training budget; None: the preset's (PRESET_BUDGETS: 7500 × batch 8, `gpu` 3000 × 64; the CPU presets 4500
    # steps where the CPU trains in float32, FLOAT32_BUDGET). Checkpoints saved (and diagnosed) this many times per run.
    steps: int | None = None
    batch_size: int | None = None
    checkpoints: int = 4
    # One training run per seed.
    seeds: list[int] = field(default_factory=lambda: [0])
    # Steps of the cosine learning-rate decay (--policy.scheduler_decay_steps); None: the whole run (`steps`).
    schedule_steps: int | None = None
    # The policy preset (configuration_sigma.PRESETS): `suite` is `small` with per-task boxes, the yaw scan and lr 3e-3.
    preset: str = "suite"
    # Peak learning rate (--policy.optimizer_lr); None: the preset's (suite 3e-3; small's 1e-2 diverged here).
    lr: float | None = None
    # lerobot-train arguments beyond the preset.
    policy_args: list[str] = field(default_factory=lambda: list(SUITE_ARGS))
    # Closed-loop episodes per variation (seeds from 100000) and keyframes per episode.
    eval_episodes: int = 20
    max_keyframes: int = 16
    # Collection and evaluation processes; the device that trains, diagnoses and evaluates (docs/gpu.md).
    workers: int = 2
    device: str = "cpu"
    # Write benchmarks/results/suite.{md,json} (RESULTS.md includes them).
    publish: bool = True
    results_dir: Path | None = None
    # Also score every seed's last checkpoint together as one policy (`sigma-eval --ensemble`, docs/method.md
    # §14.4), on the same episodes; needs two seeds or more.
    ensemble: bool = False
    # The last stage to run: `collect` (the datasets), `train` (and the runs; a machine without robosuite trains
    # on data collected elsewhere, docs/gpu.md) or `evaluate` (everything: closed loop, diagnosis, the table).
    stop_after: str = "evaluate"

    def __post_init__(self) -> None:
        if self.stop_after not in STAGES:
            raise ValueError(f"--stop_after must be one of {', '.join(STAGES)}, got {self.stop_after!r}")
        if self.ensemble and len(set(self.seeds)) < 2:
            raise ValueError(f"--ensemble needs two training seeds or more, got --seeds {self.seeds}")
        steps, batch_size = PRESET_BUDGETS.get(self.preset, DEFAULT_BUDGET)
        episodes = DEFAULT_EPISODES
        self._float32_budget = self._defaults_to_float32_budget()
        if self._float32_budget:
            episodes, steps = FLOAT32_BUDGET
            named = {a.split("=")[0] for a in self.policy_args}
            # a new list: the caller's (or a default's) stays as it was given
            self.policy_args = [*self.policy_args, *(a for a in FLOAT32_ARGS if a.split("=")[0] not in named)]
        self.episodes = self.episodes or episodes
        self.steps = self.steps or steps
        self.batch_size = self.batch_size or batch_size

    def _defaults_to_float32_budget(self) -> bool:
        """Whether the defaults are ``FLOAT32_BUDGET``: a CPU preset trained on a CPU without native bf16 (bf16
        autocast is then off), with neither ``--episodes`` nor ``--steps`` given: either one given keeps the other at
        the bf16 recipe's value, so a command that names the steps of a run collected elsewhere reads its data. Only
        meaningful in ``__post_init__``, before the defaults fill those fields (``_float32_budget`` keeps the answer)."""
        given = self.episodes is not None or self.steps is not None
        if given or self.device != "cpu" or self.preset in PRESET_BUDGETS:
            return False
        from sigma_policy.modeling_sigma import cpu_has_native_bf16

        return not cpu_has_native_bf16()

    def budget_line(self) -> str:
        """The demonstrations and steps this run uses, and why, in words (printed at the start)."""
        line = f"{self.episodes} demonstrations per variation, {self.steps} steps × batch {self.batch_size}"
        if self._float32_budget:
            line += (
                f" (this CPU has no native bf16, so the network trains in float32: the defaults are then "
                f"--episodes {FLOAT32_BUDGET[0]} --steps {FLOAT32_BUDGET[1]} and {' '.join(FLOAT32_ARGS)}, which keep one "
                f"seed within 2 hours on 2 cores; --episodes {DEFAULT_EPISODES} --steps {DEFAULT_BUDGET[0]} is the "
                f"recipe measured in bf16)"
            )
        return line

    @property
    def decay_steps(self) -> int:
        """Steps of the learning-rate decay: ``schedule_steps``, else the whole run."""
        return self.schedule_steps or self.steps

    @property
    def peak_lr(self) -> float:
        """The peak learning rate: ``lr``, else the preset's."""
        from sigma_policy.configuration_sigma import PRESETS

        return self.lr or PRESETS[self.preset]["optimizer_lr"]

    @property
    def loader_workers(self) -> int:
        """DataLoader workers of the training run: none on the CPU (the read shares the 2 cores with the update),
        4 on a GPU machine, where reading in the training process took as long as the update (docs/gpu.md)."""
        return 0 if self.device == "cpu" else 4

    def run_dir(self, seed: int) -> Path:
        """Where training seed ``seed`` of this schedule trains, is diagnosed and is evaluated (a batch other than
        the suite's 8, a preset other than ``suite`` and ``policy_args`` other than ``SUITE_ARGS`` are named:
        ``..._batch64_gpu_proprio_film-true``), so runs that share a collection never share a directory."""
        batch = "" if self.batch_size == 8 else f"_batch{self.batch_size}"
        preset = "" if self.preset == "suite" else f"_{self.preset}"
        name = f"seed{seed}_decay{self.decay_steps}_lr{self.peak_lr:g}{batch}{preset}{self._args_tag()}"
        return self.output_dir / "runs" / name

    def ensemble_dir(self) -> Path:
        """Where the seeds' runs are scored as one ensemble: ``runs/ensemble_seeds0-1_<the runs' name after the
        seed>``."""
        schedule = self.run_dir(self.seeds[0]).name.split("_", 1)[1]
        return self.output_dir / "runs" / f"ensemble_seeds{'-'.join(map(str, self.seeds))}_{schedule}"

    def _args_tag(self) -> str:
        """``policy_args`` beyond ``SUITE_ARGS`` as ``_name-value``, and ``SUITE_ARGS`` left out as
        ``_without-name``."""
        added = [a for a in self.policy_args if a not in SUITE_ARGS]
        dropped = [a for a in SUITE_ARGS if a not in self.policy_args]
        words = [a.removeprefix("--policy.") for a in added] + [
            "without-" + a.removeprefix("--policy.").split("=")[0] for a in dropped
        ]
        return "".join("_" + re.sub(r"[^A-Za-z0-9._,-]+", "", w.replace("=", "-", 1)) for w in words)

    def train_run(self, seed: int, train_root: Path) -> TrainRun:
        """The ``lerobot-train`` run of training seed ``seed`` on the dataset at ``train_root``."""
        from pipelines.training import TrainRun
        from sigma_data.suite import scene_bounds

        return TrainRun(
            dataset_root=train_root,
            output_dir=self.run_dir(seed) / "train",
            steps=self.steps,
            batch_size=self.batch_size,
            scene_bounds=scene_bounds(self.tasks),
            preset=self.preset,
            seed=seed,
            device=self.device,
            num_workers=self.loader_workers,
            job_name=f"suite_seed{seed}",
            save_freq=max(1, self.steps // self.checkpoints),
            extra_args=[*self.policy_args, *self.schedule_args],
        )

    @property
    def preset_args(self) -> list[str]:
        """The policy's options as the table names them: the preset, then ``policy_args``."""
        return [f"--policy.preset={self.preset}", *self.policy_args]

    @property
    def schedule_args(self) -> list[str]:
        """``lerobot-train`` arguments of the learning-rate schedule."""
        lr = [f"--policy.optimizer_lr={self.lr:g}"] if self.lr else []
        return [f"--policy.scheduler_decay_steps={self.decay_steps}", *lr]


def collect_data(cfg: SuiteBenchConfig) -> tuple[Path, Path]:
    from benchmarks.training_runs import collect_train_and_heldout

    return collect_train_and_heldout(
        cfg.output_dir,
        cfg.tasks,
        cfg.episodes,
        cfg.heldout_episodes,
        cfg.cameras,
        cfg.image_size,
        cfg.workers,
        "suite",
        pregrasp_jitter_m=cfg.pregrasp_jitter_m,
    )


def run_one(cfg: SuiteBenchConfig, seed: int, train_root: Path, held_root: Path) -> dict:
    """Train with ``seed`` (unless done; resumed if interrupted), evaluate (unless done), diagnose."""
    from benchmarks.training_runs import train_evaluate_diagnose

    run_dir = cfg.run_dir(seed)
    run = cfg.train_run(seed, train_root)
    done = train_evaluate_diagnose(
        run,
        run_dir,
        held_root,
        cfg.tasks,
        f"[suite] seed {seed}",
        episodes=cfg.eval_episodes,
        max_keyframes=cfg.max_keyframes,
        workers=cfg.workers,
    )
    trained_on = json.loads((run.checkpoint / "train_config.json").read_text())["policy"]["device"]
    return {"seed": seed, "trained_on": trained_on} | done


def evaluate_ensemble(cfg: SuiteBenchConfig, train_root: Path) -> dict:
    """Every seed's last checkpoint scored as one policy, on the episodes each seed was scored on (unless scored
    already with these weights: ``members.json`` records them)."""
    from pipelines.evaluate import EvalConfig, run_eval
    from sigma_data.files import sha256, write_json_atomic

    checkpoints = [cfg.train_run(seed, train_root).checkpoint for seed in cfg.seeds]
    out = cfg.ensemble_dir() / "eval"
    members = {str(c): sha256(c / "model.safetensors") for c in checkpoints}
    record = cfg.ensemble_dir() / "members.json"
    done = out / "results.json"
    if done.exists() and record.exists() and json.loads(record.read_text()) == members:
        return json.loads(done.read_text())
    t0 = time.perf_counter()
    summary = run_eval(
        EvalConfig(
            checkpoint=checkpoints[0],
            ensemble=checkpoints[1:],
            tasks=cfg.tasks,
            train_dataset=train_root,
            output_dir=out,
            device=cfg.device,
            episodes=cfg.eval_episodes,
            max_keyframes=cfg.max_keyframes,
            workers=cfg.workers,
        )
    )
    write_json_atomic(record, members, indent=2)
    print(f"[suite] ensemble of seeds {cfg.seeds}: evaluated in {time.perf_counter() - t0:.0f} s", flush=True)
    return summary


def stop_early(cfg: SuiteBenchConfig, train_root: Path, held_root: Path) -> int:
    """``--stop_after collect`` or ``train``: the datasets, and with ``train`` every seed's run, then a summary."""
    from benchmarks.training_runs import train_unless_done

    done = [f"data {train_root} and {held_root}"]
    if cfg.stop_after == "train":
        for seed in cfg.seeds:
            run = cfg.train_run(seed, train_root)
            seconds = train_unless_done(run, cfg.run_dir(seed), f"[suite] seed {seed}")
            done.append(f"seed {seed}: {run.checkpoint} ({seconds / 60:.1f} min of training)")
    print(f"bench_suite: stopped after {cfg.stop_after}; " + "; ".join(done))
    return 0


def markdown(cfg: SuiteBenchConfig, results: list[dict], ensemble: dict | None = None) -> str:
    """The tables: success per variation (a column per seed, and one for ``ensemble``, the seeds' checkpoints
    scored as one policy), a row per seed of errors and pooled success, and the held-out error per task."""
    from benchmarks.bench_demos import cell, eval_numbers, numbers

    rows = [numbers(r) for r in results]
    together = eval_numbers(ensemble) if ensemble else None
    names = list(rows[0]["variations"]) if rows else []
    head = (
        f"Tasks {', '.join(cfg.tasks)}: {cfg.episodes} demonstrations per variation (seeds from 0"
        + (
            f", approach waypoints moved up to {100 * cfg.pregrasp_jitter_m:g} cm"
            if cfg.pregrasp_jitter_m
            else ""
        )
        + "), held-out "
        f"keyframes from {cfg.heldout_episodes} more per variation (seeds from 50000); 4 cameras at "
        f"{cfg.image_size}²; one multi-task policy, {' '.join(f'`{a}`' for a in cfg.preset_args)}, "
        f"{cfg.steps} `lerobot-train` steps × batch {cfg.batch_size}, peak learning rate {cfg.peak_lr:g} and its "
        f"cosine decay over {cfg.decay_steps} steps, {devices_line(cfg, results)}; closed loop: `sigma-eval`, "
        f"{cfg.eval_episodes} episodes per variation (seeds from 100000), ≤ {cfg.max_keyframes} keyframes. "
        "Errors are medians over every keyframe with a goal at the last checkpoint; yaw is the mean absolute error "
        "of the yaw bin. One column (first table) and one row (second) per training seed.\n\n"
    )
    columns = [f"seed {r['seed']}" for r in results] + (["the seeds as one ensemble"] if together else [])
    lines = [f"| variation | {' | '.join(columns)} |", "|---" * (1 + len(columns)) + "|"]
    scored = rows + ([together] if together else [])
    for k in names:
        lines.append(f"| {k} | " + " | ".join(cell(*n["variations"][k]) for n in scored) + " |")
    summary = [
        "",
        "| seed | train cm | held-out cm | held-out ≤ 1 cm | held-out yaw ° | gripper | all (95% CI) | failures "
        "| train min | eval min |",
        "|---" * 10 + "|",
    ]
    for r, n in zip(results, rows, strict=True):
        fails = ", ".join(f"{k} {c}" for k, c in sorted(n["failures"].items(), key=lambda kv: -kv[1])) or "-"
        summary.append(
            f"| {r['seed']} | {n['train_cm']:.2f} | {n['held_cm']:.2f} | {100 * n['held_1cm']:.0f}% "
            f"| {n['held_yaw']:.1f} | {100 * n['held_grip']:.0f}% "
            f"| **{cell(n['successes'], n['episodes'], n['ci95'])}** | {fails} "
            f"| {r['train_seconds'] / 60:.0f} | {r['eval'].get('seconds', float('nan')) / 60:.0f} |"
        )
    if together:
        fails = ", ".join(f"{k} {c}" for k, c in sorted(together["failures"].items(), key=lambda kv: -kv[1]))
        summary.append(
            f"| ensemble of {', '.join(str(r['seed']) for r in results)} | - | - | - | - | - "
            f"| **{cell(together['successes'], together['episodes'], together['ci95'])}** | {fails or '-'} | - "
            f"| {ensemble.get('seconds', float('nan')) / 60:.0f} |"
        )
    return head + "\n".join(lines + summary + per_task_lines(cfg, results)) + "\n"


def devices_line(cfg: SuiteBenchConfig, results: list[dict]) -> str:
    """Where the runs trained and were scored: ``--device``, or "trained on CUDA, scored on CPU" for a run trained
    on a GPU machine and reused here with ``--device cpu``."""
    here = cfg.device.upper()
    trained = "/".join(sorted({r.get("trained_on", cfg.device).upper() for r in results})) or here
    return here if trained == here else f"trained on {trained}, scored on {here}"


def per_task_lines(cfg: SuiteBenchConfig, results: list[dict]) -> list[str]:
    """A table of the held-out translation error per task at the last checkpoint (median, share within 1 cm), one
    column per training seed; empty when the diagnostics have no per-task split."""
    per = [r["diagnostics"]["checkpoints"][-1]["heldout"].get("per_task", {}) for r in results]
    tasks = [t for t in cfg.tasks if any(t in p for p in per)]
    if not tasks:
        return []
    seeds = " | ".join(f"seed {r['seed']}" for r in results)
    lines = [
        "",
        f"| task: held-out keyframes, median cm (≤ 1 cm) | {seeds} |",
        "|---" * (1 + len(results)) + "|",
    ]
    for t in tasks:
        cells = [
            f"{p[t]['all']['trans_cm_median']:.2f} ({100 * p[t]['all']['within_1cm']:.0f}%)"
            if t in p
            else "-"
            for p in per
        ]
        lines.append(f"| {t} | " + " | ".join(cells) + " |")
    return lines


def main(argv: list[str] | None = None) -> int:
    from pipelines.reporting import RESULTS_DIR, write_report

    cfg = draccus.parse(SuiteBenchConfig, args=sys.argv[1:] if argv is None else argv)
    if not cfg.seeds:
        raise ValueError("--seeds must name at least one training seed")
    import sigma_data  # noqa: F401  (MUJOCO_GL before robosuite)

    print(f"bench_suite: {cfg.budget_line()}", flush=True)
    train_root, held_root = collect_data(cfg)
    if cfg.stop_after != "evaluate":
        return stop_early(cfg, train_root, held_root)
    results = [run_one(cfg, seed, train_root, held_root) for seed in cfg.seeds]
    ensemble = evaluate_ensemble(cfg, train_root) if cfg.ensemble else None
    table = markdown(cfg, results, ensemble)
    print(table)
    from benchmarks.bench_demos import eval_numbers, numbers

    if cfg.publish:
        data = [{k: v for k, v in r.items() if k != "eval"} | {"numbers": numbers(r)} for r in results]
        if ensemble:
            data.append({"ensemble_of_seeds": cfg.seeds, "numbers": eval_numbers(ensemble)})
        write_report(
            "suite",
            "The suite on 2 CPU cores: one multi-task policy, every variation",
            table,
            data,
            results_dir=Path(cfg.results_dir or RESULTS_DIR),
        )
    pooled = [numbers(r) for r in results]
    together = eval_numbers(ensemble) if ensemble else None
    print(
        f"bench_suite: {len(results)} run(s); "
        + "; ".join(
            f"seed {r['seed']}: {n['successes']}/{n['episodes']}"
            for r, n in zip(results, pooled, strict=True)
        )
        + (f"; the seeds as one ensemble: {together['successes']}/{together['episodes']}" if ensemble else "")
        + f" -> {cfg.output_dir}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
