"""What a collection is asked to do and what it reports: the options of ``sigma-data collect``
(:class:`CollectConfig`), the unit of work (:class:`ShardSpec`), a shard's outcome (:class:`ShardResult`) and the
run's (:class:`CollectSummary`), and the names of the files a run leaves in ``output.dir``."""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from sigma_data.cameras import RenderOptions
from sigma_data.files import temporary_name
from sigma_data.output import OutputConfig
from sigma_data.record import check_pregrasp_jitter

# A shard's completion marker: its ShardResult and the files it wrote (written last, after the datasets).
MARKER = "shard.json"
DATASETS = ("dense", "keyframe")
# The run's record in output.dir: its data options (before the first shard) and, once merged, every ShardResult.
RECORD = "collect.json"
# collect.json while it is written (renamed to RECORD when complete; sigma_data/files.py).
RECORD_TMP = temporary_name(Path(RECORD)).name
# Options that change how a collection runs, not what it writes: a rerun may change them and still resume.
RUN_OPTIONS = frozenset(
    {"output.dir", "workers", "render_threads", "executor", "progress", "output.overwrite"}
)
# collect.json of a collection made before the output and render options were grouped (--output.*, --render.*)
# records them under their old flat names: old name -> today's.
OLD_OPTION_NAMES = {
    "output_dir": "output.dir",
    "repo_id": "output.repo_id",
    "dense": "output.dense",
    "keyframe": "output.keyframe",
    "dense_depth": "output.dense_depth",
    "dense_video": "output.dense_video",
    "keyframe_video": "output.keyframe_video",
    "augment_every": "output.augment_every",
    "overwrite": "output.overwrite",
    "cameras": "render.cameras",
    "height": "render.height",
    "width": "render.width",
    "fast_render": "render.fast",
    "max_depth": "render.max_depth",
}


def recorded_options(recorded: dict[str, str]) -> dict[str, str]:
    """The data options a ``collect.json`` records, under today's names (:data:`OLD_OPTION_NAMES` renamed)."""
    return {OLD_OPTION_NAMES.get(k, k): v for k, v in recorded.items()}


@dataclass
class CollectOutputConfig(OutputConfig):
    """Where and how ``sigma-data collect`` writes: ``<dir>/shards/<shard>/{dense,keyframe}``, the merged
    ``<dir>/{dense,keyframe}`` and ``<dir>/collect.json``."""

    # Where the shards and the merged datasets go.
    dir: Path = Path("outputs/sigma_data")
    # LeRobot repo_id prefix of the datasets (local only): <repo_id>_dense, <repo_id>_keyframe.
    repo_id: str = "local/sigma"


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
    # Where and how the datasets are written: shards and the merged datasets go to dir.
    output: CollectOutputConfig = field(default_factory=CollectOutputConfig)
    # The cameras to render, their image size, the fast exact settings and the depth clip.
    render: RenderOptions = field(default_factory=RenderOptions)
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
    # Radius (m) of a random horizontal offset given to each expert's approach waypoint (the pose above the object
    # before a grasp), uniform over the disc; the grasp that follows still goes to the object. 0: the experts'
    # own waypoints, where every grasp is straight below its approach. DART-style data (docs/learning.md): a policy
    # trained on it sees approaches that are off and the grasp that corrects them.
    pregrasp_jitter_m: float = 0.0
    # How shards run: "processes" (a process pool) or "datatrove" (DataTrove's local executor; optional extra).
    executor: str = "processes"
    # Show progress bars.
    progress: bool = True

    def __post_init__(self) -> None:
        if self.executor not in ("processes", "datatrove"):
            raise ValueError(f"--executor must be processes or datatrove, got {self.executor!r}")
        if self.render_threads < 0:
            raise ValueError(f"--render_threads must be >= 0, got {self.render_threads}")
        check_pregrasp_jitter(self.pregrasp_jitter_m)

    def data_options(self) -> dict[str, str]:
        """The options that decide what a collection writes (all but :data:`RUN_OPTIONS`), as recorded in
        ``collect.json``: by their command-line names (``render.height``, ``output.dense``...), values as text."""
        options: dict[str, Any] = {}
        for name, value in asdict(self).items():
            if isinstance(value, dict):  # a sub-config: --render.*, --output.*
                options.update({f"{name}.{sub}": v for sub, v in value.items()})
            else:
                options[name] = value
        return {k: str(v) for k, v in options.items() if k not in RUN_OPTIONS}

    def threads_per_worker(self) -> int:
        """Render threads of each worker process (``render_threads``, or the cores shared among the workers)."""
        if self.render_threads:
            return self.render_threads
        return max(1, len(os.sched_getaffinity(0)) // max(1, self.workers))

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
        return tuple(k for k in DATASETS if getattr(self.output, k))

    def fingerprint(self) -> str:
        """Hash of every option that changes a shard's data (not workers, paths or progress). Keyed by the options'
        names from before they were grouped under ``render`` and ``output``, so shards written then still match."""
        render, output = self.render, self.output
        options = {
            "cameras": render.cameras,
            "height": render.height,
            "width": render.width,
            "dense": output.dense,
            "keyframe": output.keyframe,
            "dense_depth": output.dense_depth,
            "dense_video": output.dense_video,
            "keyframe_video": output.keyframe_video,
            "augment_every": output.augment_every,
            "fast_render": render.fast,
            "max_depth": render.max_depth,
            "model_seed": self.model_seed,
        }
        if self.pregrasp_jitter_m:  # added later: shards collected without it keep their fingerprint
            options["pregrasp_jitter_m"] = self.pregrasp_jitter_m
        blob = json.dumps(options, sort_keys=True)
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
