"""Collect scripted-expert demonstrations into the dense and keyframe LeRobot datasets.

Per episode: reset (``reset_env``, deterministic in the seed), record the expert **without rendering**
(:class:`~sigma_data.record.EpisodeRecorder` stores the flattened sim state every control step), drop and count
the episode if the expert gives up or the task's success check fails, else replay the stored states and render
**only the frames that are written** (every frame for the dense dataset, the decision points for the keyframe
dataset; a frame both need is rendered once).

A worker with more than one core (``render_threads`` >= 2; by default the cores divided among the workers)
overlaps three things: the env records episode k + 1 in a background thread, the frames of episode k render
ahead of the writers in ``render_threads`` threads with their own GL contexts (:mod:`sigma_data.replay_render`,
bit-identical to rendering them one by one), and the writers write them (LeRobot's video encoders run in threads
of their own). A worker with one core does them in turn.

Scale and robustness:

* Work is cut into shards of seeds (``shard_size`` seeds of one task variation). Each shard is written by one
  worker process into ``<output_dir>/shards/<name>/{dense,keyframe}`` and ends with a ``shard.json`` marker;
  the shards are then merged with LeRobot's ``aggregate_datasets`` into ``<output_dir>/{dense,keyframe}`` (a
  single shard is copied). A process builds one env per task and reuses it for all its shards.
* Rerunning skips shards whose marker matches the configuration and whose datasets load with the recorded
  episode counts; anything else (an interrupted shard) is deleted and redone. The merge is redone every run.
* Same configuration and seeds give identical data: the model (e.g. Lift's random cube size, drawn when the
  env is built) is built under ``model_seed``, every episode under its own seed.
* ``executor = "datatrove"`` runs the same shards through DataTrove's ``LocalPipelineExecutor``
  (:mod:`sigma_data.cluster`; on a Slurm cluster its step runs under ``SlurmPipelineExecutor``, see
  ``docs/cluster.md``); it needs the optional extra ``cluster`` (``datatrove``).
"""

from __future__ import annotations

import atexit
import contextlib
import dataclasses
import hashlib
import json
import multiprocessing as mp
import os
import queue
import shutil
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sigma_data.cameras import DEFAULT_CAMERAS, CameraRig, RenderConfig
from sigma_data.episode import Episode
from sigma_data.keyframes import compare_keyframes, discover_keyframes
from sigma_data.replay_render import RenderedFrames, ReplayRenderer, SceneSnapshot
from sigma_data.writers import SIDECAR, DatasetLayout, DenseWriter, KeyframeWriter, SigmaWriter, shared_frames

MARKER = "shard.json"
DATASETS = ("dense", "keyframe")


@dataclass
class CollectConfig:
    """Options of ``sigma-data collect``."""

    # Registry task names, comma-separated, or "all".
    tasks: str = "lift"
    # Variation names (of the chosen tasks), comma-separated, or "all".
    variations: str = "all"
    # Seeds tried per variation (failed episodes are dropped and counted, not replaced).
    episodes: int = 10
    # First seed; variation v uses seeds start_seed .. start_seed + episodes - 1.
    start_seed: int = 0
    # Where shards and the merged datasets go.
    output_dir: Path = Path("outputs/sigma_data")
    # LeRobot repo_id prefix of the merged datasets (local only): <repo_id>_dense, <repo_id>_keyframe.
    repo_id: str = "local/sigma"
    # Cameras, comma-separated.
    cameras: str = ",".join(DEFAULT_CAMERAS)
    # Image height in pixels (every camera).
    height: int = 128
    # Image width in pixels (every camera).
    width: int = 128
    # Write the dense dataset (every control step).
    dense: bool = True
    # Write the keyframe dataset (decision points; action = next keyframe pose).
    keyframe: bool = True
    # Store depth in the dense dataset. false: RGB-only dense dataset that stock LeRobot image policies (ACT,
    # Diffusion Policy) train on as it is (the keyframe dataset always keeps depth).
    dense_depth: bool = True
    # Dense camera storage: video (RGB AV1, depth 12-bit lossless HEVC) or PNG/TIFF images.
    dense_video: bool = True
    # Keyframe camera storage: PNG/TIFF images by default (exact depth) or video.
    keyframe_video: bool = False
    # RVT-style augmentation chains in the keyframe dataset: an extra episode from every N-th frame (0 = off).
    augment_every: int = 0
    # Render with the fast settings (MSAA/reflections/skybox off: exact depth, ~3x faster).
    fast_render: bool = True
    # Depth is clipped to this many metres (background pixels hit the far plane, hundreds of metres away).
    max_depth: float = 3.0
    # Worker processes (each writes its own shards).
    workers: int = 1
    # Render threads per worker process. With 2 or more, the env records the next episode while this one's frames
    # render ahead of the writers in that many threads (same images); 1 renders each frame in the writing thread
    # when it is asked for, one episode at a time; 0 = the CPU cores available divided among the workers.
    render_threads: int = 0
    # Seeds per shard (the unit of resume: a finished shard that validates is reused).
    shard_size: int = 10
    # Seed of the random model parameters drawn when an env is built (e.g. Lift's cube size).
    model_seed: int = 0
    # How shards run: "processes" (a process pool) or "datatrove" (DataTrove's local executor; optional extra).
    executor: str = "processes"
    # Show progress bars.
    progress: bool = True
    # Replace what output_dir holds when it was not written by a collection with these options (another
    # configuration, another tool, or files of your own). Without it such a directory is an error, never touched.
    overwrite: bool = False

    def __post_init__(self) -> None:
        if self.executor not in ("processes", "datatrove"):
            raise ValueError(f"--executor must be processes or datatrove, got {self.executor!r}")
        if self.render_threads < 0:
            raise ValueError(f"--render_threads must be >= 0, got {self.render_threads}")

    def data_options(self) -> dict[str, str]:
        """The options that decide what a collection writes (all but :data:`RUN_OPTIONS`), as recorded in
        ``collect.json``."""
        return {k: str(v) for k, v in asdict(self).items() if k not in RUN_OPTIONS}

    def threads_per_worker(self) -> int:
        """Render threads of each worker process (``render_threads``, or the cores shared among the workers)."""
        if self.render_threads:
            return self.render_threads
        return max(1, len(os.sched_getaffinity(0)) // max(1, self.workers))

    def camera_list(self) -> tuple[str, ...]:
        cams = tuple(c.strip() for c in self.cameras.split(",") if c.strip())
        if not cams:
            raise ValueError("no cameras given (--cameras)")
        return cams

    def task_names(self) -> list[str]:
        from sigma_data.tasks import TASKS

        if self.tasks.strip() == "all":
            return sorted(TASKS)
        names = list(dict.fromkeys(t.strip() for t in self.tasks.split(",") if t.strip()))
        if not names:
            raise ValueError("no task given (--tasks)")
        return names

    def render_config(self) -> RenderConfig:
        return RenderConfig(self.camera_list(), self.height, self.width, self.fast_render, self.max_depth)

    def fingerprint(self) -> str:
        """Hash of every option that changes the data (not workers, paths or progress)."""
        keys = [
            "cameras",
            "height",
            "width",
            "dense",
            "keyframe",
            "dense_depth",
            "dense_video",
            "keyframe_video",
            "augment_every",
            "fast_render",
            "max_depth",
            "model_seed",
        ]
        blob = json.dumps({k: getattr(self, k) for k in keys}, sort_keys=True)
        return hashlib.sha256(blob.encode()).hexdigest()[:16]


@dataclass(frozen=True)
class ShardSpec:
    """One unit of work: seeds of one task variation."""

    task: str
    variation: str
    seeds: tuple[int, ...]

    @property
    def name(self) -> str:
        return f"{self.task}-{self.variation}-{self.seeds[0]:06d}-{self.seeds[-1]:06d}"


@dataclass
class ShardResult:
    """What a shard produced, with timings in seconds (render = replay + render, summed over the render threads;
    write = the writers' time minus their waits for frames)."""

    name: str
    kept: int = 0
    dropped: list[dict[str, Any]] = field(default_factory=list)
    frames: dict[str, int] = field(default_factory=dict)  # dataset -> frames written
    episodes: dict[str, int] = field(default_factory=dict)  # dataset -> LeRobot episodes written
    keyframes: int = 0  # expert keyframes of the kept episodes
    steps: int = 0  # recorded control steps of the kept episodes
    rendered_frames: int = 0
    record_s: float = 0.0
    render_s: float = 0.0
    write_s: float = 0.0
    total_s: float = 0.0
    heuristic: dict[str, float] = field(default_factory=dict)  # heuristic vs expert keyframes (sums)
    skipped: bool = False
    fingerprint: str = ""


@dataclass
class CollectSummary:
    shards: list[ShardResult]
    outputs: dict[str, Path]
    wall_s: float

    @property
    def kept(self) -> int:
        return sum(s.kept for s in self.shards)

    @property
    def dropped(self) -> int:
        return sum(len(s.dropped) for s in self.shards)

    def frames(self, kind: str) -> int:
        return sum(s.frames.get(kind, 0) for s in self.shards)

    def line(self) -> str:
        skipped = sum(s.skipped for s in self.shards)
        parts = [f"collect: kept {self.kept}, dropped {self.dropped} episodes"]
        for kind in self.outputs:
            parts.append(f"{kind} {self.frames(kind)} frames")
        parts.append(f"{sum(s.keyframes for s in self.shards)} keyframes")
        parts.append(f"{len(self.shards)} shards ({skipped} reused)")
        parts.append(f"{self.wall_s:.1f} s")
        return ", ".join(parts) + " -> " + ", ".join(str(p) for p in self.outputs.values())


# --------------------------------------------------------------------------------------------------
# Planning
# --------------------------------------------------------------------------------------------------


def plan_shards(cfg: CollectConfig) -> list[ShardSpec]:
    """Shards of the run, in a fixed order (task, variation, seed). Raises ``ValueError`` on bad names."""
    from sigma_data.tasks import get_task

    if cfg.episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {cfg.episodes}")
    if cfg.shard_size < 1 or cfg.workers < 1:
        raise ValueError(f"shard_size and workers must be >= 1, got {cfg.shard_size}, {cfg.workers}")
    if not (cfg.dense or cfg.keyframe):
        raise ValueError("nothing to write: enable --dense and/or --keyframe")
    names = cfg.task_names()
    tasks = [get_task(n) for n in names]
    wanted = (
        None
        if cfg.variations.strip() == "all"
        else {v.strip() for v in cfg.variations.split(",") if v.strip()}
    )
    if wanted is not None:
        known = {v.name for t in tasks for v in t.variations}
        unknown = sorted(wanted - known)
        if unknown:
            raise ValueError(
                f"unknown variation(s) {unknown} for tasks {names}; known: {', '.join(sorted(known))}"
            )
    seeds = list(range(cfg.start_seed, cfg.start_seed + cfg.episodes))
    shards = []
    for task in tasks:
        for var in task.variations:
            if wanted is not None and var.name not in wanted:
                continue
            for i in range(0, len(seeds), cfg.shard_size):
                shards.append(ShardSpec(task.name, var.name, tuple(seeds[i : i + cfg.shard_size])))
    return shards


def build_env(task: Any, render: RenderConfig, model_seed: int) -> Any:
    """``make_env`` with the random model parameters drawn under ``model_seed`` (global RNG restored)."""
    from sigma_data.tasks import make_env

    return make_env(
        task, cameras=render.cameras, height=render.height, width=render.width, model_seed=model_seed
    )


# Envs built in this process, by (task, render settings, model seed). Building a robosuite env compiles its
# model (~1.5 s); every shard of a task in one process reuses it. ``reset_env`` makes each episode depend on its
# seed only, not on what the env ran before (the resume test compares a reused env with a fresh one).
_ENVS: dict[tuple[str, RenderConfig, int], Any] = {}


def cached_env(task_name: str, render: RenderConfig, model_seed: int) -> Any:
    """This process's env for ``task_name`` (built on first use; :func:`close_envs` closes them all)."""
    from sigma_data.tasks import get_task

    key = (task_name, render, model_seed)
    if key not in _ENVS:
        if not _ENVS:
            atexit.register(close_envs)  # spawned workers exit through sys.exit: close GL contexts first
        _ENVS[key] = build_env(get_task(task_name), render, model_seed)
    return _ENVS[key]


_REPLAYS: dict[tuple[int, int], ReplayRenderer] = {}


def cached_replay(rig: CameraRig, threads: int) -> ReplayRenderer:
    """This process's render threads for ``rig``'s env (closed by :func:`close_envs`, before the envs)."""
    key = (id(rig.env), threads)
    if key not in _REPLAYS:
        _REPLAYS[key] = ReplayRenderer(rig, threads)
    return _REPLAYS[key]


def close_envs() -> None:
    """Close and forget every env :func:`cached_env` built in this process (and their render threads)."""
    while _REPLAYS:
        _, replay = _REPLAYS.popitem()
        with contextlib.suppress(Exception):
            replay.close()
    while _ENVS:
        _, env = _ENVS.popitem()
        with contextlib.suppress(Exception):
            env.close()


def check_cameras_exist(cfg: CollectConfig, task_names: list[str], reuse: bool) -> None:
    """Raise ``ValueError`` naming the first task whose scene lacks a requested camera, before any shard runs
    (or, for worker processes, while they start). With ``reuse`` the envs the shards of this process will use
    are built now (nothing extra); otherwise a throwaway env without a renderer is built per task."""
    from sigma_data.tasks import get_task

    for task_name in task_names:
        if reuse:
            env = cached_env(task_name, cfg.render_config(), cfg.model_seed)
            known = set(env.sim.model.camera_names)
        else:
            env = build_env(get_task(task_name), RenderConfig(cameras=()), cfg.model_seed)  # no renderer
            try:
                known = set(env.sim.model.camera_names)
            finally:
                env.close()
        unknown = [c for c in cfg.camera_list() if c not in known]
        if unknown:
            raise ValueError(
                f"unknown camera(s) {unknown} for task '{task_name}'; known: {', '.join(sorted(known))}"
            )


# --------------------------------------------------------------------------------------------------
# One shard
# --------------------------------------------------------------------------------------------------


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
    from sigma_data.tasks import get_task
    from sigma_data.tasks.registry import CONTROL_FREQ, CONTROLLER, ROBOT

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
        "render": asdict(cfg.render_config()),
        "model_seed": cfg.model_seed,
        "fingerprint": cfg.fingerprint(),
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
    env: Any, task: Any, variation: Any, spec: ShardSpec, seed: int, replay: ReplayRenderer | None
) -> _Recording:
    """Reset ``env`` to ``seed``, run the expert without rendering and check success (and, for ``replay``, take
    the snapshot of the scene its frames render from)."""
    from sigma_data.experts.base import ExpertFailure
    from sigma_data.record import EpisodeRecorder
    from sigma_data.tasks import reset_env

    start = time.perf_counter()
    reset_env(env, task, variation, seed)
    recorder = EpisodeRecorder(env)
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
    """Record, filter, render and write one shard into ``shard_dir`` (replaced if present); writes the marker."""
    from sigma_data.tasks import get_task, get_variation

    start_all = time.perf_counter()
    if shard_dir.exists():
        shutil.rmtree(shard_dir)
    shard_dir.mkdir(parents=True)
    task = get_task(spec.task)
    variation = get_variation(task, spec.variation)
    render = cfg.render_config()
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
        if cfg.dense:
            writers["dense"] = stack.enter_context(
                DenseWriter(
                    shard_dir / "dense",
                    use_videos=cfg.dense_video,
                    repo_id=f"{cfg.repo_id}_dense",
                    **(common | {"layout": dataclasses.replace(layout, depth=cfg.dense_depth)}),
                )
            )
        if cfg.keyframe:
            writers["keyframe"] = stack.enter_context(
                KeyframeWriter(
                    shard_dir / "keyframe",
                    use_videos=cfg.keyframe_video,
                    augment_every=cfg.augment_every,
                    repo_id=f"{cfg.repo_id}_keyframe",
                    **common,
                )
            )
        # With render threads the env records episode k + 1 in a background thread while this thread writes
        # episode k (its frames render in the replay threads from a snapshot of the scene taken right after it was
        # recorded). Closed first on the way out: the recording thread stops before the writers finalize.
        recordings: Iterator[_Recording] = (
            _record(env, task, variation, spec, seed, replay) for seed in spec.seeds
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
    result.total_s = time.perf_counter() - start_all
    (shard_dir / MARKER).write_text(json.dumps(asdict(result), indent=1))
    return result


def _static_json(rig: CameraRig) -> dict[str, Any]:
    return {
        cam: {"intrinsics": K.tolist(), "extrinsics": E.tolist()}
        for cam, (K, E) in rig.static_calibration().items()
    }


def finished_shard(shard_dir: Path, cfg: CollectConfig) -> ShardResult | None:
    """The stored result if ``shard_dir`` is complete and matches ``cfg``; None if it must be (re)done."""
    marker = shard_dir / MARKER
    # Checked before importing LeRobot (~5 s), so a fresh run starts its helpers without waiting for it.
    if not marker.exists():
        return None
    from lerobot.datasets.dataset_metadata import LeRobotDatasetMetadata

    try:
        result = ShardResult(**json.loads(marker.read_text()))
    except (json.JSONDecodeError, TypeError):
        return None
    if result.fingerprint != cfg.fingerprint():
        return None
    for kind in (k for k, on in (("dense", cfg.dense), ("keyframe", cfg.keyframe)) if on):
        expected = result.episodes.get(kind, 0)
        root = shard_dir / kind
        if expected == 0:
            continue
        try:
            meta = LeRobotDatasetMetadata(f"{cfg.repo_id}_{kind}", root=root)
        except Exception:
            return None
        if meta.total_episodes != expected or not (root / SIDECAR).exists():
            return None
    result.skipped = True
    return result


# --------------------------------------------------------------------------------------------------
# Runs
# --------------------------------------------------------------------------------------------------


def _worker(spec: ShardSpec, cfg: CollectConfig, shard_dir: Path, progress: Any) -> ShardResult:
    import sigma_data  # noqa: F401  (headless GL before robosuite in a fresh process)

    return collect_shard(spec, cfg, shard_dir, on_episode=(lambda: progress.put(1)) if progress else None)


def _warm_up(task_name: str, render: RenderConfig, model_seed: int) -> None:
    """A helper's first act: the imports and the env its first shard needs (seconds that would otherwise be
    spent inside that shard). A failure here is left for the shard itself to report."""
    import sigma_data  # noqa: F401  (headless GL before robosuite in a fresh process)

    with contextlib.suppress(Exception):
        import lerobot.datasets.lerobot_dataset  # noqa: F401  (~5 s: LeRobot imports transformers, torchvision)

        cached_env(task_name, render, model_seed)


class Helpers:
    """``n`` spawned helper processes for a run, started as soon as the run knows it has work for them, so
    their start-up (interpreter, imports, env: ~8 s) overlaps this process's own; they exit while this process
    merges the shards. Spawned, not forked: no inherited GL contexts or MuJoCo state."""

    def __init__(self, n: int, cfg: CollectConfig, first_task: str) -> None:
        ctx = mp.get_context("spawn")
        self.manager = ctx.Manager()
        self.progress = self.manager.Queue()
        self.pool = ProcessPoolExecutor(
            max_workers=n,
            mp_context=ctx,
            initializer=_warm_up,
            initargs=(first_task, cfg.render_config(), cfg.model_seed),
        )
        self.n = n
        # One trivial job per helper: the pool spawns its processes now, not at the first shard.
        for _ in range(n):
            self.pool.submit(int)

    def release(self) -> None:
        """No more shards: the helpers exit in the background (call :meth:`close` later to reap them)."""
        self.pool.shutdown(wait=False, cancel_futures=True)

    def close(self) -> None:
        self.pool.shutdown(wait=True, cancel_futures=True)
        self.manager.shutdown()


def _run_processes(
    todo: list[ShardSpec], cfg: CollectConfig, shards_dir: Path, pbar: Any, helpers: Helpers | None
) -> list[ShardResult]:
    """Collect ``todo`` with this process and the spawned ``helpers``.

    Shards are handed out one at a time: each helper gets the next one from the front of the queue when it is
    free (a feeder thread per helper), while this process starts at once and takes shards from the back. A
    shard that raises stops the hand-out and the error is re-raised; finished shards stay for a rerun.
    """
    tasks = list(dict.fromkeys(s.task for s in todo))

    def run_here(spec: ShardSpec, after_episode: Callable[[], None]) -> ShardResult:
        return collect_shard(spec, cfg, shards_dir / spec.name, on_episode=after_episode)

    if helpers is None:
        check_cameras_exist(cfg, tasks, reuse=True)  # this process's envs, built once per task
        return [run_here(s, lambda: pbar.update(1)) for s in todo]

    pending = deque(todo)
    lock = threading.Lock()
    results: dict[str, ShardResult] = {}
    errors: list[BaseException] = []
    pool, progress = helpers.pool, helpers.progress

    def feed() -> None:  # keeps one helper busy until the queue is empty or a shard failed
        while True:
            with lock:
                if errors or not pending:
                    return
                spec = pending.popleft()
            try:
                results[spec.name] = pool.submit(
                    _worker, spec, cfg, shards_dir / spec.name, progress
                ).result()
            except BaseException as exc:
                with lock:
                    errors.append(exc)
                return

    def tick() -> None:  # progress of every process; stop on a helper's error
        pbar.update(1)
        with contextlib.suppress(queue.Empty):
            while True:
                pbar.update(progress.get_nowait())
        if errors:
            raise errors[0]

    feeders = [threading.Thread(target=feed, daemon=True) for _ in range(helpers.n)]
    for t in feeders:
        t.start()
    try:
        check_cameras_exist(cfg, tasks, reuse=True)  # while the helpers start (seconds of imports)
        while True:
            with lock:
                if errors or not pending:
                    break
                spec = pending.pop()
            results[spec.name] = run_here(spec, tick)
        while any(t.is_alive() for t in feeders):
            with contextlib.suppress(queue.Empty):
                pbar.update(progress.get(timeout=0.2))
        if errors:
            raise errors[0]
    except BaseException:
        with lock:
            pending.clear()  # helpers finish their current shard and stop
        raise
    with contextlib.suppress(queue.Empty):
        while True:
            pbar.update(progress.get_nowait())
    return [results[s.name] for s in todo]


def _run_datatrove(todo: list[ShardSpec], cfg: CollectConfig) -> list[ShardResult]:
    try:
        from sigma_data.cluster import run_local
    except ImportError as exc:
        raise ImportError(
            "executor='datatrove' needs the optional dependency datatrove: pip install -e '.[cluster]' "
            f"(or 'datatrove>=0.4,<1'); {exc}"
        ) from exc
    return run_local(todo, cfg)


@contextlib.contextmanager
def _typed_parquet_writes(features: dict[str, dict]):
    """Work around LeRobot 0.6.1's ``aggregate_datasets`` on datasets without image features: it rebuilds the
    data parquet with ``pa.Table.from_pandas(df)`` and no schema, which fails on 2-D features such as the
    (3, 3) intrinsics ("Did not pass numpy.dtype object"). Within this context the same writer is given the
    datasets' own HF schema (used with ``concatenate_data=False``: its append path re-reads files untyped). Only the module attribute that function looks up is swapped, and restored."""
    import datasets
    from lerobot.datasets import aggregate
    from lerobot.datasets.feature_utils import get_hf_features_from_features
    from lerobot.datasets.io_utils import write_table_one_row_group_per_episode

    hf_features = get_hf_features_from_features(features)
    original = aggregate.to_parquet_one_row_group_per_episode

    def typed(df, path):
        ds = datasets.Dataset.from_dict(df.to_dict(orient="list"), features=hf_features)
        table = ds.with_format("arrow")[:]
        write_table_one_row_group_per_episode(table, path)

    aggregate.to_parquet_one_row_group_per_episode = typed
    try:
        yield
    finally:
        aggregate.to_parquet_one_row_group_per_episode = original


@contextlib.contextmanager
def _datasets_bars_stay_off():
    """``datasets``' per-file bars ("Generating train split", "Map") off for the whole merge. LeRobot 0.6.1 wraps
    its metadata reads in ``SuppressProgressBars``, whose exit turns the bars back *on* instead of restoring what
    was set, so a merge of n shards printed ~4n bars. Only that exit is swapped, and restored."""
    from datasets import disable_progress_bars
    from lerobot.utils.utils import SuppressProgressBars

    disable_progress_bars()
    original = SuppressProgressBars.__exit__
    SuppressProgressBars.__exit__ = lambda self, *exc: None
    try:
        yield
    finally:
        SuppressProgressBars.__exit__ = original


def merge_shards(kind: str, shard_roots: list[Path], out: Path, repo_id: str) -> None:
    """Merge shard datasets of one kind with LeRobot's ``aggregate_datasets`` and merge their sidecars."""
    from lerobot.datasets.aggregate import aggregate_datasets
    from lerobot.datasets.io_utils import load_info

    # Merge next to the target and swap it in when complete: a kill or a full disk mid-merge leaves the previous
    # dataset (or none) at ``out``, never a partial one that LeRobot would read as a dataset.
    final, out = out, out.with_name(f".{out.name}.merging")
    if out.exists():
        shutil.rmtree(out)
    if len(shard_roots) == 1:  # already the merged dataset: LeRobot's merge would rewrite the same files
        shutil.copytree(shard_roots[0], out)
    else:
        features = load_info(shard_roots[0]).features  # shapes as tuples, as LeRobot's metadata gives them
        # LeRobot's own "Copy data and videos" bar stays (one for the merge); the per-file bars go.
        with _typed_parquet_writes(features), _datasets_bars_stay_off():
            aggregate_datasets(
                repo_ids=[repo_id] * len(shard_roots),
                aggr_repo_id=repo_id,
                roots=shard_roots,
                aggr_root=out,
                concatenate_data=False,  # one data file per shard: LeRobot's append path re-reads untyped
            )
    sidecars = [json.loads((r / SIDECAR).read_text()) for r in shard_roots]
    merged = {k: v for k, v in sidecars[0].items() if k not in ("episodes", "num_episodes", "num_frames")}
    merged["env_kwargs"], merged["bounds"], merged["env_name"], merged["static_calibration"] = {}, {}, {}, {}
    episodes = []
    for root, side in zip(shard_roots, sidecars, strict=True):
        task = side["episodes"][0]["task"] if side["episodes"] else None
        for key in ("env_kwargs", "bounds", "env_name"):
            merged[key].update(side.get(key, {}))
        if task is not None:
            merged["static_calibration"][task] = side.get("static_calibration", {})
        for ep in side["episodes"]:
            episodes.append({**ep, "episode_index": len(episodes), "shard": root.parent.name})
    merged["episodes"] = episodes
    merged["num_episodes"] = len(episodes)
    merged["num_frames"] = sum(e["length"] for e in episodes)
    (out / SIDECAR).write_text(json.dumps(merged, indent=1))
    old = final.with_name(f".{final.name}.replaced")
    if old.exists():
        shutil.rmtree(old)
    if final.exists():
        final.rename(old)
    out.rename(final)
    shutil.rmtree(old, ignore_errors=True)


# Options that change how a collection runs, not what it writes: a rerun may change them and still resume.
RUN_OPTIONS = frozenset({"output_dir", "workers", "render_threads", "executor", "progress", "overwrite"})
RECORD = "collect.json"


def claim_output_dir(cfg: CollectConfig) -> None:
    """Make sure ``output_dir`` holds nothing but this collection (or a resumable run of it), then record the
    options in ``collect.json`` before any shard is written. Anything else there raises ``FileExistsError``
    (``--overwrite=true`` replaces it): a directory of someone else's files, datasets from another tool, or a
    collection made with other options (other tasks, seeds, image size...)."""
    out = Path(cfg.output_dir)
    record = out / RECORD
    mine = cfg.data_options()
    present = sorted(p.name for p in out.iterdir()) if out.is_dir() else []
    if present and not cfg.overwrite:
        hint = "pass --overwrite=true to replace it, or choose another --output_dir"
        if RECORD not in present:
            raise FileExistsError(
                f"{out} is not empty ({', '.join(present[:5])}) and holds no {RECORD}: {hint}"
            )
        previous = json.loads(record.read_text()).get("config", {})
        defaults = CollectConfig().data_options()  # options added since that run
        differ = [k for k in mine if previous.get(k, defaults[k]) != mine[k]]
        if differ:
            changes = ", ".join(f"{k} {previous.get(k, defaults[k])} -> {mine[k]}" for k in differ)
            raise FileExistsError(f"{out} holds a collection made with other options ({changes}): {hint}")
    if present and cfg.overwrite:
        for name in ("dense", "keyframe", "shards", RECORD):
            path = out / name
            if path.is_dir():
                shutil.rmtree(path)
            elif path.exists():
                path.unlink()
    out.mkdir(parents=True, exist_ok=True)
    if not record.exists():
        record.write_text(json.dumps({"config": mine, "shards": []}, indent=1))


def collect(cfg: CollectConfig) -> CollectSummary:
    """Run (or resume) a collection and merge the shards. Returns per-shard results and output roots."""
    from tqdm import tqdm

    start = time.perf_counter()
    shards = plan_shards(cfg)
    out = Path(cfg.output_dir)
    shards_dir = out / "shards"
    claim_output_dir(cfg)

    done: dict[str, ShardResult] = {}
    for spec in shards:
        prev = finished_shard(shards_dir / spec.name, cfg)
        if prev is not None:
            done[spec.name] = prev
    todo = [s for s in shards if s.name not in done]
    total = sum(len(s.seeds) for s in todo)
    n_helpers = min(cfg.workers, len(todo)) - 1 if cfg.executor != "datatrove" else 0
    helpers = Helpers(n_helpers, cfg, todo[0].task) if n_helpers > 0 else None
    try:  # the helpers are reaped on every way out; after an error a helper first finishes its current shard
        try:
            if todo and cfg.executor == "datatrove":
                check_cameras_exist(cfg, list(dict.fromkeys(s.task for s in todo)), reuse=False)
            shards_dir.mkdir(parents=True, exist_ok=True)
            with tqdm(total=total, desc="episodes", unit="ep", disable=not cfg.progress) as pbar:
                if cfg.executor == "datatrove":
                    results = _run_datatrove(todo, cfg) if todo else []
                    pbar.update(total)
                else:
                    results = _run_processes(todo, cfg, shards_dir, pbar, helpers) if todo else []
        finally:
            close_envs()
        if helpers is not None:
            helpers.release()  # they exit while the shards are merged
        for r in results:
            done[r.name] = r
        ordered = [done[s.name] for s in shards]

        outputs: dict[str, Path] = {}
        for kind in (k for k, on in (("dense", cfg.dense), ("keyframe", cfg.keyframe)) if on):
            roots = [shards_dir / r.name / kind for r in ordered if r.episodes.get(kind, 0) > 0]
            target = out / kind
            if not roots:
                shutil.rmtree(target, ignore_errors=True)
                continue
            merge_shards(kind, roots, target, f"{cfg.repo_id}_{kind}")
            outputs[kind] = target
    finally:
        if helpers is not None:
            helpers.close()
    summary = CollectSummary(ordered, outputs, time.perf_counter() - start)
    tmp = out / f".{RECORD}.tmp"
    tmp.write_text(
        json.dumps({"config": cfg.data_options(), "shards": [asdict(s) for s in ordered]}, indent=1)
    )
    tmp.replace(out / RECORD)
    return summary
