"""``sigma-eval``: closed-loop evaluation of a sigma checkpoint on the robosuite task suite.

Each episode resets a task variation with a seed, then asks the policy for one 9-D keyframe per step and lets
the :class:`~sigma_data.keyframe_executor.KeyframeExecutor` drive the robot there (``sigma_data.sim_env``), until the
task's success check passes or ``max_keyframes`` keyframes were taken (one episode: ``pipelines/rollout.py``).
The observation goes through the same LeRobot path as ``lerobot-eval`` (``preprocess_observation`` → the
checkpoint's saved pre-processor → ``select_action`` → post-processor), so numbers agree with it.

Honest numbers: evaluation seeds start at ``seed_start`` (100000 by default) and, when ``--train_dataset`` is
given, are checked against the seeds recorded in its ``meta/sigma.json`` (overlap is an error). Every rate is
reported with its episode count, its seeds and a Wilson 95% interval. Episodes run in ``workers`` processes,
each with its own policy copy and environments.

Why a failed episode failed (wrong object, grasp missed, dropped, ...) is read from its keyframe trace by
``pipelines/failures.py``; every episode's reason is in ``results.json`` and counted by kind in the table.

A killed evaluation resumes: every finished episode is logged as it ends (``pipelines/episode_log.py``), and the
same command run again plays only the episodes that are missing.

Example::

    sigma-eval --checkpoint outputs/train/checkpoints/last/pretrained_model \\
        --tasks '[lift, stack]' --episodes 10 --workers 2 --output_dir outputs/eval
"""

from __future__ import annotations

import math
import multiprocessing as mp
import os
import sys
import time
from collections import Counter, defaultdict
from dataclasses import asdict, dataclass, field
from pathlib import Path

import draccus
from tqdm import tqdm

from pipelines.checkpoints import CheckpointError, check_act_with_ema, check_checkpoint
from pipelines.episode_log import EpisodeLog
from pipelines.failures import failure_kind
from pipelines.rollout import EpisodeResult, Job, init_worker, run_job
from sigma_data.files import sha256, write_json_atomic


@dataclass
class EvalConfig:
    """Options of ``sigma-eval``."""

    # A `pretrained_model` directory saved by lerobot-train (config.json, model.safetensors, processors).
    checkpoint: Path | None = None
    # Tasks ("lift"), single variations ("stack:green_on_red"), or "all" for the whole registered suite.
    tasks: list[str] = field(default_factory=lambda: ["lift"])
    # Episodes per variation.
    episodes: int = 10
    # First evaluation seed; episode k of a variation uses seed_start + k.
    seed_start: int = 100_000
    # The training dataset, to prove evaluation seeds are disjoint from its collection seeds (optional).
    train_dataset: Path | None = None
    # Keyframes the policy may take per episode.
    max_keyframes: int = 10
    # Parallel worker processes (each holds a policy copy and its environments).
    workers: int = 2
    device: str = "cpu"
    # Where results (results.json, results.md) and recordings go.
    output_dir: Path = Path("outputs/eval")
    # Save a Rerun recording (.rrd) of every rollout: virtual views, heatmaps, predictions per keyframe.
    rerun: bool = False
    # The test-time yaw ensemble's extra angles (degrees; the policy's `tta_yaw_deg`, sigma_policy/test_time.py);
    # None: the checkpoint's own (off unless it was trained with them set).
    tta_yaw_deg: list[float] | None = None
    # How the views' heatmaps are fused into the 3D point (the policy's `heatmap_fusion`: sum or product,
    # sigma_policy/heatmap.py); None: the one the checkpoint acts with (its config's, else its preset's).
    heatmap_fusion: str | None = None
    # Instruction-contrastive decoding's weight (the policy's `instruction_contrast`, in [0, 1);
    # sigma_policy/instruction_contrast.py); None: the checkpoint's own (0, off, unless it was trained with it set).
    # It needs the policy's instruction -> task map, which checkpoints saved before 2026-11-29 lack: it is then read
    # from --train_dataset.
    instruction_contrast: float | None = None
    # Further checkpoints trained on the same data (other seeds) that act with --checkpoint as one policy: every
    # pass averages their heatmaps and head probabilities (a deep ensemble, sigma_policy/ensemble.py). Their views
    # and boxes must be --checkpoint's; the pre- and post-processor are --checkpoint's.
    ensemble: list[Path] = field(default_factory=list)
    # For a checkpoint trained with a weight average (the policy's `ema_decay`, docs/method.md §10.1): act with the
    # average (true) or with the trained weights (false); None: the checkpoint's own choice (the average).
    act_with_ema: bool | None = None
    # Empty grasps undone per episode (pipelines/regrasp.py): when a close leaves the fingers together (nothing
    # held), the hand opens back at the approach it came down from and the policy is asked again. Each retreat is
    # one of the episode's max_keyframes. 0: off, the policy's keyframes alone.
    regrasps: int = 0


def wilson_interval(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson score 95% interval of a binomial rate (sound for small n and rates near 0 or 1)."""
    if n == 0:
        return (0.0, 1.0)
    p = successes / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return (max(0.0, centre - half), min(1.0, centre + half))


def training_seeds(train_dataset: Path) -> set[int]:
    """Collection seeds recorded in a sigma dataset's ``meta/sigma.json`` (per-episode ``seed`` fields)."""
    from sigma_data.contract import read_sidecar

    episodes = read_sidecar(Path(train_dataset)).get("episodes", [])
    return {int(e["seed"]) for e in episodes if e.get("seed") is not None}


def plan_jobs(cfg: EvalConfig) -> list[Job]:
    from sigma_data.suite import expand_tasks

    pairs = expand_tasks(cfg.tasks)
    seeds = list(range(cfg.seed_start, cfg.seed_start + cfg.episodes))
    if cfg.train_dataset is not None:
        overlap = sorted(set(seeds) & training_seeds(cfg.train_dataset))
        if overlap:
            raise ValueError(
                f"evaluation seeds {overlap[:5]}... were used to collect {cfg.train_dataset}; "
                f"choose another --seed_start"
            )
    # Interleave variations so partial results stay balanced and workers share the load evenly.
    return [Job(t, v, s) for s in seeds for t, v in pairs]


def _plain(value: object) -> object:
    """A config value as JSON holds it: paths as strings, in lists too."""
    if isinstance(value, list):
        return [_plain(v) for v in value]
    return str(value) if isinstance(value, Path) else value


def summarise(results: list[EpisodeResult], cfg: EvalConfig) -> dict:
    """Per-variation success with Wilson 95% intervals, plus the mean over variations."""
    groups: dict[tuple[str, str], list[EpisodeResult]] = defaultdict(list)
    for r in results:
        groups[(r.task, r.variation)].append(r)
    rows = []
    for (task, variation), rs in sorted(groups.items()):
        n, s = len(rs), sum(r.success for r in rs)
        lo, hi = wilson_interval(s, n)
        rows.append(
            {
                "task": task,
                "variation": variation,
                "episodes": n,
                "successes": s,
                "success_rate": s / n,
                "ci95": [lo, hi],
                "mean_keyframes": sum(r.keyframes for r in rs) / n,
                "seeds": sorted(r.seed for r in rs),
                "errors": sum(r.error is not None for r in rs),
                "failures": dict(Counter(failure_kind(r.failure) for r in rs if r.failure)),
            }
        )
    mean = sum(r["success_rate"] for r in rows) / len(rows) if rows else 0.0
    return {
        "checkpoint": str(cfg.checkpoint),
        "config": {k: _plain(v) for k, v in asdict(cfg).items()},
        "variations": rows,
        "mean_success": mean,
        "episodes": [asdict(r) for r in results],
    }


def markdown_table(summary: dict) -> str:
    lines = [
        "| task | variation | success | 95% CI | episodes | mean keyframes | errors | failures | seeds |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in summary["variations"]:
        seeds = r["seeds"]
        seed_txt = f"{seeds[0]}–{seeds[-1]}" if seeds else "-"
        lines.append(
            f"| {r['task']} | {r['variation']} | {r['successes']}/{r['episodes']} ({100 * r['success_rate']:.0f}%) "
            f"| {100 * r['ci95'][0]:.0f}–{100 * r['ci95'][1]:.0f}% | {r['episodes']} | {r['mean_keyframes']:.1f} "
            f"| {r['errors']} | {_failures_text(r.get('failures', {}))} | {seed_txt} |"
        )
    lines.append(f"| **mean** | | **{100 * summary['mean_success']:.1f}%** | | | | | | |")
    return "\n".join(lines)


def _failures_text(failures: dict[str, int]) -> str:
    return ", ".join(f"{kind} {n}" for kind, n in sorted(failures.items(), key=lambda kv: -kv[1])) or "-"


def _check_instruction_contrast(cfg: EvalConfig) -> None:
    """ValueError unless the weight is in [0, 1) and the policy will know each instruction's task: from the
    checkpoint's config or from ``--train_dataset``'s records."""
    from sigma_data.contract import recorded_instruction_tasks
    from sigma_policy.configuration_sigma import SigmaConfig
    from sigma_policy.instruction_contrast import check_contrast_weight

    check_contrast_weight(cfg.instruction_contrast)
    config_file = Path(cfg.checkpoint) / "config.json"
    if SigmaConfig.from_pretrained(cfg.checkpoint).instruction_tasks:
        return
    if cfg.train_dataset is None or not recorded_instruction_tasks(cfg.train_dataset):
        raise ValueError(
            f"--instruction_contrast: {config_file} has no instruction_tasks (saved before they were recorded) and "
            f"--train_dataset {cfg.train_dataset} records none; pass the dataset the checkpoint was trained on"
        )


def _check_ensemble(cfg: EvalConfig) -> None:
    """CheckpointError or ValueError, naming the member, unless every ``--ensemble`` checkpoint is sound and renders
    the scene as ``--checkpoint`` does (sigma_policy/ensemble.py, ``SHARED_FIELDS``)."""
    from sigma_policy.configuration_sigma import SigmaConfig
    from sigma_policy.ensemble import check_members

    for member in cfg.ensemble:
        if not (Path(member) / "config.json").exists():
            raise CheckpointError(f"--ensemble: {member} is not a pretrained_model directory")
        check_checkpoint(member)
    lead = SigmaConfig.from_pretrained(str(cfg.checkpoint))
    members = [SigmaConfig.from_pretrained(str(m)) for m in cfg.ensemble]
    check_members(lead, members, [str(m) for m in cfg.ensemble])


def run_eval(cfg: EvalConfig) -> dict:
    """Evaluate and write ``results.json`` / ``results.md`` under ``cfg.output_dir``; return the summary."""
    if cfg.checkpoint is None or not (Path(cfg.checkpoint) / "config.json").exists():
        raise CheckpointError(f"--checkpoint must be a pretrained_model directory, got {cfg.checkpoint}")
    if cfg.episodes < 1 or cfg.max_keyframes < 1 or cfg.workers < 1:
        raise ValueError("--episodes, --max_keyframes and --workers must be >= 1")
    if cfg.regrasps < 0:
        raise ValueError(f"--regrasps must be >= 0, got {cfg.regrasps}")
    check_checkpoint(cfg.checkpoint)  # here, not in a pool worker: a bad file is one clear error
    if cfg.ensemble:
        _check_ensemble(cfg)
    if cfg.tta_yaw_deg is not None:
        from sigma_policy.configuration_sigma import SigmaConfig
        from sigma_policy.test_time import check_yaw_angles

        bins = SigmaConfig.from_pretrained(cfg.checkpoint).num_rotation_bins
        check_yaw_angles(cfg.tta_yaw_deg, bins)  # ValueError naming the angles
    if cfg.heatmap_fusion is not None:
        from sigma_policy.heatmap import check_heatmap_fusion

        check_heatmap_fusion(cfg.heatmap_fusion, "--heatmap_fusion")
    if cfg.instruction_contrast:
        _check_instruction_contrast(cfg)
    if cfg.act_with_ema is not None:
        check_act_with_ema(cfg.checkpoint)
    jobs = plan_jobs(cfg)
    cfg.output_dir = Path(cfg.output_dir)
    cfg.output_dir.mkdir(parents=True, exist_ok=True)
    # A previous run's results are replaced at the end; meanwhile nothing should take them for this run's.
    for name in ("results.json", "results.md"):
        (cfg.output_dir / name).unlink(missing_ok=True)
    log, results, todo = _resume(cfg, jobs)
    start = time.perf_counter()
    bar = tqdm(total=len(jobs), initial=len(results), desc="sigma-eval", unit="episode")
    workers = min(cfg.workers, len(todo))
    if workers == 1:
        init_worker(cfg)
        for job in todo:
            results.append(run_job(job))
            log.append(results[-1])
            bar.update()
    elif workers > 1:
        with mp.get_context("spawn").Pool(workers, initializer=init_worker, initargs=(cfg,)) as pool:
            for result in pool.imap_unordered(run_job, todo):
                results.append(result)
                log.append(result)
                bar.update()
    bar.close()
    summary = summarise(results, cfg)
    summary["seconds"] = time.perf_counter() - start
    summary["resumed_episodes"] = len(jobs) - len(todo)
    (cfg.output_dir / "results.md").write_text(markdown_table(summary) + "\n")
    write_json_atomic(cfg.output_dir / "results.json", summary, indent=2)
    log.remove()
    return summary


def _resume(cfg: EvalConfig, jobs: list[Job]) -> tuple[EpisodeLog, list[EpisodeResult], list[Job]]:
    """The episode log of this evaluation, the planned episodes a killed run of it already finished
    (``pipelines/episode_log.py``: the same weights, keyframe budget and test-time options), and the jobs left."""
    # The weights by content: the same wherever the checkpoint was copied to (a GPU lease's, unpacked here).
    header = {
        "weights_sha256": sha256(Path(cfg.checkpoint) / "model.safetensors"),
        "max_keyframes": cfg.max_keyframes,
        "tta_yaw_deg": cfg.tta_yaw_deg,
        "instruction_contrast": cfg.instruction_contrast,
    }
    if cfg.act_with_ema is not None:  # the header of every other log stays as it was
        header["act_with_ema"] = cfg.act_with_ema
    if cfg.regrasps:  # likewise
        header["regrasps"] = cfg.regrasps
    from sigma_policy.configuration_sigma import SigmaConfig

    # likewise for a policy acting with the sum; a checkpoint saved before the field acts with its preset's now
    fusion = cfg.heatmap_fusion or SigmaConfig.from_pretrained(cfg.checkpoint).heatmap_fusion
    if cfg.heatmap_fusion is not None or fusion != "sum":
        header["heatmap_fusion"] = fusion
    if cfg.ensemble:  # the header of a single policy's log stays as it was
        header["ensemble_sha256"] = [sha256(Path(m) / "model.safetensors") for m in cfg.ensemble]
    log = EpisodeLog(cfg.output_dir, header)
    logged = {Job(r.task, r.variation, r.seed): r for r in log.resume(lambda d: EpisodeResult(**d))}
    done = [logged[j] for j in jobs if j in logged]
    if done:
        print(f"sigma-eval: resuming {cfg.output_dir}: {len(done)} of {len(jobs)} episodes already finished")
    return log, done, [j for j in jobs if j not in logged]


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    import sigma_data  # noqa: F401  (MUJOCO_GL before robosuite)

    cfg = draccus.parse(EvalConfig, args=sys.argv[1:] if argv is None else argv)
    try:
        summary = run_eval(cfg)
    except (CheckpointError, ValueError) as e:  # a bad checkpoint or option: one line, before any episode
        print(f"sigma-eval: {e}", file=sys.stderr)
        return 1
    print(markdown_table(summary))
    n = len(summary["episodes"])
    wins = sum(e["success"] for e in summary["episodes"])
    print(
        f"sigma-eval: {wins}/{n} episodes succeeded over {len(summary['variations'])} variations "
        f"(mean {100 * summary['mean_success']:.1f}%) in {summary['seconds']:.0f} s; "
        f"results in {cfg.output_dir}/results.md"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
