"""Result-identical speed fixes for LeRobot 0.6.1's multi-frame reads, installed by :func:`install`.

With ``delta_timestamps`` (sigma reads the current frame and its goal: ``observation_delta_indices=[0, 1]``),
``DatasetReader._query_hf_dataset`` fetches every key separately with ``hf_dataset[key][rows]``. Under LeRobot's
row transform each such call decodes *all* columns of those rows, so a keyframe dataset with 4 RGB-D cameras
(8 image columns, 8 calibration columns) decodes ~270 images per sample instead of 16: 216 ms instead of 13 ms
per sample, measured on this project's demo dataset, which made ``lerobot-train`` data-bound on a CPU.

1. The grouped query groups keys that ask for the same rows and decodes those rows once.
2. ``DatasetReader.get_item`` first decodes the whole current row and then overwrites every queried key with the
   query's result: the current row is read without those columns instead (1.5x fewer decodes again).

3. Both keep what they decoded, per loaded dataset, in memory: a training run reads every sample once per epoch
   (``make demo``: ~17 epochs of 690 keyframes), and from the second epoch on a read is a dictionary lookup
   instead of ~12 ms of PNG decoding per sample (about 15% of a CPU training step). The cache holds at most
   ``SIGMA_READ_CACHE_MB`` (default 2048) per process; past that, new rows are decoded and not kept
   (``SIGMA_READ_CACHE_MB=0``: no cache). A hit returns the very tensors decoded the first time; LeRobot only
   builds new dictionaries and tensors from them (the DataLoader's collation copies).

All return the same dictionary of tensors (``tests/sigma_policy/test_lerobot_patches.py`` compares them with the
originals on a real dataset); on any unexpected input they defer to the original methods.

LeRobot's ``lerobot-train`` starts its DataLoader workers with ``spawn``: they re-import modules instead of
inheriting the patched class, so a class patch made in the main process alone would not reach the workers that
do the reading (measured on an H100 machine with 14 workers: 7-12 samples/s, data-bound 10x). Every
``DatasetReader`` made after the install therefore carries a small marker whose unpickling -- which happens in
each worker when it receives the dataset -- installs the patch there too.

A log filter shortens one LeRobot warning: on machines without FFmpeg's shared libraries (sigma's set-up does not
need them: PyAV ships its own), LeRobot logs torchcodec's loading tracebacks for every FFmpeg version at every
``lerobot-train`` start (~150 lines) before falling back to PyAV. The filter keeps the warning as one line.

``install`` runs when LeRobot loads sigma's plugin entry point (``lerobot_policy_sigma``: ``lerobot-train``,
``lerobot-eval``) and when a ``SigmaPolicy`` is built; ``import sigma_policy`` alone changes nothing. Set
``SIGMA_NO_LEROBOT_PATCHES=1`` to leave LeRobot untouched.
"""

from __future__ import annotations

import logging
import numbers
import os
import weakref
from collections import defaultdict

import torch

_INSTALLED = False
_DEFAULT_CACHE_MB = 2048


class _DecodedRows:
    """Decoded reads of one loaded dataset (``source``), kept until ``budget`` bytes are held."""

    def __init__(self, source, budget: int) -> None:
        self.source, self.budget, self.used = source, budget, 0
        self.items: dict = {}

    def get(self, key, decode):
        """The dictionary ``decode()`` returned for ``key`` (a shallow copy: callers may add keys to it)."""
        hit = self.items.get(key)
        if hit is None:
            hit = decode()
            size = sum(v.numel() * v.element_size() for v in hit.values() if torch.is_tensor(v))
            if self.used + size <= self.budget:
                self.items[key] = hit
                self.used += size
        return dict(hit)


# One cache per reader, kept beside it (not in it: a reader is pickled into every spawned DataLoader worker).
_CACHES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _decoded_rows(reader) -> _DecodedRows | None:
    """``reader``'s cache for its current ``hf_dataset``, or None when ``SIGMA_READ_CACHE_MB`` is 0."""
    budget = int(float(os.environ.get("SIGMA_READ_CACHE_MB", _DEFAULT_CACHE_MB)) * 2**20)
    if budget <= 0:
        return None
    cache = _CACHES.get(reader)
    if cache is None or cache.source is not reader.hf_dataset:
        cache = _CACHES[reader] = _DecodedRows(reader.hf_dataset, budget)
    return cache


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

        def decode(rows: tuple[int, ...], keys: list[str]) -> dict:
            table = self.hf_dataset[list(rows)]
            return {key: torch.stack(table[key]) for key in keys}

        cache = _decoded_rows(self)
        result: dict = {}
        for rows, keys in groups.items():
            if cache is None:
                result.update(decode(rows, keys))
            else:
                result.update(cache.get(("query", rows, tuple(keys)), lambda r=rows, k=keys: decode(r, k)))
        return result
    except (KeyError, TypeError, IndexError, RuntimeError):
        return original(self, query_indices)


class _CachedLightRows:
    """``light[idx]`` for an integer ``idx``, kept in ``cache``; anything else goes to ``light`` itself."""

    def __init__(self, light, cache: _DecodedRows) -> None:
        self._light, self._cache = light, cache

    def __getitem__(self, idx):
        if isinstance(idx, numbers.Integral):
            return self._cache.get(("row", int(idx)), lambda: self._light[idx])
        return self._light[idx]

    def __getattr__(self, name: str):
        return getattr(self._light, name)


class _ReaderWithLightRows:
    """``reader`` as seen by LeRobot's ``get_item``, except that its ``hf_dataset`` is ``light``: the same rows
    without the columns the multi-frame query replaces anyway (read through the reader's cache, if any). Methods
    stay bound to the real reader."""

    def __init__(self, reader, light) -> None:
        cache = _decoded_rows(reader)
        self._reader = reader
        self.hf_dataset = light if cache is None else _CachedLightRows(light, cache)

    def __getattr__(self, name: str):
        return getattr(self._reader, name)


def _light_rows(reader):
    """``reader.hf_dataset`` without the ``delta_indices`` columns (cached per loaded dataset)."""
    full = reader.hf_dataset
    cached = reader.__dict__.get("_sigma_light_rows")
    if cached is None or cached[0] is not full:
        keep = [c for c in full.column_names if c not in reader.delta_indices]
        cached = (full, full.select_columns(keep))
        reader.__dict__["_sigma_light_rows"] = cached
    return cached[1]


def _get_item_without_double_decode(self, idx) -> dict:
    """LeRobot's ``get_item`` first decodes the whole current row, then replaces every ``delta_indices`` key by
    the multi-frame query: with sigma's keyframe datasets that first decode (8 images of 16) is thrown away.
    Here the current row is read without those columns; the rest of ``get_item`` runs unchanged."""
    original = _get_item_without_double_decode.original
    if not self.delta_indices or self.hf_dataset is None:
        return original(self, idx)
    try:
        return original(_ReaderWithLightRows(self, _light_rows(self)), idx)
    except (KeyError, TypeError, IndexError, AttributeError, ValueError):
        return original(self, idx)


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


def _install_in_this_process() -> _InstallOnUnpickle:
    install()
    return _InstallOnUnpickle()


class _InstallOnUnpickle:
    """Pickled with every ``DatasetReader``; unpickling it (in a spawned DataLoader worker) installs the patch."""

    def __reduce__(self):
        return (_install_in_this_process, ())


def _init_with_marker(self, *args, **kwargs) -> None:
    _init_with_marker.original(self, *args, **kwargs)
    self._sigma_lerobot_patches = _InstallOnUnpickle()


def install() -> bool:
    """Install the read fixes on LeRobot's ``DatasetReader`` -- the grouped query, the light current row, and the
    marker that carries both into spawned workers -- and the log filter (idempotent). Returns whether active."""
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
    _get_item_without_double_decode.original = DatasetReader.get_item
    DatasetReader.get_item = _get_item_without_double_decode
    _init_with_marker.original = DatasetReader.__init__
    _init_with_marker.__doc__ = DatasetReader.__init__.__doc__
    DatasetReader.__init__ = _init_with_marker
    logging.getLogger("lerobot.utils.import_utils").addFilter(_ShortTorchcodecWarning())
    _INSTALLED = True
    return True
