"""A result-identical speed fix for LeRobot 0.6.1's multi-frame reads, installed when sigma is imported.

With ``delta_timestamps`` (sigma reads the current frame and its goal: ``observation_delta_indices=[0, 1]``),
``DatasetReader._query_hf_dataset`` fetches every key separately with ``hf_dataset[key][rows]``. Under LeRobot's
row transform each such call decodes *all* columns of those rows, so a keyframe dataset with 4 RGB-D cameras
(8 image columns, 8 calibration columns) decodes ~270 images per sample instead of 16: 216 ms instead of 13 ms
per sample, measured on this project's demo dataset, which made ``lerobot-train`` data-bound on a CPU.

The replacement groups keys that ask for the same rows and decodes those rows once. Its output is the same
dictionary of stacked tensors (``tests/sigma_policy/test_lerobot_patches.py`` compares it with the original on a
real dataset); on any unexpected input it defers to the original method.

A log filter shortens one LeRobot warning: on machines without FFmpeg's shared libraries (sigma's set-up does not
need them: PyAV ships its own), LeRobot logs torchcodec's loading tracebacks for every FFmpeg version at every
``lerobot-train`` start (~150 lines) before falling back to PyAV. The filter keeps the warning as one line.

Set ``SIGMA_NO_LEROBOT_PATCHES=1`` to leave LeRobot untouched.
"""

from __future__ import annotations

import logging
import os
from collections import defaultdict

import torch

_INSTALLED = False


def _grouped_query_hf_dataset(self, query_indices: dict[str, list[int]]) -> dict:
    original = _grouped_query_hf_dataset.original
    try:
        groups: dict[tuple[int, ...], list[str]] = defaultdict(list)
        for key, q_idx in query_indices.items():
            if key in self._meta.video_keys:
                continue
            rows = (
                q_idx
                if self._absolute_to_relative_idx is None
                else [self._absolute_to_relative_idx[idx] for idx in q_idx]
            )
            groups[tuple(rows)].append(key)
        result: dict = {}
        for rows, keys in groups.items():
            table = self.hf_dataset[list(rows)]
            for key in keys:
                result[key] = torch.stack(table[key])
        return result
    except (KeyError, TypeError, IndexError, RuntimeError):
        return original(self, query_indices)


class _ShortTorchcodecWarning(logging.Filter):
    """Rewrites LeRobot's "torchcodec cannot be loaded" warning (with its tracebacks) to one line."""

    def filter(self, record: logging.LogRecord) -> bool:
        msg = str(record.msg)
        if "torchcodec' is installed but cannot be loaded" in msg:
            record.msg = (
                "torchcodec cannot load here (usually: no FFmpeg 4-8 shared libraries); LeRobot falls back to "
                "PyAV for video decoding (SIGMA_NO_LEROBOT_PATCHES=1 shows torchcodec's loader tracebacks)"
            )
            record.args = ()
        return True


def install() -> bool:
    """Install the grouped query on LeRobot's ``DatasetReader`` (idempotent). Returns whether it is active."""
    global _INSTALLED
    if _INSTALLED:
        return True
    if os.environ.get("SIGMA_NO_LEROBOT_PATCHES"):
        return False
    try:
        from lerobot.datasets.dataset_reader import DatasetReader
    except ImportError:  # a LeRobot without this reader: nothing to patch
        return False
    if not hasattr(DatasetReader, "_query_hf_dataset"):
        return False
    _grouped_query_hf_dataset.original = DatasetReader._query_hf_dataset
    DatasetReader._query_hf_dataset = _grouped_query_hf_dataset
    logging.getLogger("lerobot.utils.import_utils").addFilter(_ShortTorchcodecWarning())
    _INSTALLED = True
    return True
