"""``sigma-eval``: closed-loop evaluation of a sigma checkpoint on the robosuite task suite.

Each episode resets a task variation with a seed, then asks the policy for one 9-D keyframe per step and lets
the :class:`~sigma_data.control.KeyframeExecutor` drive the robot there (``sigma_data.sim_env``), until the
task's success check passes or ``max_keyframes`` keyframes were taken. The observation goes through the same
LeRobot path as ``lerobot-eval`` (``preprocess_observation`` → the checkpoint's saved pre-processor →
``select_action`` → post-processor), so numbers agree with it.

Honest numbers: evaluation seeds start at ``seed_start`` (100000 by default) and, when ``--train_dataset`` is
given, are checked against the seeds recorded in its ``meta/sigma.json`` (overlap is an error). Every rate is
reported with its episode count, its seeds and a Wilson 95% interval. Episodes run in ``workers`` processes,
each with its own policy copy and environments.

Example::

    sigma-eval --checkpoint outputs/train/checkpoints/last/pretrained_model \\
        --tasks '[lift, stack]' --episodes 10 --workers 2 --output_dir outputs/eval
"""

from __future__ import annotations

import json
import logging
import math
import multiprocessing as mp
import os
import sys
import time
from collections import Counter, defaultdict
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import draccus
from tqdm import tqdm

from pipelines.checkpoints import CheckpointError, check_checkpoint, load_policy

logger = logging.getLogger(__name__)


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
    # Whether a policy trained with the zoomed second stage (`zoom_box_m`, sigma_policy/zoom.py) runs it; None: the
    # checkpoint's own (on). False scores the same weights on their first pass alone.
    zoom_at_inference: bool | None = None
    # Instruction-contrastive decoding's weight (the policy's `instruction_contrast`, in [0, 1);
    # sigma_policy/instruction_contrast.py); None: the checkpoint's own (0, off, unless it was trained with it set).
    # It needs the policy's instruction -> task map, which checkpoints saved before 2026-11-29 lack: it is then read
    # from --train_dataset.
    instruction_contrast: float | None = None


@dataclass(frozen=True)
class Job:
    task: str
    variation: str
    seed: int


@dataclass
class EpisodeResult:
    task: str
    variation: str
    seed: int
    success: bool
    keyframes: int
    control_steps: int
    seconds: float
    recording: str | None = None
    error: str | None = None
    # Why a failed episode failed (see :func:`failure_reason`); None on success.
    failure: str | None = None
    # One entry per keyframe taken: the action, how the arm move ended, the finger gap after it.
    trace: list[dict] = field(default_factory=list)
    # A failed episode that ended in another variation's success state (e.g. the other stacking order).
    other_variation: str | None = None


# Panda fingers: each joint travels 0..0.04 m; a closed gripper whose gap is below this holds nothing.
EMPTY_GRIP_GAP_M = 0.01
# Two consecutive keyframes this close, turned this little, with the same gripper command, make no progress: the
# policy is stuck. Door's first two keyframes turn the hand in place, so the place alone is not a repeat. The policy
# turns in 5° bins: the bound lies between one bin and two, so a one-bin jitter is a repeat whatever the rounding.
REPEAT_TOLERANCE_M = 0.01
REPEAT_TOLERANCE_DEG = 7.5


def failure_reason(result: EpisodeResult, max_keyframes: int) -> str | None:
    """A short, task-independent reason for a failed episode, from its keyframe trace.

    In order of precedence: ``error: ...`` (an exception); ``wrong object: did <variation>`` (the scene ended in
    another variation's success state: the policy did the other instruction); ``wrong object at keyframe k: went
    for <variation>`` (the gripper first closed nearer another variation's object than the instructed one, see
    :func:`nearest_variation`: the policy did not ground the instruction); ``grasp missed at keyframe k`` (the
    gripper closed on nothing: finger gap below 1 cm once the close has finished, :func:`_settled_gap`; where the
    task's objects have ``points``, followed by how the object sat between the open fingers, :func:`grasp_fit`:
    wider than the 78 mm gap means the hand's yaw was wrong, far off centre its position);
    ``dropped at keyframe k`` (something was held, then the gripper opened away from success); ``repeats keyframe
    k`` (the next keyframe is the same position, within 1 cm, the same orientation, within 7.5°, and the same gripper
    command: stuck; Door's in-place turns of the hand are not repeats); ``keyframe k not reached
    (stalled|budget)`` (the executor could not get the arm there); ``timeout after N keyframes`` (every move
    converged but the task never succeeded). The last two end with where the task's joints were at the end, for a
    task that has them (``TaskSpec.progress``: Door's hinge and lever).
    """
    import numpy as np

    from pipelines.diagnostics import geodesic_deg

    if result.success:
        return None
    if result.error is not None:
        return f"error: {result.error.splitlines()[0][:120]}"
    if result.other_variation is not None:
        return f"wrong object: did {result.other_variation}"
    held = False
    for i, step in enumerate(result.trace):
        k = step["keyframe"]
        nearest = step.get("nearest")
        if step["closed_now"] and not held and nearest is not None and nearest != result.variation:
            return f"wrong object at keyframe {k}: went for {nearest}"
        if step["closed_now"] and _settled_gap(result.trace, i) < EMPTY_GRIP_GAP_M:
            return f"grasp missed at keyframe {k}" + _fit_text(result.trace, i)
        held = held or step["closed_now"]
        if held and step["opened_now"]:
            return f"dropped at keyframe {k}"
    for prev, step in zip(result.trace, result.trace[1:], strict=False):
        same_place = math.dist(prev["action"][:3], step["action"][:3]) < REPEAT_TOLERANCE_M
        same_turn = (
            geodesic_deg(np.array(prev["action"][3:7]), np.array(step["action"][3:7])) < REPEAT_TOLERANCE_DEG
        )
        if same_place and same_turn and prev["action"][7] == step["action"][7]:
            return f"repeats keyframe {prev['keyframe']}"
    for step in result.trace:
        if step["arm_status"] != "converged":
            return f"keyframe {step['keyframe']} not reached ({step['arm_status']})" + _progress_text(
                result.trace
            )
    return (
        f"timeout after {len(result.trace)} keyframes"
        + ("" if len(result.trace) >= max_keyframes else " (stopped)")
        + _progress_text(result.trace)
    )


def _progress_text(trace: list[dict]) -> str:
    """Where the task's joints ended (``TaskSpec.progress``, e.g. Door's ``hinge_rad`` and ``lever_rad``), as
    ``"; at the end hinge_rad 0.05, lever_rad 0.8"``; empty for a task without them."""
    progress = trace[-1].get("progress") if trace else None
    if not progress:
        return ""
    return "; at the end " + ", ".join(f"{name} {value}" for name, value in progress.items())


def _fit_text(trace: list[dict], i: int) -> str:
    """How the object sat between the fingers for the close at ``trace[i]`` (:func:`grasp_fit`), from the keyframe
    before it where the hand was already down (the grasp pose, fingers open), else from the close itself."""
    fit = next((trace[j] for j in (i - 1, i) if j >= 0 and "across_fingers_mm" in trace[j]), None)
    if fit is None:
        return ""
    ridge = f", closing {fit['ridge_deg']}° off its ridge" if "ridge_deg" in fit else ""
    return (
        f" ({fit['across_fingers_mm']} mm across the fingers, {fit['off_centre_mm']} mm off centre,"
        f" {fit['below_top_mm']} mm below its top{ridge})"
    )


def _settled_gap(trace: list[dict], i: int) -> float:
    """The finger gap once the close at ``trace[i]`` has finished: a close whose arm stalled (blocked on the object)
    can end before the fingers meet, so the next keyframe's gap counts too unless it opens the gripper."""
    gap = trace[i]["finger_gap_m"]
    if i + 1 < len(trace) and not trace[i + 1]["opened_now"]:
        gap = min(gap, trace[i + 1]["finger_gap_m"])
    return gap


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


class _Worker:
    """One process: a policy copy, its processors, and a cached environment per variation."""

    def __init__(self, cfg: EvalConfig):
        import torch

        import sigma_data.lerobot_env  # noqa: F401  (registers the env type, as the plugin shim does)

        torch.set_num_threads(max(1, (os.cpu_count() or 1) // max(1, cfg.workers)))
        self.cfg = cfg
        self.policy, self.pre, self.post = load_policy(cfg.checkpoint, cfg.device)
        if cfg.tta_yaw_deg is not None:  # checked in run_eval
            self.policy.config.tta_yaw_deg = [float(a) for a in cfg.tta_yaw_deg]
        if cfg.zoom_at_inference is not None:
            self.policy.config.zoom_at_inference = cfg.zoom_at_inference
        if cfg.instruction_contrast is not None:  # checked in run_eval
            self.policy.config.instruction_contrast = cfg.instruction_contrast
            if not self.policy.config.instruction_tasks and cfg.train_dataset is not None:
                from sigma_data.contract import recorded_instruction_tasks

                self.policy.config.instruction_tasks = recorded_instruction_tasks(cfg.train_dataset)
        self.cameras = tuple(self.policy.config.camera_names())
        self.image_size = self._image_size()
        self.envs: dict[str, Any] = {}

    def _image_size(self) -> int:
        feature = self.policy.config.input_features[self.policy.config.camera_keys(self.cameras[0])["rgb"]]
        return int(feature.shape[-1])

    def close(self) -> None:
        """Close the cached envs (each frees its render context in its own GL context)."""
        while self.envs:
            self.envs.popitem()[1].close()

    def env(self, task: str, variation: str):
        from sigma_data.sim_env import SigmaRobosuiteEnv

        key = f"{task}:{variation}"
        if key not in self.envs:
            self.envs[key] = SigmaRobosuiteEnv(
                key,
                cameras=self.cameras,
                image_size=self.image_size,
                depth_unit=self.policy.config.depth_unit,
            )
        return self.envs[key]

    def act(self, obs: dict, instruction: str):
        import numpy as np
        import torch
        from lerobot.envs.utils import preprocess_observation

        batch = preprocess_observation({k: _batched(v) for k, v in obs.items()})
        batch["task"] = [instruction]
        with torch.inference_mode():
            action = self.policy.select_action(self.pre(batch))
        return np.asarray(self.post(action).cpu().numpy()[0], dtype=np.float64)

    def run(self, job: Job) -> EpisodeResult:
        env = self.env(job.task, job.variation)
        start = time.perf_counter()
        rec = None
        recording = None
        if self.cfg.rerun:
            rec, recording = self._open_recording(job)
        obs, _ = env.reset(seed=job.seed)
        self.policy.reset()
        success, steps, k, error = False, 0, 0, None
        trace: list[dict] = []
        was_open = True
        try:
            for k in range(1, self.cfg.max_keyframes + 1):
                action = self.act(obs, env.task_description)
                if rec is not None:
                    self._log_step(rec, env.task_description, k)
                obs, _, terminated, _, info = env.step(action)
                steps += info["control_steps"]
                success = bool(info["is_success"])
                now_open = bool(action[7] > 0.5)
                fingers = obs["agent_pos"][8:10]
                near = nearest_variation(env)
                trace.append(
                    {
                        "keyframe": k,
                        "action": [round(float(a), 4) for a in action],
                        "arm_status": info["arm_status"],
                        "closed_now": was_open and not now_open,
                        "opened_now": now_open and not was_open,
                        "finger_gap_m": round(float(abs(fingers[0]) + abs(fingers[1])), 4),
                    }
                    | near
                    | grasp_fit(env, near.get("nearest", job.variation))
                    | ({"progress": env.task.progress(env.env)} if env.task.progress else {})
                )
                was_open = now_open
                if terminated:
                    break
        except Exception as exc:  # a bad action or a simulator error fails this episode, not the run
            logger.exception("episode %s failed", job)
            success, error = False, repr(exc)
        finally:
            if rec is not None:
                rec.flush()
                rec.disconnect()
        result = EpisodeResult(
            job.task,
            job.variation,
            job.seed,
            success,
            k,
            steps,
            time.perf_counter() - start,
            recording,
            error,
            trace=trace,
        )
        if not success and error is None:
            result.other_variation = other_variation_done(env)
        result.failure = failure_reason(result, self.cfg.max_keyframes)
        return result

    def _open_recording(self, job: Job):
        from pipelines.viz.blueprints import policy_blueprint
        from pipelines.viz.cli import ViewerDelivery, open_recording
        from sigma_policy.renderer import VIEW_NAMES

        path = self.cfg.output_dir / "rollouts" / f"{job.task}_{job.variation}_seed{job.seed}.rrd"
        rec = open_recording(
            f"sigma-eval/{job.task}/{job.variation}/{job.seed}",
            ViewerDelivery(save=path),
            policy_blueprint(list(VIEW_NAMES)),
        )
        return rec, str(path)

    def _log_step(self, rec, instruction: str, step: int) -> None:
        """Log the policy's last decision (views, heatmaps, prediction, cloud) at ``step`` of the rollout."""
        from pipelines.viz.policy import log_policy_frame, prediction_frame

        pred = self.policy.last_prediction
        if pred is not None:
            log_policy_frame(rec, **prediction_frame(self.policy, pred, instruction), step=step)


def nearest_variation(env) -> dict[str, str]:
    """``{"nearest": <variation>}``: the variation of ``env``'s task whose object (``TaskSpec.target``) is nearest
    the grip site in the horizontal plane, e.g. which PickPlace object the hand is over; ``{}`` for a task with
    one object."""
    import numpy as np

    from sigma_data.control import grip_site_frame

    task = env.task
    if task.target is None or len(task.variations) < 2:
        return {}
    site = grip_site_frame(env.env)[0][:2]
    dist = {v.name: float(np.linalg.norm(task.target(env.env, v)[:2] - site)) for v in task.variations}
    return {"nearest": min(dist, key=dist.get)}


# The finger pads reach this far below the grip site (m): an object's vertices above it are what they close on
# (the vertices above, not a band at the pads' height: a can's or a box's mesh has vertices only at its corners).
PAD_BELOW_SITE_M = 0.01


def grasp_fit(env, variation: str) -> dict[str, int]:
    """How the object of ``variation`` sits between the fingers now, from its vertices (``TaskSpec.points``) above
    the pads' lower edge; ``{}`` for a task without ``points`` or a hand not down at the object:

    * ``across_fingers_mm``: its width along the closing axis (wider than the open gap, 78 mm for the Panda, it
      cannot be grasped at this yaw);
    * ``off_centre_mm``: how far its middle is from the fingers' midpoint along that axis;
    * ``below_top_mm``: how far the grip site is below the object's top (the expert grasps 36 mm below it, the
      palm's clearance, or 20 mm above the bottom of a short object; near 0 or negative: the hand is on top of it);
    * ``ridge_deg``, only for an object whose top is elongated (the milk carton's gable ridge; the long axis of the
      cereal box's top): the angle between the closing axis and it, 0-90 (the expert closes along the carton's
      ridge, within 12°, onto the vertical gable ends).

    At the expert's grasp (seed 0) PickPlace's objects are 31-50 mm across the fingers; turned 45° from it the
    cereal box is 93 mm (it no longer fits), the bread 62 mm and the milk carton 56 mm (they still do), the can 50.
    """
    import numpy as np

    from sigma_data.control import grip_site_frame
    from sigma_data.suite import get_variation
    from sigma_data.tasks.geometry import ridge_direction

    task = env.task
    if task.points is None:
        return {}
    site, rot = grip_site_frame(env.env)
    pts = task.points(env.env, get_variation(task, variation))
    band = pts[pts[:, 2] > site[2] - PAD_BELOW_SITE_M]
    if len(band) == 0:
        return {}
    closing = rot[:2, 0] / np.linalg.norm(rot[:2, 0])  # the site's x axis points from one finger to the other
    proj = band[:, :2] @ closing
    middle = 0.5 * (proj.max() + proj.min())
    fit = {
        "across_fingers_mm": round(1000 * float(proj.max() - proj.min())),
        "off_centre_mm": round(1000 * abs(float(middle - site[:2] @ closing))),
        "below_top_mm": round(1000 * float(pts[:, 2].max() - site[2])),
    }
    ridge = ridge_direction(pts)
    if ridge is not None:
        fit["ridge_deg"] = round(float(np.degrees(np.arccos(min(1.0, abs(float(closing @ ridge)))))))
    return fit


def other_variation_done(env) -> str | None:
    """The name of another variation of ``env``'s task whose success check passes now, if any."""
    for variation in env.task.variations:
        if variation.name != env.variation.name and env.task.success(env.env, variation):
            return variation.name
    return None


def _batched(value):
    import numpy as np

    if isinstance(value, dict):
        return {k: _batched(v) for k, v in value.items()}
    return np.asarray(value)[None]


_WORKER: _Worker | None = None


_WORKER_ERROR: BaseException | None = None


def _init_worker(cfg: EvalConfig) -> None:
    # An exception here would make multiprocessing.Pool replace the worker forever (a hang): keep it and raise
    # it from the first job instead, which ends the evaluation with that error.
    global _WORKER, _WORKER_ERROR
    logging.basicConfig(level=logging.WARNING)
    if _WORKER is not None:  # a second evaluation in this process (workers=1): the last one's envs go first
        _WORKER.close()
        _WORKER = None
    try:
        _WORKER = _Worker(cfg)
    except Exception as e:
        _WORKER_ERROR = e


def _run_job(job: Job) -> EpisodeResult:
    if _WORKER_ERROR is not None:
        raise RuntimeError(f"an evaluation worker could not start: {_WORKER_ERROR}") from _WORKER_ERROR
    assert _WORKER is not None
    return _WORKER.run(job)


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
        "config": {k: str(v) if isinstance(v, Path) else v for k, v in asdict(cfg).items()},
        "variations": rows,
        "mean_success": mean,
        "episodes": [asdict(r) for r in results],
    }


FAILURE_KINDS = ("error", "wrong object", "grasp missed", "dropped", "repeats", "not reached", "timeout")


def failure_kind(reason: str) -> str:
    """``grasp missed at keyframe 3`` -> ``grasp missed``: the kind of a :func:`failure_reason`."""
    return next((kind for kind in FAILURE_KINDS if kind in reason), reason)


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
    from sigma_policy.instruction_contrast import check_contrast_weight

    check_contrast_weight(cfg.instruction_contrast)
    config_file = Path(cfg.checkpoint) / "config.json"
    if json.loads(config_file.read_text()).get("instruction_tasks"):
        return
    if cfg.train_dataset is None or not recorded_instruction_tasks(cfg.train_dataset):
        raise ValueError(
            f"--instruction_contrast: {config_file} has no instruction_tasks (saved before they were recorded) and "
            f"--train_dataset {cfg.train_dataset} records none; pass the dataset the checkpoint was trained on"
        )


def run_eval(cfg: EvalConfig) -> dict:
    """Evaluate and write ``results.json`` / ``results.md`` under ``cfg.output_dir``; return the summary."""
    if cfg.checkpoint is None or not (Path(cfg.checkpoint) / "config.json").exists():
        raise CheckpointError(f"--checkpoint must be a pretrained_model directory, got {cfg.checkpoint}")
    if cfg.episodes < 1 or cfg.max_keyframes < 1 or cfg.workers < 1:
        raise ValueError("--episodes, --max_keyframes and --workers must be >= 1")
    check_checkpoint(cfg.checkpoint)  # here, not in a pool worker: a bad file is one clear error
    if cfg.tta_yaw_deg is not None:
        from sigma_policy.test_time import check_yaw_angles

        bins = json.loads((Path(cfg.checkpoint) / "config.json").read_text()).get("num_rotation_bins", 72)
        check_yaw_angles(cfg.tta_yaw_deg, bins)  # ValueError naming the angles
    if cfg.instruction_contrast:
        _check_instruction_contrast(cfg)
    jobs = plan_jobs(cfg)
    cfg.output_dir = Path(cfg.output_dir)
    cfg.output_dir.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    results: list[EpisodeResult] = []
    bar = tqdm(total=len(jobs), desc="sigma-eval", unit="episode")
    workers = min(cfg.workers, len(jobs))
    if workers == 1:
        _init_worker(cfg)
        for job in jobs:
            results.append(_run_job(job))
            bar.update()
    else:
        with mp.get_context("spawn").Pool(workers, initializer=_init_worker, initargs=(cfg,)) as pool:
            for result in pool.imap_unordered(_run_job, jobs):
                results.append(result)
                bar.update()
    bar.close()
    summary = summarise(results, cfg)
    summary["seconds"] = time.perf_counter() - start
    (cfg.output_dir / "results.json").write_text(json.dumps(summary, indent=2))
    (cfg.output_dir / "results.md").write_text(markdown_table(summary) + "\n")
    return summary


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
