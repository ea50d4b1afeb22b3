"""One shard: record, filter, render and write its seeds into ``<shard_dir>/{dense,keyframe}``, then the
``shard.json`` marker (:func:`collect_shard`).

Per episode: reset (``reset_env``, deterministic in the seed), record the expert **without rendering**
(:class:`~sigma_data.record.EpisodeRecorder` stores the flattened sim state every control step), drop and count
the episode if the expert gives up or the task's success check fails, else replay the stored states and render
**only the frames that are written** (every frame for the dense dataset, the decision points for the keyframe
dataset; a frame both need is rendered once).

A worker with more than one core (``render_threads`` >= 2; by default the cores divided among the workers)
overlaps three things: the env records episode k + 1 in a background thread (:func:`_ahead`), the frames of
episode k render ahead of the writers in ``render_threads`` threads with their own GL contexts
(:mod:`sigma_data.replay_render`, the images of rendering them one by one but for rare single pixels,
``docs/robosuite.md`` §2), and the writers write them (LeRobot's video encoders run in threads of their own). A worker with one core does them in turn.
"""

from __future__ import annotations

import contextlib
import dataclasses
import queue
import shutil
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sigma_data.cameras import CameraRig
from sigma_data.collect.config import DATASETS, MARKER, CollectConfig, ShardResult, ShardSpec
from sigma_data.collect.envs import cached_env, cached_replay
from sigma_data.collect.manifest import shard_files
from sigma_data.dataset_layout import DatasetLayout
from sigma_data.episode import Episode
from sigma_data.files import write_json_atomic
from sigma_data.keyframes import compare_keyframes, discover_keyframes
from sigma_data.replay_render import RenderedFrames, ReplayRenderer, SceneSnapshot
from sigma_data.writers import DenseWriter, KeyframeWriter, SigmaWriter, shared_frames


def _heuristic_vs_expert(ep: Episode) -> tuple[list[int], dict[str, float]]:
    gripper = ep.states[:, 7]
    heuristic = discover_keyframes(ep.joint_velocities, gripper)
    match = compare_keyframes(ep.keyframe_indices, heuristic, tolerance=3)
    return heuristic, {
        "episodes": 1,
        "expert": match.reference,
        "heuristic": match.found,
        "matched": match.matched,
        "heuristic_near_expert": match.precision * match.found,
    }


def _provenance(cfg: CollectConfig, shards_tasks: list[str]) -> dict[str, Any]:
    from sigma_data.suite import CONTROL_FREQ, CONTROLLER, ROBOT, get_task

    return {
        "source": "robosuite scripted experts (sigma_data.collect)",
        "robot": ROBOT,
        "controller": {
            "composite": CONTROLLER,
            "arm": "OSC_POSE",
            "input": "delta, base frame",
            "control_freq": CONTROL_FREQ,
        },
        "env_kwargs": {t: dict(get_task(t).env_kwargs) for t in shards_tasks},
        "env_name": {t: get_task(t).env_name for t in shards_tasks},
        "bounds": {t: list(get_task(t).bounds) for t in shards_tasks},
        "render": asdict(cfg.render.config()),
        "model_seed": cfg.model_seed,
        "pregrasp_jitter_m": cfg.pregrasp_jitter_m,
        "fingerprint": cfg.fingerprint(),
    }


def _static_json(rig: CameraRig) -> dict[str, Any]:
    return {
        cam: {"intrinsics": K.tolist(), "extrinsics": E.tolist()}
        for cam, (K, E) in rig.static_calibration().items()
    }


@dataclass
class _Recording:
    """One seed's expert run: the episode and the scene it was recorded in, or why it was dropped."""

    seed: int
    seconds: float
    steps: int
    episode: Episode | None = None
    snapshot: SceneSnapshot | None = None
    reason: str = ""


def _record(
    env: Any,
    task: Any,
    variation: Any,
    spec: ShardSpec,
    seed: int,
    replay: ReplayRenderer | None,
    pregrasp_jitter_m: float = 0.0,
) -> _Recording:
    """Reset ``env`` to ``seed``, run the expert without rendering and check success (and, for ``replay``, take
    the snapshot of the scene its frames render from)."""
    from sigma_data.experts.base import ExpertFailure
    from sigma_data.record import EpisodeRecorder
    from sigma_data.suite import reset_env

    start = time.perf_counter()
    reset_env(env, task, variation, seed)
    recorder = EpisodeRecorder(env, pregrasp_jitter_m=pregrasp_jitter_m)
    reason = ""
    try:
        task.expert(recorder, variation, np.random.default_rng(seed))
        if not task.success(env, variation):
            reason = "success check failed at the end of the expert"
    except ExpertFailure as exc:
        reason = f"expert failure: {exc}"
    if reason or recorder.num_steps == 0:
        return _Recording(seed, time.perf_counter() - start, recorder.num_steps, reason=reason or "no steps")
    ep = recorder.to_episode(
        spec.task, spec.variation, variation.instruction, seed, provenance={"expert": spec.task}
    )
    snapshot = replay.snapshot() if replay is not None else None
    return _Recording(seed, time.perf_counter() - start, recorder.num_steps, ep, snapshot)


def _ahead(items: Iterator[Any], depth: int = 1) -> Iterator[Any]:
    """Yield ``items``, produced in a background thread at most ``depth`` items ahead of the consumer. An error
    of the producer is raised here; when the consumer stops early the producer stops after its current item."""
    buffer: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def produce() -> None:
        try:
            for item in items:
                buffer.put((True, item))
                if stop.is_set():
                    return
            buffer.put((False, None))
        except BaseException as exc:  # re-raised in the consumer
            buffer.put((False, exc))

    producer = threading.Thread(target=produce, name="sigma-record", daemon=True)
    producer.start()
    try:
        while True:
            more, item = buffer.get()
            if not more:
                if item is not None:
                    raise item
                return
            yield item
    finally:
        stop.set()
        while producer.is_alive():  # unblock a producer waiting to put
            with contextlib.suppress(queue.Empty):
                buffer.get(timeout=0.1)
        producer.join()


def collect_shard(
    spec: ShardSpec, cfg: CollectConfig, shard_dir: Path, on_episode: Callable[[], None] | None = None
) -> ShardResult:
    """Record, filter, render and write one shard into ``shard_dir`` (replaced if present); writes the marker,
    with the files of its datasets, last."""
    from sigma_data.suite import get_task, get_variation

    start_all = time.perf_counter()
    if shard_dir.exists():
        shutil.rmtree(shard_dir)
    shard_dir.mkdir(parents=True)
    task = get_task(spec.task)
    variation = get_variation(task, spec.variation)
    render = cfg.render.config()
    result = ShardResult(spec.name, fingerprint=cfg.fingerprint())
    env = cached_env(spec.task, render, cfg.model_seed)  # stays open for the task's next shard
    rig = CameraRig(env, render)
    # A worker with cores to spare overlaps recording, rendering and writing; one with a single core does them in
    # turn (threads there only add GIL hand-offs and a scene copy per episode: measured slower with 2 workers).
    threads = cfg.threads_per_worker()
    replay = cached_replay(rig, threads) if threads > 1 else None
    layout = DatasetLayout(render.cameras, render.height, render.width)
    # Static K/E go into the feature info only when one task (one scene) fills the dataset: shards of
    # different scenes would disagree and LeRobot's merge requires identical features.
    static = rig.static_calibration() if len(cfg.task_names()) == 1 else None
    common = {
        "layout": layout,
        "provenance": {**_provenance(cfg, [spec.task]), "static_calibration": _static_json(rig)},
        "static_calibration": static,
    }
    with contextlib.ExitStack() as stack:
        writers: dict[str, SigmaWriter] = {}
        if cfg.output.dense:
            writers["dense"] = stack.enter_context(
                DenseWriter(
                    shard_dir / "dense",
                    use_videos=cfg.output.dense_video,
                    repo_id=f"{cfg.output.repo_id}_dense",
                    **(common | {"layout": dataclasses.replace(layout, depth=cfg.output.dense_depth)}),
                )
            )
        if cfg.output.keyframe:
            writers["keyframe"] = stack.enter_context(
                KeyframeWriter(
                    shard_dir / "keyframe",
                    use_videos=cfg.output.keyframe_video,
                    augment_every=cfg.output.augment_every,
                    repo_id=f"{cfg.output.repo_id}_keyframe",
                    **common,
                )
            )
        # With render threads the env records episode k + 1 in a background thread while this thread writes
        # episode k (its frames render in the replay threads from a snapshot of the scene taken right after it was
        # recorded). Closed first on the way out: the recording thread stops before the writers finalize.
        recordings: Iterator[_Recording] = (
            _record(env, task, variation, spec, seed, replay, cfg.pregrasp_jitter_m) for seed in spec.seeds
        )
        if replay is not None:
            recordings = stack.enter_context(contextlib.closing(_ahead(recordings)))
        for rec in recordings:
            result.record_s += rec.seconds
            if rec.episode is None:
                result.dropped.append({"seed": rec.seed, "steps": rec.steps, "reason": rec.reason})
                if on_episode:
                    on_episode()
                continue
            ep = rec.episode
            heuristic, stats = _heuristic_vs_expert(ep)
            ep.provenance["heuristic_keyframes"] = heuristic
            for k, v in stats.items():
                result.heuristic[k] = result.heuristic.get(k, 0.0) + v

            # The frames in the order the writers will ask for them; those several writers ask for render once.
            order = [t for w in writers.values() for t in w.frame_indices(ep)]
            keep = shared_frames(writers.values(), ep)
            t1 = time.perf_counter()
            with RenderedFrames(
                ep, rig, keep=keep, order=order, replay=replay, snapshot=rec.snapshot
            ) as frames:
                for kind, writer in writers.items():
                    result.episodes[kind] = result.episodes.get(kind, 0) + writer.add_episode(ep, frames)
            result.write_s += time.perf_counter() - t1 - frames.waited
            result.render_s += frames.seconds
            result.rendered_frames += frames.count
            result.kept += 1
            result.keyframes += len(ep.keyframes)
            result.steps += len(ep) - 1
            if on_episode:
                on_episode()
        t2 = time.perf_counter()
    result.write_s += time.perf_counter() - t2  # finalize (flushes encoders, closes parquet)
    for kind, writer in writers.items():
        result.frames[kind] = writer.num_frames
    if result.kept == 0:  # an empty LeRobot dataset cannot be read or merged
        for kind in DATASETS:
            shutil.rmtree(shard_dir / kind, ignore_errors=True)
    files = shard_files(shard_dir, DATASETS)  # what a rerun checks before it reuses the shard
    result.total_s = time.perf_counter() - start_all
    # Written whole or not at all: a kill mid-write leaves no marker (the shard is redone), never a torn one.
    write_json_atomic(shard_dir / MARKER, {**asdict(result), "files": files})
    return result
