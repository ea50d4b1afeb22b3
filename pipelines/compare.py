"""``sigma-compare``: the Σ-agent beside the stock LeRobot policies a user would pick instead, on the same demos.

One collection by the scripted experts writes both datasets from the same episodes: the keyframe dataset (RGB-D,
calibration, next-keyframe actions) for sigma, and an RGB-only dense dataset (every 20 Hz control step, 7-D
OSC_POSE actions; ``--output.dense_depth=false``, so stock image policies take it as it is) for the stock policies.
Every policy trains with the stock ``lerobot-train``, one at a time (the machine's cores go to one job), and is
evaluated on the same held-out seeds (from 100000, per variation): sigma by ``sigma-eval`` in keyframe control,
the stock policies by the stock ``lerobot-eval`` in the dense control mode of ``--env.type=sigma_robosuite``.

How each policy receives the instruction: sigma encodes it (frozen MiniLM tokens, fused with the image tokens);
LeRobot 0.6.1's ACT and Diffusion Policy take no language input (the ``task`` string reaches their
pre-processor and is not used), so on tasks where the instruction decides success (Stack's two orders) they can
at best pick one order per scene.

Every stage resumes: finished shards, checkpoints and evaluations are reused (``--fresh true`` retrains and
re-evaluates). Example::

    sigma-compare --tasks '[lift]' --episodes 30 --eval_episodes 20 --publish true
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import draccus

from sigma_data.cameras import DEFAULT_CAMERAS

os.environ.setdefault("HF_HUB_OFFLINE", "1")

# lerobot-train arguments of the stock policies. Offline: no ImageNet backbone download (LeRobot's default), so
# Diffusion Policy uses GroupNorm as its docs require for a backbone trained from scratch. Sizes fit 64² images
# and a 20 Hz, ~3 s task: ACT predicts 1 s chunks; Diffusion Policy a 16-step horizon of which it executes 8,
# with a smaller U-Net than the default (512, 1024, 2048) and 10 DDIM steps at inference, for a CPU budget, and
# random crops of 7/8 of the image (84 of 96 pixels in the Diffusion Policy paper; added by stock_args).
STOCK_ARGS: dict[str, list[str]] = {
    "act": [
        "--policy.pretrained_backbone_weights=null",
        "--policy.chunk_size=20",
        "--policy.n_action_steps=20",
    ],
    "diffusion": [
        "--policy.pretrained_backbone_weights=null",
        "--policy.use_group_norm=true",
        "--policy.horizon=16",
        "--policy.n_action_steps=8",
        "--policy.down_dims=[128,256,512]",
        "--policy.use_separate_rgb_encoder_per_camera=false",
        "--policy.noise_scheduler_type=DDIM",
        "--policy.num_inference_steps=10",
    ],
}


def stock_args(policy: str, image_size: int) -> list[str]:
    """``lerobot-train`` arguments of a stock policy for ``image_size``² cameras."""
    args = list(STOCK_ARGS[policy])
    if policy == "diffusion":
        crop = image_size * 7 // 8
        args.append(f"--policy.crop_shape=[{crop},{crop}]")
    return args


LANGUAGE = {
    "sigma": "MiniLM token features fused with image tokens",
    "act": "none (task string unused)",
    "diffusion": "none (task string unused)",
}


@dataclass
class PolicyBudget:
    """Training budget of one policy."""

    steps: int
    batch_size: int = 8


@dataclass
class CompareConfig:
    """Options of ``sigma-compare``."""

    output_dir: Path = Path("outputs/compare")
    # Tasks (all their variations).
    tasks: list[str] = field(default_factory=lambda: ["lift"])
    # Expert seeds collected per variation (failed expert episodes are dropped), and the camera set-up.
    episodes: int = 30
    cameras: list[str] = field(default_factory=lambda: list(DEFAULT_CAMERAS))
    image_size: int = 64
    # Policies to train and evaluate: "sigma" and stock LeRobot types from STOCK_ARGS.
    policies: list[str] = field(default_factory=lambda: ["sigma", "act", "diffusion"])
    # Training budgets. The defaults give each policy about the same wall time on 2 CPU cores (~11 min: sigma
    # `small` and Diffusion Policy ~2.3 steps/s, ACT ~1.5 steps/s at batch 8, 4 cameras at 64²).
    sigma: PolicyBudget = field(default_factory=lambda: PolicyBudget(steps=1500))
    act: PolicyBudget = field(default_factory=lambda: PolicyBudget(steps=1000))
    diffusion: PolicyBudget = field(default_factory=lambda: PolicyBudget(steps=1500))
    sigma_preset: str = "small"
    seed: int = 0
    device: str = "cpu"
    # Evaluation episodes per variation (seeds from 100000, disjoint from the collection seeds).
    eval_episodes: int = 20
    # sigma: keyframes per episode; the stock policies: control steps per episode (0 = the task's max_steps).
    max_keyframes: int = 12
    max_control_steps: int = 0
    # Worker processes for collection and sigma-eval.
    workers: int = 2
    # Retrain and re-evaluate (the collected data is always reused when complete).
    fresh: bool = False
    # Also write benchmarks/results/compare.md (+ .json), the fragment RESULTS.md includes.
    publish: bool = False

    def __post_init__(self) -> None:
        unknown = [p for p in self.policies if p != "sigma" and p not in STOCK_ARGS]
        if unknown:
            raise ValueError(f"unknown policies {unknown}; known: sigma, {', '.join(STOCK_ARGS)}")

    def budget(self, policy: str) -> PolicyBudget:
        return getattr(self, policy)


def collect_stage(cfg: CompareConfig) -> dict[str, Path]:
    """Scripted experts -> keyframe (RGB-D) + dense (RGB-only) datasets from the same episodes."""
    from pipelines.collecting import collect_demonstrations

    return collect_demonstrations(
        cfg.output_dir,
        cfg.tasks,
        cfg.episodes,
        cfg.cameras,
        cfg.image_size,
        cfg.workers,
        "local/sigma_compare",
        dense_depth=False,
    )


def train_stage(cfg: CompareConfig, data: dict[str, Path]) -> dict[str, dict]:
    """Train each policy in turn with lerobot-train (finished runs are reused)."""
    from pipelines.training import TrainRun, last_logged_metrics, train
    from sigma_data.suite import scene_bounds

    results: dict[str, dict] = {}
    for policy in cfg.policies:
        budget = cfg.budget(policy)
        sigma = policy == "sigma"
        run = TrainRun(
            dataset_root=data["keyframe" if sigma else "dense"],
            output_dir=cfg.output_dir / "train" / policy,
            steps=budget.steps,
            batch_size=budget.batch_size,
            scene_bounds=scene_bounds(cfg.tasks) if sigma else None,
            preset=cfg.sigma_preset,
            policy_type=policy,
            device=cfg.device,
            seed=cfg.seed,
            job_name=f"compare_{policy}",
            extra_args=[] if sigma else stock_args(policy, cfg.image_size),
        )
        done = cfg.output_dir / "train" / f"{policy}.json"
        previous = run.reuse_or_clear(done, policy)
        if previous is not None:
            results[policy] = previous
            continue
        log = cfg.output_dir / "train" / f"{policy}.log"
        print(
            f"{policy}: lerobot-train {budget.steps} steps x batch {budget.batch_size}; log {log}", flush=True
        )
        ckpt, seconds = train(run, log)
        results[policy] = {
            "checkpoint": str(ckpt),
            "train_seconds": seconds,
            "steps": budget.steps,
            "batch_size": budget.batch_size,
            "dataset": str(run.dataset_root),
            "args": run.arguments(),
            "last_metrics": last_logged_metrics(log),
        }
        done.write_text(json.dumps(results[policy], indent=2))
        print(f"{policy}: trained in {seconds:.0f} s", flush=True)
    return results


def lerobot_eval_variation(
    cfg: CompareConfig, checkpoint: Path, task: str, variation: str, out: Path
) -> dict:
    """The stock ``lerobot-eval`` on one variation in dense control; returns its per-episode rows."""
    from sigma_data.suite import get_task

    cmd = [
        str(Path(sys.executable).with_name("lerobot-eval")),
        f"--policy.path={checkpoint}",
        f"--policy.device={cfg.device}",
        "--env.type=sigma_robosuite",
        "--env.control=dense",
        "--env.depth=false",
        f"--env.task={task}:{variation}",
        f"--env.cameras=[{','.join(cfg.cameras)}]",
        f"--env.image_size={cfg.image_size}",
        f"--env.episode_length={cfg.max_control_steps or get_task(task).max_steps}",
        f"--eval.n_episodes={cfg.eval_episodes}",
        "--eval.batch_size=1",
        "--eval.use_async_envs=false",
        "--seed=100000",
        f"--output_dir={out}",
    ]
    if out.exists():
        shutil.rmtree(out)  # lerobot-eval writes videos into it; a rerun starts clean
    out.parent.mkdir(parents=True, exist_ok=True)
    log = out.with_suffix(".log")
    with open(log, "w") as fh:
        fh.write("$ " + " ".join(cmd) + "\n")
        fh.flush()
        code = subprocess.run(
            cmd, stdout=fh, stderr=subprocess.STDOUT, env=dict(os.environ, HF_HUB_OFFLINE="1")
        )
    if code.returncode != 0:
        raise RuntimeError(f"lerobot-eval on {task}:{variation} exited with {code.returncode}; see {log}")
    info = json.loads((out / "eval_info.json").read_text())
    successes = info["per_task"][0]["metrics"][
        "successes"
    ]  # episode i ran with seed 100000 + i (batch size 1)
    return {
        "rows": [{"seed": 100000 + i, "success": bool(s)} for i, s in enumerate(successes)],
        "log": str(log),
    }


def eval_stage(cfg: CompareConfig, data: dict[str, Path], trained: dict[str, dict]) -> dict[str, list[dict]]:
    """Per policy, per variation: successes over the same seeds, with Wilson 95% intervals."""
    from pipelines.evaluate import EvalConfig, run_eval, wilson_interval
    from sigma_data.suite import expand_tasks

    out: dict[str, list[dict]] = {}
    for policy, info in trained.items():
        cached = cfg.output_dir / "eval" / f"{policy}.json"
        if cached.exists():
            out[policy] = json.loads(cached.read_text())
            print(f"{policy}: reusing the evaluation in {cached}", flush=True)
            continue
        t0 = time.perf_counter()
        rows = []
        if policy == "sigma":
            summary = run_eval(
                EvalConfig(
                    checkpoint=Path(info["checkpoint"]),
                    tasks=cfg.tasks,
                    episodes=cfg.eval_episodes,
                    train_dataset=data["keyframe"],
                    max_keyframes=cfg.max_keyframes,
                    workers=cfg.workers,
                    device=cfg.device,
                    output_dir=cfg.output_dir / "eval" / "sigma",
                )
            )
            rows = [
                {k: r[k] for k in ("task", "variation", "episodes", "successes", "ci95", "seeds")}
                for r in summary["variations"]
            ]
        else:
            for task, variation in expand_tasks(cfg.tasks):
                print(f"{policy}: lerobot-eval {task}:{variation}, {cfg.eval_episodes} episodes", flush=True)
                res = lerobot_eval_variation(
                    cfg,
                    Path(info["checkpoint"]),
                    task,
                    variation,
                    cfg.output_dir / "eval" / policy / variation,
                )
                n, s = len(res["rows"]), sum(r["success"] for r in res["rows"])
                rows.append(
                    {
                        "task": task,
                        "variation": variation,
                        "episodes": n,
                        "successes": s,
                        "ci95": list(wilson_interval(s, n)),
                        "seeds": sorted(r["seed"] for r in res["rows"] if r["seed"] is not None),
                    }
                )
        for r in rows:
            r["eval_seconds"] = (time.perf_counter() - t0) / len(rows)
        cached.parent.mkdir(parents=True, exist_ok=True)
        cached.write_text(json.dumps(rows, indent=2))
        out[policy] = rows
    return out


def _cell(row: dict | None) -> str:
    if row is None:
        return "-"
    lo, hi = row["ci95"]
    return f"{row['successes']}/{row['episodes']} ({100 * lo:.0f}–{100 * hi:.0f}%)"


def report(
    cfg: CompareConfig, data: dict[str, Path], trained: dict[str, dict], evals: dict[str, list]
) -> str:
    """Markdown: success per variation and policy (Wilson 95%), then each policy's budget and wall time."""
    from sigma_data.contract import read_sidecar

    policies = [p for p in cfg.policies if p in evals]
    by = {p: {(r["task"], r["variation"]): r for r in evals[p]} for p in policies}
    keys = sorted(set().union(*(b.keys() for b in by.values())))
    lines = [
        "| task | variation | " + " | ".join(policies) + " |",
        "|---|---|" + "---|" * len(policies),
    ]
    for key in keys:
        lines.append(f"| {key[0]} | {key[1]} | " + " | ".join(_cell(by[p].get(key)) for p in policies) + " |")
    means = []
    for p in policies:
        rates = [r["successes"] / r["episodes"] for r in evals[p]]
        means.append(f"**{100 * sum(rates) / len(rates):.0f}%**")
    lines.append("| **mean** | | " + " | ".join(means) + " |")
    lines += [
        "",
        "| policy | data | steps × batch | training wall time | instruction | arguments |",
        "|---|---|---|---|---|---|",
    ]
    for p in policies:
        t = trained[p]
        args = " ".join(
            f"`{a}`"
            for a in (
                [f"--policy.preset={cfg.sigma_preset}"] if p == "sigma" else stock_args(p, cfg.image_size)
            )
        )
        kind = "keyframe (RGB-D)" if p == "sigma" else "dense (RGB)"
        lines.append(
            f"| {p} | {kind} | {t['steps']} × {t['batch_size']} | {t['train_seconds'] / 60:.1f} min | "
            f"{LANGUAGE.get(p, '-')} | {args} |"
        )
    n_eps = read_sidecar(data["keyframe"]).get("num_episodes", "?")
    seeds = next(iter(evals.values()))[0]["seeds"]
    limit = cfg.max_control_steps or "the task's"
    setup = (
        f"Data: {n_eps} expert episodes ({cfg.episodes} seeds per variation from 0, failed expert runs dropped), "
        f"{len(cfg.cameras)} cameras at {cfg.image_size}² ({', '.join(cfg.cameras)}); the keyframe and the "
        f"dense dataset hold the same episodes. Training: stock `lerobot-train`, seed {cfg.seed}, {cfg.device}, "
        f"one policy at a time. Evaluation: {cfg.eval_episodes} episodes per variation, seeds {seeds[0]}–"
        f"{seeds[-1]} (disjoint from the training seeds); sigma by `sigma-eval` (≤ {cfg.max_keyframes} "
        "keyframes), the stock policies by the stock `lerobot-eval --env.type=sigma_robosuite --env.control=dense` "
        f"({limit} control-step limit). Cells: successes / episodes (Wilson 95% interval). Single runs."
    )
    return "\n".join([setup, "", *lines])


def run_compare(cfg: CompareConfig) -> str:
    import sigma_data  # noqa: F401  (MUJOCO_GL before robosuite)
    from pipelines.reporting import start_run_dir, write_run_outputs

    cfg.output_dir = start_run_dir(cfg.output_dir, cfg.fresh)
    t0 = time.perf_counter()
    print("=== 1/3 collect (scripted experts -> keyframe RGB-D + dense RGB datasets) ===", flush=True)
    data = collect_stage(cfg)
    print("\n=== 2/3 train (lerobot-train, one policy at a time) ===", flush=True)
    trained = train_stage(cfg, data)
    print("\n=== 3/3 evaluate (sigma-eval / lerobot-eval, same seeds) ===", flush=True)
    evals = eval_stage(cfg, data, trained)
    text = report(cfg, data, trained, evals)
    write_run_outputs(
        cfg.output_dir,
        "compare",
        "Σ-agent vs stock LeRobot policies (same demonstrations, same evaluation seeds)",
        text,
        cfg,
        {"trained": trained, "eval": evals},
        cfg.publish,
    )
    print("\n" + text)
    parts = []
    for p, rows in evals.items():
        s, n = sum(r["successes"] for r in rows), sum(r["episodes"] for r in rows)
        parts.append(f"{p} {s}/{n}")
    print(
        f"\nsigma-compare: {', '.join(parts)} over {len(next(iter(evals.values())))} variation(s) in "
        f"{(time.perf_counter() - t0) / 60:.1f} min -> {cfg.output_dir}/compare.md"
    )
    return text


def main(argv: list[str] | None = None) -> int:
    cfg = draccus.parse(CompareConfig, args=sys.argv[1:] if argv is None else argv)
    run_compare(cfg)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
