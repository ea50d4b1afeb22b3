"""What a collection is asked to do and what it reports: the options of ``sigma-data collect``
(:class:`CollectConfig`), the unit of work (:class:`ShardSpec`), a shard's outcome (:class:`ShardResult`) and the
run's (:class:`CollectSummary`), and the names of the files a run leaves in ``output_dir``."""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from sigma_data.cameras import DEFAULT_CAMERAS, RenderConfig

# A shard's completion marker: its ShardResult and the files it wrote (written last, after the datasets).
MARKER = "shard.json"
DATASETS = ("dense", "keyframe")
# The run's record in output_dir: its data options (before the first shard) and, once merged, every ShardResult.
RECORD = "collect.json"
# Options that change how a collection runs, not what it writes: a rerun may change them and still resume.
RUN_OPTIONS = frozenset({"output_dir", "workers", "render_threads", "executor", "progress", "overwrite"})


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
    # Seeds per shard (the unit of resume: a finished shard whose files are intact is reused).
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
        from sigma_data.suite import TASKS

        if self.tasks.strip() == "all":
            return sorted(TASKS)
        names = list(dict.fromkeys(t.strip() for t in self.tasks.split(",") if t.strip()))
        if not names:
            raise ValueError("no task given (--tasks)")
        return names

    def datasets(self) -> tuple[str, ...]:
        """The datasets this collection writes, of :data:`DATASETS`."""
        return tuple(k for k, on in (("dense", self.dense), ("keyframe", self.keyframe)) if on)

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
    # Why this run redid a shard it found on disk (damaged, interrupted...); "" when reused or new.
    redone: str = ""


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
        redone = sum(bool(s.redone) for s in self.shards)
        parts = [f"collect: kept {self.kept}, dropped {self.dropped} episodes"]
        for kind in self.outputs:
            parts.append(f"{kind} {self.frames(kind)} frames")
        parts.append(f"{sum(s.keyframes for s in self.shards)} keyframes")
        reuse = f"{skipped} reused" + (f", {redone} redone" if redone else "")
        parts.append(f"{len(self.shards)} shards ({reuse})")
        parts.append(f"{self.wall_s:.1f} s")
        return ", ".join(parts) + " -> " + ", ".join(str(p) for p in self.outputs.values())
