"""Import demonstrations from other sources into the sigma dense and keyframe datasets.

Every importer turns its source into :class:`~sigma_data.episode.Episode` s and hands them, with a way to get
each frame's camera views, to one :class:`DatasetSink`; so every source produces the same two LeRobot datasets
through the same writers as the scripted-expert collector:

* :mod:`sigma_data.importers.hdf5` -- robosuite ``demo.hdf5`` and robomimic HDF5 files, by state replay;
* :mod:`sigma_data.importers.raw` -- raw real-robot episodes in sigma's documented directory format;
* :mod:`sigma_data.importers.teleop` -- live teleoperation (uses the same sink).

Bad input in one episode (a missing field, NaN states, a missing image, ...) raises :class:`SourceError`
naming the file, the episode and the field; the importer records it as a failure and goes on with the next
episode. Episodes written before stay written: the writers finalize in ``finally``, and a failure inside a
writer discards only the partial episode. The run ends with :class:`ImportSummary` (one summary line, and
``<output.dir>/import.json`` with every failure and each dataset's episode count).

A failure to *write* (disk full, read-only directory) is not the source's fault and would repeat for every later
episode: :meth:`DatasetSink.add` raises :class:`OutputError`, the importers stop, and the report says what each
dataset holds; a dataset left without any episode (LeRobot cannot read one) is removed.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sigma_data.dataset_layout import DatasetLayout, StaticCalibration
from sigma_data.episode import CameraViews, Episode
from sigma_data.output import OutputConfig
from sigma_data.writers import DenseWriter, KeyframeWriter, SigmaWriter, shared_frames

REPORT = "import.json"


class SourceError(ValueError):
    """Bad input: names the file, the episode (demo) and the field at fault."""

    def __init__(self, path: str | Path, episode: str | None, field: str | None, problem: str):
        self.path, self.episode, self.field, self.problem = str(path), episode, field, problem
        where = [self.path]
        if episode:
            where.append(episode)
        if field:
            where.append(field)
        super().__init__(f"{': '.join(where)}: {problem}")


class OutputError(OSError):
    """Writing a dataset failed (disk full, permissions): the import stops; the message says what each dataset
    holds."""


@dataclass
class EpisodeFailure:
    """One source episode that could not be converted."""

    episode: str  # where: "<file>: <demo>" or the episode directory
    error: str


@dataclass
class ImportSummary:
    """What an import produced. ``converted``/``failed`` count source episodes."""

    source: str
    converted: int = 0
    failed: list[EpisodeFailure] = field(default_factory=list)
    frames: dict[str, int] = field(default_factory=dict)  # dataset kind -> frames written
    episodes: dict[str, int] = field(default_factory=dict)  # dataset kind -> episodes written
    keyframes: int = 0  # keyframes of the converted episodes
    outputs: dict[str, str] = field(default_factory=dict)  # dataset kind -> root
    wall_s: float = 0.0

    def line(self) -> str:
        parts = [f"import {self.source}: converted {self.converted}, failed {len(self.failed)} episodes"]
        for kind, n in self.frames.items():
            eps = self.episodes.get(kind, 0)
            parts.append(f"{kind} {n} frames ({eps} episode{'' if eps == 1 else 's'})")
        parts.append(f"{self.keyframes} keyframes")
        parts.append(f"{self.wall_s:.1f} s")
        out = ", ".join(parts)
        return out + (" -> " + ", ".join(self.outputs.values()) if self.outputs else " (nothing written)")


ViewsFn = Callable[[int], CameraViews]


def stored_views(episode: Episode) -> ViewsFn:
    """``views(t)`` of an episode with stored camera frames (:attr:`Episode.images`)."""
    if not episode.images:
        raise ValueError(f"{episode.name}: no stored images")
    images = episode.images
    return lambda t: {cam: stream.frame(t) for cam, stream in images.items()}


class DatasetSink:
    """Writes imported episodes into the dense and/or keyframe datasets under ``output.dir``.

    The writers are opened at the first episode (so a run whose every episode fails writes nothing, rather
    than an unreadable empty dataset), with that episode's layout and static calibration; later episodes
    must have the same layout. Use as a context manager: the writers are always finalized and the
    ``import.json`` report is written, also when the run is interrupted.
    """

    def __init__(self, output: OutputConfig, source: str, provenance: Mapping[str, Any]):
        output.check_writable()
        self.output = output
        self.summary = ImportSummary(source)
        self.provenance = dict(provenance)
        self.writers: dict[str, SigmaWriter] = {}
        self.layout: DatasetLayout | None = None
        self.static_calibration: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self._start = time.perf_counter()

    def _open(self, layout: DatasetLayout, static_calibration: StaticCalibration | None) -> None:
        out = Path(self.output.dir)
        for kind in self.output.kinds():
            common: dict[str, Any] = {
                "layout": layout,
                "repo_id": f"{self.output.repo_id}_{kind}",
                "provenance": self.provenance,
                "static_calibration": static_calibration,
                "overwrite": self.output.overwrite,
            }
            if kind == "dense":
                common["layout"] = dataclasses.replace(layout, depth=self.output.dense_depth)
                self.writers[kind] = DenseWriter(out / kind, use_videos=self.output.dense_video, **common)
            else:
                self.writers[kind] = KeyframeWriter(
                    out / kind,
                    use_videos=self.output.keyframe_video,
                    augment_every=self.output.augment_every,
                    **common,
                )
        self.layout = layout
        self.static_calibration = {
            cam: (np.asarray(K, np.float64), np.asarray(E, np.float64))
            for cam, (K, E) in (static_calibration or {}).items()
        }

    def open(self, layout: DatasetLayout, static_calibration: StaticCalibration | None = None) -> None:
        """Open the writers (first call) or check that ``layout`` matches the open datasets."""
        if self.layout is None:
            self._open(layout, static_calibration)
            return
        if layout != self.layout:
            raise ValueError(
                f"cameras/size {layout} differ from the dataset's {self.layout} (one dataset, one camera layout)"
            )
        if static_calibration is not None:  # None: the caller checked it already (or has nothing to say)
            self.check_static_calibration(static_calibration)

    def check_static_calibration(self, static_calibration: StaticCalibration, tol: float = 1e-6) -> None:
        """A camera the dataset stores as fixed (its K and E in the feature's ``info``, from the first episode)
        must have that calibration in every later episode too: otherwise the stored one would be wrong for it."""
        for cam, (K0, E0) in self.static_calibration.items():
            if cam not in static_calibration:
                raise ValueError(
                    f"camera '{cam}' moves in this episode, but the dataset stores it as a fixed camera (its "
                    "calibration from the first episode); import episodes with a moving camera into another dataset"
                )
            K, E = (np.asarray(m, np.float64) for m in static_calibration[cam])
            dk, de = float(np.abs(K - K0).max()), float(np.abs(E - E0).max())
            if dk > tol or de > tol:
                raise ValueError(
                    f"fixed camera '{cam}' has other calibration than in the first episode (max |dK| {dk:.3g} px, "
                    f"max |dE| {de:.3g}); one dataset stores one calibration per fixed camera: import episodes "
                    "with another camera set-up into another dataset"
                )

    def shared_frames(self, episode: Episode) -> set[int]:
        """Frames of ``episode`` that more than one open writer asks for (worth caching once rendered)."""
        return shared_frames(self.writers.values(), episode)

    def add(
        self,
        episode: Episode,
        views: ViewsFn,
        layout: DatasetLayout,
        static_calibration: StaticCalibration | None = None,
    ) -> None:
        """Write one episode into every dataset. Raises on failure (the partial episode is discarded).

        The dense writer runs first and reads every frame, so a bad source frame (missing image, wrong size,
        NaN) fails the episode before anything of it reaches either dataset; the keyframe writer then reads a
        subset of the same frames. Only an I/O failure inside the keyframe writer (disk full) could leave the
        dense dataset one episode ahead; ``import.json`` then names the episode.
        """
        self.open(layout, static_calibration)
        written: list[str] = []
        for kind, writer in self.writers.items():
            try:
                writer.add_episode(episode, views)
            except OSError as exc:
                counts = ", ".join(f"{k} {len(w.episodes)}" for k, w in self.writers.items())
                note = f"; {', '.join(written)} already holds this episode" if written else ""
                raise OutputError(
                    f"writing episode {episode.name} into the {kind} dataset failed ({exc}){note}. Episodes per "
                    f"dataset: {counts}. Free space (or fix permissions) and import again with "
                    "--output.overwrite=true"
                ) from exc
            written.append(kind)
        self.summary.converted += 1
        self.summary.keyframes += len(episode.keyframes)

    def fail(self, episode: str, error: BaseException | str) -> None:
        """Record a source episode that could not be converted."""
        self.summary.failed.append(EpisodeFailure(episode, str(error)))

    def close(self) -> ImportSummary:
        """Finalize every writer (each even if another fails), write the report; returns the summary."""
        errors: list[BaseException] = []
        for kind, writer in self.writers.items():
            try:
                writer.finalize()
            except BaseException as exc:
                errors.append(exc)
            self.summary.frames[kind] = writer.num_frames
            self.summary.episodes[kind] = len(writer.episodes)
            if writer.episodes:
                self.summary.outputs[kind] = str(writer.root)
            else:  # LeRobot cannot read a dataset without episodes: leave nothing that looks like one
                shutil.rmtree(writer.root, ignore_errors=True)
        self.summary.wall_s = time.perf_counter() - self._start
        out = Path(self.output.dir)
        out.mkdir(parents=True, exist_ok=True)
        (out / REPORT).write_text(json.dumps(asdict(self.summary), indent=1))
        if errors:
            raise errors[0]
        return self.summary

    def __enter__(self) -> DatasetSink:
        return self

    def __exit__(self, exc_type: object, exc: BaseException | None, tb: object) -> None:
        if isinstance(exc, OutputError):
            self.fail("output", exc)
        self.close()


def finite_or_error(array: np.ndarray, path: str | Path, episode: str, name: str) -> None:
    """Raise :class:`SourceError` naming the first row of ``array`` with NaN or inf."""
    bad = ~np.isfinite(np.asarray(array, dtype=np.float64)).reshape(len(array), -1).all(axis=1)
    if bad.any():
        rows = np.flatnonzero(bad)
        raise SourceError(path, episode, name, f"NaN or inf in {len(rows)} row(s), first at row {rows[0]}")


__all__ = [
    "DatasetSink",
    "EpisodeFailure",
    "ImportSummary",
    "SourceError",
    "finite_or_error",
    "stored_views",
]
