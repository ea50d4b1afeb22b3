"""One closed-loop episode of ``sigma-eval``, played in a worker process: the policy asks for a keyframe, the
:class:`~sigma_data.keyframe_executor.KeyframeExecutor` (inside ``sigma_data.sim_env``) drives the arm there, and the episode
ends on the task's success or after ``max_keyframes`` keyframes.

:class:`RolloutWorker` holds one policy copy, its processors and one cached environment per variation.
:func:`init_worker` / :func:`run_job` are what ``pipelines/evaluate.py``'s process pool (or its single in-process
worker) calls. Every keyframe taken is traced (the action, how the arm move ended, the finger gap, the nearest
variation's object), and ``pipelines/failures.py`` reads the trace to say why a failed episode failed.
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from pipelines.checkpoints import load_policy
from pipelines.failures import (
    failure_reason,
    grasp_fit,
    handle_fit,
    nearest_variation,
    other_variation_done,
    placement_fit,
)
from pipelines.regrasp import grasp_is_empty, retreat_keyframe

if TYPE_CHECKING:
    from pipelines.evaluate import EvalConfig

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class Job:
    """One episode to play: a task's variation and the seed its scene is reset with."""

    task: str
    variation: str
    seed: int


@dataclass
class EpisodeResult:
    """What one episode did: a line of the episode log (``pipelines/episode_log.py``) and an entry of
    ``results.json``'s ``episodes``."""

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


class RolloutWorker:
    """One process: a policy copy, its processors, and a cached environment per variation."""

    def __init__(self, cfg: EvalConfig):
        import torch

        import sigma_data.lerobot_env  # noqa: F401  (registers the env type, as the plugin shim does)

        torch.set_num_threads(max(1, (os.cpu_count() or 1) // max(1, cfg.workers)))
        self.cfg = cfg
        self.policy, self.pre, self.post = load_policy(cfg.checkpoint, cfg.device)
        if cfg.ensemble:  # checked in run_eval
            members = [load_policy(m, cfg.device)[0] for m in cfg.ensemble]
            self.policy.add_ensemble_members(members, [str(m) for m in cfg.ensemble])
        if cfg.tta_yaw_deg is not None:  # checked in run_eval
            self.policy.config.tta_yaw_deg = [float(a) for a in cfg.tta_yaw_deg]
        if cfg.act_with_ema is not None:  # checked in run_eval
            self.policy.config.act_with_ema = cfg.act_with_ema
        if cfg.heatmap_fusion is not None:  # checked in run_eval
            self.policy.config.heatmap_fusion = cfg.heatmap_fusion
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
        regrasps_left, retreat = self.cfg.regrasps, None
        try:
            for k in range(1, self.cfg.max_keyframes + 1):
                retreating = retreat is not None
                if retreating:  # the last close held nothing: undo it (pipelines/regrasp.py)
                    action, retreat = retreat, None
                else:
                    action = self.act(obs, env.task_description)
                    if rec is not None:
                        self._log_step(rec, env.task_description, k)
                obs, _, terminated, _, info = env.step(action)
                steps += info["control_steps"]
                success = bool(info["is_success"])
                now_open = bool(action[7] > 0.5)
                fingers = obs["agent_pos"][8:10]
                near = nearest_variation(env)
                over = near.get("nearest", job.variation)  # the object the hand is over
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
                    | grasp_fit(env, over)
                    | handle_fit(env, over)
                    | ({"progress": env.task.progress(env.env)} if env.task.progress else {})
                    | placement_fit(env)
                    | ({"regrasp": True} if retreating else {})
                )
                was_open = now_open
                if terminated:
                    break
                if regrasps_left and grasp_is_empty(trace[-1]):
                    retreat, regrasps_left = retreat_keyframe(trace), regrasps_left - 1
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

        path = self.cfg.output_dir / "rollouts" / f"{job.task}_{job.variation}_seed{job.seed}.rrd"
        rec = open_recording(
            f"sigma-eval/{job.task}/{job.variation}/{job.seed}",
            ViewerDelivery(save=path),
            policy_blueprint(self.policy.renderer.view_names),
        )
        return rec, str(path)

    def _log_step(self, rec, instruction: str, step: int) -> None:
        """Log the policy's last decision (views, heatmaps, prediction, cloud) at ``step`` of the rollout."""
        from pipelines.viz.policy import log_policy_frame, prediction_frame

        pred = self.policy.last_prediction
        if pred is not None:
            log_policy_frame(rec, **prediction_frame(self.policy, pred, instruction), step=step)


def _batched(value):
    import numpy as np

    if isinstance(value, dict):
        return {k: _batched(v) for k, v in value.items()}
    return np.asarray(value)[None]


_WORKER: RolloutWorker | None = None


_WORKER_ERROR: BaseException | None = None


def init_worker(cfg: EvalConfig) -> None:
    # An exception here would make multiprocessing.Pool replace the worker forever (a hang): keep it and raise
    # it from the first job instead, which ends the evaluation with that error.
    global _WORKER, _WORKER_ERROR
    logging.basicConfig(level=logging.WARNING)
    if _WORKER is not None:  # a second evaluation in this process (workers=1): the last one's envs go first
        _WORKER.close()
        _WORKER = None
    _WORKER_ERROR = None
    try:
        _WORKER = RolloutWorker(cfg)
    except Exception as e:
        _WORKER_ERROR = e


def run_job(job: Job) -> EpisodeResult:
    if _WORKER_ERROR is not None:
        raise RuntimeError(f"an evaluation worker could not start: {_WORKER_ERROR}") from _WORKER_ERROR
    assert _WORKER is not None
    return _WORKER.run(job)
