"""``make demo``: the whole sigma job, offline, on embedded defaults, on a 2-core CPU.

Stages (each shows progress; the run ends with a short table and the paths it wrote):

1. **collect** a multi-task keyframe dataset with the scripted experts (``episodes`` per variation: keyframe-only
   collection renders only the decision points, so 30 per variation take 2-3 minutes on 2 cores), and a dense episode
   per variation (``dense_episodes``: every control step, for the episode viewer and stock LeRobot policies);
2. **validate** both against the data contract (``sigma-data validate``);
3. **train** the ``small`` Σ-agent policy with the stock ``lerobot-train --policy.type=sigma``: 1500 steps in bf16
   autocast where the CPU has native bf16 (about 13 minutes on 2 cores of an AVX512-BF16 machine), 700 in float32
   elsewhere (about 13 minutes on 2 cores of an AMD EPYC without AVX-512, where 1500 take 24), so that the demo
   keeps to 20 minutes; fewer steps read Stack's order less well (README.md gives the whole demo's times and scores);
4. **evaluate** it closed-loop in robosuite (``sigma-eval``), seeds disjoint from the training seeds;
5. **visualise**: a Rerun recording of a dataset episode and of the policy's virtual views and heatmaps on a
   failed and a successful rollout (``sigma-viz``; open them with ``rerun <file>.rrd``).

``--quick`` (about 2 minutes; used by the tests) shrinks every stage. Outputs go under ``--output_dir``; an
existing run directory is replaced, so a demo always shows a fresh, complete run.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import draccus

from sigma_data.cameras import DEFAULT_CAMERAS

os.environ.setdefault("HF_HUB_OFFLINE", "1")


# The demo's training steps where the network trains in bf16 autocast (a CPU with native bf16: AVX512-BF16 or AMX),
# and in float32 elsewhere (DemoConfig.steps).
BF16_STEPS = 1500
FLOAT32_STEPS = 700


@dataclass
class DemoConfig:
    """Options of the demo (``make demo ARGS='--quick true'``)."""

    output_dir: Path = Path("outputs/demo")
    # A ~2 minute smoke version of every stage (what the tests run).
    quick: bool = False
    # Tasks collected and evaluated ("lift", "stack", ...; see sigma_data.suite).
    tasks: list[str] = field(default_factory=lambda: ["lift", "stack"])
    # Seeds collected per variation for the keyframe (training) dataset, and for the dense dataset (the episode viewer's
    # and stock LeRobot policies' data: every control step rendered, about 15 s of collection per episode).
    episodes: int = 30
    dense_episodes: int = 1
    # Evaluation episodes per variation (held-out seeds), and keyframes a rollout may take.
    eval_episodes: int = 10
    max_keyframes: int = 12
    # Training steps of the small policy (None = ``BF16_STEPS`` where the network trains in bf16, that is with
    # ``bf16`` on a CPU with native bf16, else ``FLOAT32_STEPS``, which keep the demo to 20 minutes on 2 cores of a
    # CPU without it; docs/learning.md "The demo in float32: fewer steps") and batch size.
    steps: int | None = None
    batch_size: int = 8
    # Training seed (the data and evaluation seeds stay fixed): a second seed says how much of a result is the draw.
    seed: int = 0
    # Train and evaluate the network in bf16 autocast where the CPU has native bf16 (--policy.use_cpu_bf16_autocast).
    bf16: bool = True
    cameras: list[str] = field(default_factory=lambda: list(DEFAULT_CAMERAS))
    image_size: int = 64
    workers: int = 2

    def __post_init__(self) -> None:
        if self.quick:
            self.tasks = ["lift"]
            self.episodes, self.dense_episodes, self.eval_episodes = 2, 1, 1
            self.steps, self.batch_size = 4, 2
            self.cameras = ["agentview", "robot0_eye_in_hand"]
            self.image_size = 32

    def resolve_steps(self) -> str:
        """Fill ``steps`` when it is None, from the precision the network will train in; returns why, in words."""
        if self.steps is not None:
            return f"{self.steps} training steps ({'--quick' if self.quick else '--steps'})"
        from sigma_policy.modeling_sigma import cpu_has_native_bf16

        if self.bf16 and cpu_has_native_bf16():
            self.steps = BF16_STEPS
            return f"{self.steps} training steps (bf16 autocast: this CPU has native bf16)"
        self.steps = FLOAT32_STEPS
        why = "this CPU has no native bf16" if self.bf16 else "--bf16 false"
        return (
            f"{self.steps} training steps in float32 ({why}; --steps {BF16_STEPS} trains the bf16 recipe's steps, "
            "about 25 minutes of float32 training on 2 cores)"
        )


@dataclass
class StageTimes:
    seconds: dict[str, float] = field(default_factory=dict)

    def run(self, name: str, fn, *args, **kwargs):
        print(f"\n=== {name} ===", flush=True)
        start = time.perf_counter()
        out = fn(*args, **kwargs)
        self.seconds[name] = time.perf_counter() - start
        return out


def collect_stage(cfg: DemoConfig) -> dict[str, Path]:
    """Keyframe dataset (``episodes`` per variation) and dense dataset (``dense_episodes``, same first seeds)."""
    from sigma_data.cameras import RenderOptions
    from sigma_data.collect import CollectConfig, CollectOutputConfig, collect

    render = RenderOptions(cameras=",".join(cfg.cameras), height=cfg.image_size, width=cfg.image_size)
    outputs = {}
    for kind, episodes, where in (
        ("keyframe", cfg.episodes, "data"),
        ("dense", min(cfg.dense_episodes, cfg.episodes), "data_dense"),
    ):
        summary = collect(
            CollectConfig(
                tasks=",".join(cfg.tasks),
                episodes=episodes,
                output=CollectOutputConfig(
                    dir=cfg.output_dir / where,
                    repo_id="local/sigma_demo",
                    dense=kind == "dense",
                    keyframe=kind == "keyframe",
                ),
                render=render,
                workers=cfg.workers,
                shard_size=max(1, -(-episodes // cfg.workers)),
            )
        )
        print(summary.line())
        if summary.kept == 0:
            raise RuntimeError("the experts produced no successful episode; nothing to train on")
        outputs[kind] = summary.outputs[kind]
    return outputs


def validate_stage(outputs: dict[str, Path]) -> dict[str, int]:
    from sigma_data.validate import ValidateConfig, run_validate

    errors = {}
    for kind, root in outputs.items():
        errors[kind] = run_validate(ValidateConfig(root=root))
    if any(errors.values()):
        raise RuntimeError(f"dataset validation failed: {errors}")
    return errors


def train_stage(cfg: DemoConfig, keyframe_root: Path) -> Path:
    from pipelines.training import TrainRun, train
    from sigma_data.suite import scene_bounds

    run = TrainRun(
        dataset_root=keyframe_root,
        output_dir=cfg.output_dir / "train",
        steps=cfg.steps,
        batch_size=cfg.batch_size,
        scene_bounds=scene_bounds(cfg.tasks),
        job_name="sigma_demo",
        seed=cfg.seed,
        extra_args=["--policy.use_cpu_bf16_autocast=true"] if cfg.bf16 else [],
    )
    checkpoint, _ = train(run)
    return checkpoint


def eval_stage(cfg: DemoConfig, checkpoint: Path, keyframe_root: Path) -> dict:
    from pipelines.evaluate import EvalConfig, markdown_table, run_eval

    summary = run_eval(
        EvalConfig(
            checkpoint=checkpoint,
            tasks=cfg.tasks,
            episodes=cfg.eval_episodes,
            train_dataset=keyframe_root,
            max_keyframes=cfg.max_keyframes,
            workers=cfg.workers,
            output_dir=cfg.output_dir / "eval",
            rerun=True,
        )
    )
    print(markdown_table(summary))
    return summary


def viz_stage(cfg: DemoConfig, dense_root: Path, eval_summary: dict) -> dict[str, Path]:
    from pipelines.viz.cli import EpisodeViewConfig, run_episode_view

    paths = {"episode": cfg.output_dir / "viz" / "episode_0.rrd"}
    print(run_episode_view(EpisodeViewConfig(root=dense_root, episode_index=0, save=paths["episode"])))
    episodes = eval_summary["episodes"]
    for label, want in (("rollout_success", True), ("rollout_failure", False)):
        hit = next((e for e in episodes if e["success"] == want and e.get("recording")), None)
        if hit:
            dst = cfg.output_dir / "viz" / f"{label}.rrd"
            shutil.copyfile(hit["recording"], dst)
            paths[label] = dst
    return paths


def run_demo(cfg: DemoConfig) -> dict:
    import sigma_data  # noqa: F401  (MUJOCO_GL before robosuite)

    if cfg.output_dir.exists():
        shutil.rmtree(cfg.output_dir)
    cfg.output_dir.mkdir(parents=True)
    print(f"demo: {cfg.resolve_steps()}", flush=True)
    times = StageTimes()
    outputs = times.run("1/5 collect (scripted experts -> LeRobot datasets)", collect_stage, cfg)
    times.run("2/5 validate (data contract)", validate_stage, outputs)
    ckpt = times.run("3/5 train (lerobot-train --policy.type=sigma)", train_stage, cfg, outputs["keyframe"])
    summary = times.run("4/5 evaluate (sigma-eval, closed loop)", eval_stage, cfg, ckpt, outputs["keyframe"])
    recordings = times.run("5/5 visualise (Rerun recordings)", viz_stage, cfg, outputs["dense"], summary)
    report = {
        "datasets": {k: str(v) for k, v in outputs.items()},
        "checkpoint": str(ckpt),
        "eval": str(cfg.output_dir / "eval" / "results.md"),
        "recordings": {k: str(v) for k, v in recordings.items()},
        "train_steps": cfg.steps,
        "stage_seconds": times.seconds,
        "success": {f"{v['task']}:{v['variation']}": v["success_rate"] for v in summary["variations"]},
    }
    (cfg.output_dir / "demo.json").write_text(json.dumps(report, indent=2))
    print_report(cfg, report, summary)
    return report


def print_report(cfg: DemoConfig, report: dict, summary: dict) -> None:
    print("\n| task | variation | train episodes/variation | eval episodes | success |")
    print("|---|---|---|---|---|")
    for v in summary["variations"]:
        print(
            f"| {v['task']} | {v['variation']} | {cfg.episodes} | {v['episodes']} "
            f"| {v['successes']}/{v['episodes']} |"
        )
    print("\nwrote:")
    for name, path in [
        *report["datasets"].items(),
        ("checkpoint", report["checkpoint"]),
        ("eval", report["eval"]),
    ]:
        print(f"  {name:<16} {path}")
    for name, path in report["recordings"].items():
        print(f"  {name:<16} {path}   (rerun {path})")
    total = sum(report["stage_seconds"].values())
    train_s = report["stage_seconds"].get("3/5 train (lerobot-train --policy.type=sigma)", 0.0)
    print(
        f"\ndemo: {len(summary['variations'])} variations, train {train_s:.0f} s, "
        f"mean success {100 * summary['mean_success']:.0f}%, total {total / 60:.1f} min -> {cfg.output_dir}"
    )


def main(argv: list[str] | None = None) -> int:
    cfg = draccus.parse(DemoConfig, args=sys.argv[1:] if argv is None else argv)
    run_demo(cfg)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
