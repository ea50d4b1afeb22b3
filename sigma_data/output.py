"""Where and how a run writes the sigma datasets (``--output.*``): one sub-config shared by ``sigma-data collect``
and every importer.

A command whose default ``dir`` or ``repo_id`` differs from the importers' (below) subclasses :class:`OutputConfig`
with its own defaults (``CollectOutputConfig``, ``TeleopOutputConfig``) rather than passing a ``default_factory``:
draccus builds a sub-config from its class's defaults as soon as one of its options is given on the command line,
so ``--output.dense=false`` would otherwise also reset ``dir`` and ``repo_id`` (and ``--help`` would show the
class's defaults)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass
class OutputConfig:
    """Where and how the datasets are written: ``<dir>/dense``, ``<dir>/keyframe`` and the run's report."""

    # Where the datasets go.
    dir: Path = Path("outputs/sigma_import")
    # LeRobot repo_id prefix of the datasets (local only): <repo_id>_dense, <repo_id>_keyframe.
    repo_id: str = "local/sigma_import"
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
    # Replace what dir holds: an import's existing datasets, or a directory that holds anything but a collection
    # with these options (another configuration, another tool, files of your own). Without it such a directory
    # is an error, never touched.
    overwrite: bool = False

    def kinds(self) -> list[str]:
        """The datasets to write (``dense``, ``keyframe``); ``ValueError`` if neither."""
        kinds = [k for k, on in (("dense", self.dense), ("keyframe", self.keyframe)) if on]
        if not kinds:
            raise ValueError("nothing to write: enable --output.dense and/or --output.keyframe")
        return kinds

    def check_writable(self) -> None:
        """Fail before any work if a target dataset exists and ``overwrite`` is off (the importers' rule)."""
        for kind in self.kinds():
            root = Path(self.dir) / kind
            if root.exists() and not self.overwrite:
                raise FileExistsError(f"{root} already exists (pass --output.overwrite=true to replace it)")
