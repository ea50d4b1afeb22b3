"""Write :class:`~sigma_data.episode.Episode` s into the two LeRobot v3 datasets of the data contract.

* :class:`DenseWriter`: every frame; ``action`` = the executed 7-D OSC delta; keyframe flag and episode-relative
  next-keyframe index in ``sigma.*`` columns stock policies ignore. Cameras as video by default (RGB AV1, depth
  12-bit log-quantised lossless HEVC over a tabletop range, streaming encoding).
* :class:`KeyframeWriter`: per episode the decision points (start frame, then each keyframe); frame i's
  ``action`` is frame i+1's 9-D pose ``[x, y, z, qx, qy, qz, qw, gripper_open, ignore_collision]`` (the last
  frame repeats its own), so the goal of frame i is frame i+1. Cameras as ``dtype="image"`` by default (exact
  float depth, fast random reads). Optional RVT-style augmentation chains (one extra episode starting at every
  N-th frame) with ``augment_every = N``. ``sigma.source_frame`` links each frame to the dense episode frame.

Writers take pixels lazily: :meth:`SigmaWriter.add_episode` gets a ``views(t)`` callable and asks only for
:meth:`SigmaWriter.frame_indices`, so the caller renders just the frames that are stored.
Both writers finalize LeRobot's writer on exit (use them as context managers; ``finalize()`` is idempotent)
and keep a provenance sidecar ``meta/sigma.json`` (LeRobot never rewrites it) with versions, conventions,
calibration notes and one record per written episode (task, variation, seed, keyframes, ...).
"""

from __future__ import annotations

import os
import shutil
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import asdict
from pathlib import Path
from typing import Any, Literal

import numpy as np

from sigma_data.contract import (
    ACTION,
    CONVENTIONS,
    DENSE_ACTION_NAMES,
    FPS,
    IS_KEYFRAME,
    KEYFRAME_ACTION_NAMES,
    NEXT_KEYFRAME_INDEX,
    ROBOT_TYPE,
    SIDECAR,
    SOURCE_FRAME,
    STATE,
    STATE_NAMES,
    goal_frame,
)
from sigma_data.dataset_layout import (
    DatasetLayout,
    DepthRange,
    StaticCalibration,
    camera_features,
    camera_frame_values,
    depth_encoder_config,
)
from sigma_data.episode import CameraViews, Episode
from sigma_data.files import write_json_atomic
from sigma_data.keyframes import keyframe_mask, next_keyframe_index

ViewsFn = Callable[[int], CameraViews]
# Frames a camera's video encoder may fall behind before the writer waits for it.
ENCODER_BACKLOG = 32


def versions() -> dict[str, str]:
    """Versions of sigma and the simulator / dataset stack."""
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for name, dist in (
        ("sigma", "lerobot_policy_sigma"),
        ("robosuite", "robosuite"),
        ("mujoco", "mujoco"),
        ("lerobot", "lerobot"),
    ):
        try:
            out[name] = version(dist)
        except PackageNotFoundError:
            out[name] = "unknown"
    return out


def quiet_video_encoders() -> None:
    """Keep the video encoders' chatter off the terminal; their errors and FFmpeg's warnings still show.

    SVT-AV1 (LeRobot's RGB codec) prints its whole configuration and remarks on LeRobot's preset for every video
    (about 25 lines each), and FFmpeg's mp4 muxer a line per file at info level -- over 180 lines for a
    2-episode dense collection. A ``SVT_LOG`` set by the user wins."""
    os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1 log levels: 0 fatal, 1 error, 2 warn, 3 info (default)
    import av.logging

    av.logging.set_libav_level(av.logging.WARNING)


def shared_frames(writers: Iterable[SigmaWriter], episode: Episode) -> set[int]:
    """Frames of ``episode`` that more than one of ``writers`` asks for (worth caching once rendered)."""
    needed = [set(w.frame_indices(episode)) for w in writers]
    return set.intersection(*needed) if len(needed) > 1 else set()


class SigmaWriter:
    """Base class: owns one LeRobot writer and the provenance sidecar. Use as a context manager.

    ``provenance`` is any JSON-able dataset-level record (controller, env kwargs, bounds, render settings...);
    versions and conventions are added. ``overwrite`` deletes an existing ``root`` first (LeRobot's ``create``
    refuses an existing directory).
    """

    kind: Literal["dense", "keyframe"]
    action_names: tuple[str, ...]

    def __init__(
        self,
        root: str | Path,
        layout: DatasetLayout,
        repo_id: str = "local/sigma",
        provenance: Mapping[str, Any] | None = None,
        static_calibration: StaticCalibration | None = None,
        use_videos: bool = False,
        streaming_encoding: bool = True,
        depth_range: DepthRange = DepthRange(),
        image_writer_threads: int = 0,
        overwrite: bool = False,
    ):
        from datasets import disable_progress_bars
        from lerobot.datasets.lerobot_dataset import LeRobotDataset

        # LeRobot maps every saved episode through `datasets`, which draws a "Map" bar each time; sigma's own
        # progress bars (per episode / shard) say the same thing once.
        disable_progress_bars()
        if use_videos:  # a keyframe dataset encodes no video: PyAV need not even be importable
            quiet_video_encoders()
        self.root = Path(root)
        self.layout = layout
        if self.root.exists():
            if not overwrite:
                raise FileExistsError(f"{self.root} already exists (pass overwrite=True to replace it)")
            shutil.rmtree(self.root)
        self.features = self.features_for(layout, "video" if use_videos else "image", static_calibration)
        self.dataset = LeRobotDataset.create(
            repo_id=repo_id,
            fps=FPS,
            features=self.features,
            root=self.root,
            robot_type=ROBOT_TYPE,
            use_videos=use_videos,
            streaming_encoding=streaming_encoding and use_videos,
            depth_encoder=depth_encoder_config(depth_range),
            image_writer_threads=image_writer_threads,
            video_backend="pyav",  # read-back decoder; torchcodec cannot load here (docs/data_contract.md §9)
            encoder_queue_maxsize=0,  # unbounded: see _wait_for_encoders
        )
        self.provenance: dict[str, Any] = {
            "kind": self.kind,
            **versions(),
            "fps": FPS,
            "cameras": list(layout.cameras),
            "image_size": [layout.height, layout.width],
            "depth": layout.depth,
            "storage": "video" if use_videos else "image",
            "depth_video_range_m": [depth_range.depth_min, depth_range.depth_max] if use_videos else None,
            "state_names": list(STATE_NAMES),
            "action_names": list(self.action_names),
            "conventions": CONVENTIONS,
            **dict(provenance or {}),
        }
        self.episodes: list[dict[str, Any]] = []
        self.num_frames = 0
        self._finalized = False

    # ---- to implement -------------------------------------------------------------------------------
    @classmethod
    def _extra_features(cls) -> dict[str, dict]:
        raise NotImplementedError

    def frame_indices(self, episode: Episode) -> list[int]:
        """Sorted frames of ``episode`` this writer will ask ``views`` for."""
        raise NotImplementedError

    def _write(self, episode: Episode, views: ViewsFn) -> None:
        raise NotImplementedError

    # ---- shared -------------------------------------------------------------------------------------
    @classmethod
    def features_for(
        cls, layout: DatasetLayout, dtype: str, static_calibration: StaticCalibration | None = None
    ) -> dict[str, dict]:
        """The LeRobot features of this dataset kind; cameras stored as ``dtype`` ("video" or "image")."""
        feats = camera_features(layout, dtype, static_calibration)
        feats[STATE] = {
            "dtype": "float32",
            "shape": (len(STATE_NAMES),),
            "names": list(STATE_NAMES),
        }
        feats[ACTION] = {
            "dtype": "float32",
            "shape": (len(cls.action_names),),
            "names": list(cls.action_names),
        }
        feats.update(cls._extra_features())
        return feats

    def add_episode(self, episode: Episode, views: ViewsFn) -> int:
        """Write ``episode`` (one or more LeRobot episodes); returns how many LeRobot episodes were added.

        A failure mid-episode discards the partial episode (nothing already saved is lost) and re-raises.
        """
        if self._finalized:
            raise RuntimeError(f"{self.root}: writer already finalized")
        before = len(self.episodes)
        try:
            self._write(episode, views)
        except BaseException:
            self.dataset.clear_episode_buffer()
            del self.episodes[before:]
            raise
        return len(self.episodes) - before

    def _add_frame(self, values: dict[str, Any], episode: Episode) -> None:
        self._wait_for_encoders()
        self.dataset.add_frame({**values, "task": episode.instruction})

    def _wait_for_encoders(self) -> None:
        """Back-pressure for LeRobot's streaming video encoder.

        Its per-camera frame queues drop a frame (a warning, and a video one frame shorter than its episode)
        when a queue stays full for 0.1 s, which happens when frames come faster than the encoders' share of
        the CPU. The queues are unbounded here (``encoder_queue_maxsize=0``) and this waits while any camera
        is ``ENCODER_BACKLOG`` frames behind, so nothing is dropped and memory stays bounded. An encoder thread
        that died ends the wait (LeRobot's ``add_frame`` then raises its error).
        """
        encoder = getattr(getattr(self.dataset, "writer", None), "_streaming_encoder", None)
        queues = getattr(encoder, "_frame_queues", None)
        if not queues:
            return
        threads = encoder._threads
        while any(q.qsize() >= ENCODER_BACKLOG and threads[k].is_alive() for k, q in queues.items()):
            time.sleep(0.002)

    def _save_episode(self, episode: Episode, frames: Sequence[int], **extra: Any) -> None:
        with fast_fingerprints():
            self.dataset.save_episode()
        self.num_frames += len(frames)
        self.episodes.append(
            {
                "episode_index": len(self.episodes),
                "task": episode.task,
                "variation": episode.variation,
                "instruction": episode.instruction,
                "seed": episode.seed,
                "length": len(frames),
                "source_length": len(episode),
                "keyframes": episode.keyframe_indices,
                "keyframe_sources": [k.source for k in episode.keyframes],
                **extra,
                **({"provenance": episode.provenance} if episode.provenance else {}),
            }
        )

    def write_sidecar(self) -> None:
        record = {**self.provenance, "num_episodes": len(self.episodes), "num_frames": self.num_frames}
        record["episodes"] = self.episodes
        write_json_atomic(self.root / SIDECAR, record, default=_json_default)

    def finalize(self) -> None:
        """Finalize LeRobot's writer (mandatory for a readable dataset) and write the sidecar. Idempotent."""
        if self._finalized:
            return
        self._finalized = True
        try:
            self.dataset.finalize()
        finally:
            self.write_sidecar()

    def __enter__(self) -> SigmaWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.finalize()


def _fast_fingerprint(dataset: Any) -> str:
    """A content hash of an in-memory ``datasets.Dataset``: xxh3 of its Arrow IPC stream, features and split."""
    import pyarrow as pa
    import xxhash

    table = dataset._data.table
    sink = pa.BufferOutputStream()
    with pa.ipc.new_stream(
        sink, table.schema
    ) as stream:  # IPC pads with zeros: bytes depend on the data only
        stream.write_table(table)
    hasher = xxhash.xxh3_64(sink.getvalue())
    hasher.update(repr((dataset._info.features, dataset._split, dataset._indices is None)).encode())
    return hasher.hexdigest()


@contextmanager
def fast_fingerprints() -> Iterator[None]:
    """Fingerprint in-memory Hugging Face datasets by hashing their Arrow bytes instead of pickling them.

    LeRobot's ``save_episode`` builds each episode with ``datasets.Dataset.from_dict``, whose constructor
    pickles every value (images included) with dill to hash it: a quarter of the time of saving a keyframe
    episode. Here the hash is xxh3 over the table's Arrow IPC bytes, so the fingerprint still depends on the
    contents alone (same episodes, same files: the collection's determinism test compares them). The data
    written are LeRobot's; only the fingerprint string in the Parquet metadata differs from stock LeRobot's.
    """
    import datasets.arrow_dataset as arrow_dataset

    original = arrow_dataset.generate_fingerprint
    arrow_dataset.generate_fingerprint = _fast_fingerprint
    try:
        yield
    finally:
        arrow_dataset.generate_fingerprint = original


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    if hasattr(obj, "__dataclass_fields__"):
        return asdict(obj)
    raise TypeError(f"not JSON-serialisable: {type(obj).__name__}")


class DenseWriter(SigmaWriter):
    """Every control step of every episode (video cameras by default)."""

    kind = "dense"
    action_names = DENSE_ACTION_NAMES

    def __init__(self, root: str | Path, layout: DatasetLayout, use_videos: bool = True, **kwargs: Any):
        super().__init__(root, layout, use_videos=use_videos, **kwargs)

    @classmethod
    def _extra_features(cls) -> dict[str, dict]:
        return {
            IS_KEYFRAME: {"dtype": "bool", "shape": (1,), "names": None},
            NEXT_KEYFRAME_INDEX: {"dtype": "int64", "shape": (1,), "names": None},
        }

    def frame_indices(self, episode: Episode) -> list[int]:
        return list(range(len(episode)))

    def _write(self, episode: Episode, views: ViewsFn) -> None:
        T = len(episode)
        is_kf = keyframe_mask(episode.keyframe_indices, T)
        nxt = next_keyframe_index(episode.keyframe_indices, T)
        for t in range(T):
            values = camera_frame_values(self.layout, views(t), f"{episode.name} frame {t}")
            values[STATE] = episode.states[t]
            values[ACTION] = episode.actions[t]
            values[IS_KEYFRAME] = np.array([is_kf[t]])
            values[NEXT_KEYFRAME_INDEX] = np.array([nxt[t]], dtype=np.int64)
            self._add_frame(values, episode)
        self._save_episode(episode, range(T))


class KeyframeWriter(SigmaWriter):
    """Decision points only (``dtype="image"`` cameras by default); optional augmentation chains.

    ``augment_every = N > 0`` adds, for every frame ``s = N, 2N, ...`` before the last keyframe, an extra
    episode ``[s, keyframes after s]`` (RVT's demo augmentation), recorded in the sidecar as ``chain_start``.
    """

    kind = "keyframe"
    action_names = KEYFRAME_ACTION_NAMES

    def __init__(
        self,
        root: str | Path,
        layout: DatasetLayout,
        use_videos: bool = False,
        augment_every: int = 0,
        **kwargs: Any,
    ):
        if augment_every < 0:
            raise ValueError(f"augment_every must be >= 0, got {augment_every}")
        self.augment_every = augment_every
        super().__init__(root, layout, use_videos=use_videos, **kwargs)
        self.provenance["augment_every"] = augment_every

    @classmethod
    def _extra_features(cls) -> dict[str, dict]:
        return {SOURCE_FRAME: {"dtype": "int64", "shape": (1,), "names": None}}

    def chain_starts(self, episode: Episode) -> list[int]:
        last = episode.keyframe_indices[-1]
        starts = [0]
        if self.augment_every:
            starts += list(range(self.augment_every, last, self.augment_every))
        return starts

    def frame_indices(self, episode: Episode) -> list[int]:
        return sorted({t for s in self.chain_starts(episode) for t in episode.decision_frames(s)})

    def _write(self, episode: Episode, views: ViewsFn) -> None:
        poses = episode.keyframe_poses()  # (K, 9)
        pose_of = dict(zip(episode.keyframe_indices, poses, strict=True))
        cache: dict[int, dict[str, np.ndarray]] = {}
        for start in self.chain_starts(episode):
            frames = episode.decision_frames(start)
            for i, t in enumerate(frames):
                if t not in cache:
                    cache[t] = camera_frame_values(self.layout, views(t), f"{episode.name} frame {t}")
                goal = frames[goal_frame(i, len(frames))]
                values = dict(cache[t])
                values[STATE] = episode.states[t]
                values[ACTION] = pose_of[goal]
                values[SOURCE_FRAME] = np.array([t], dtype=np.int64)
                self._add_frame(values, episode)
            self._save_episode(episode, frames, chain_start=start, source_frames=frames)
