"""Reading a dataset's columns once for every check: the numeric columns whole, rows grouped by episode."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sigma_data.contract import dataset_kind


def dataset_kind_or_unknown(root: Path, features: dict) -> str:
    try:
        return dataset_kind(root, features)
    except ValueError:
        return "unknown"  # reported by check_structure


def read_columns(ds, names: list[str]) -> dict[str, np.ndarray]:
    table = ds.hf_dataset.with_format(None).select_columns(names)[:]
    return {k: np.asarray(v) for k, v in table.items()}


def episode_bounds(episode_index: np.ndarray) -> dict[int, tuple[int, int]]:
    """Episode -> [start, stop) row range (rows are stored episode-contiguous)."""
    bounds: dict[int, tuple[int, int]] = {}
    for ep in np.unique(episode_index):
        rows = np.flatnonzero(episode_index == ep)
        bounds[int(ep)] = (int(rows[0]), int(rows[-1]) + 1)
    return bounds


def sample_rows(start: int, stop: int, n: int) -> list[int]:
    rows = np.linspace(start, stop - 1, max(1, min(n, stop - start))).round().astype(int)
    return sorted(set(rows.tolist()))
