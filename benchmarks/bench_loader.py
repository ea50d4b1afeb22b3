"""Loader speed: a keyframe-dataset sample as ``lerobot-train`` reads it for sigma (current frame + goal frame).

Compares, in the same run and on the same dataset, LeRobot 0.6.1's own multi-frame read with sigma's
result-identical fixes (``sigma_policy.lerobot_patches``: the grouped query, then the current row read without
the queried columns, both with the decoded-row cache off: a first epoch), a single-frame read as the floor, and
sigma's read of samples already read once (a later epoch: the decoded-row cache). Prints a Markdown table.

    python -m benchmarks.bench_loader --root outputs/demo/data/keyframe
    python -m benchmarks.bench_loader               # a small synthetic keyframe dataset (temporary)
"""

from __future__ import annotations

import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from unittest import mock

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import draccus


@dataclass
class LoaderBenchConfig:
    # A keyframe dataset; default: a synthetic one written to a temporary directory.
    root: Path | None = None
    # Samples read per variant (the mean time is reported), after one warm-up read.
    samples: int = 20
    # Write benchmarks/results/loader.md (+ .json), the fragment RESULTS.md includes.
    publish: bool = True
    # Where the fragment goes (default: benchmarks/results).
    results_dir: Path | None = None


def _per_item_ms(ds, n: int, *, second_pass: bool = False) -> float:
    ds[0]  # warm-up (file handles, decoders)
    if second_pass:  # every timed sample read once before (what a later training epoch sees)
        for i in range(n):
            ds[i % len(ds)]
    start = time.perf_counter()
    for i in range(n):
        ds[i % len(ds)]
    return 1000 * (time.perf_counter() - start) / n


def main(cfg: LoaderBenchConfig) -> str:
    """Time the three reads, print (and publish) the table; returns the table."""
    if cfg.root is not None:
        return _bench(cfg, Path(cfg.root), f"Dataset {cfg.root}")
    from tests.sigma_policy.tiny_dataset import write_tiny_keyframe_dataset

    with tempfile.TemporaryDirectory(prefix="bench_loader_") as tmp:
        root = write_tiny_keyframe_dataset(Path(tmp) / "ds", size=64)
        return _bench(
            cfg, root, "Synthetic keyframe dataset (`tests/sigma_policy/tiny_dataset.py`, 64² images)"
        )


def _bench(cfg: LoaderBenchConfig, root: Path, described: str) -> str:
    from lerobot.datasets.dataset_reader import DatasetReader
    from lerobot.datasets.factory import resolve_delta_timestamps
    from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata

    from sigma_policy import lerobot_patches
    from sigma_policy.configuration_sigma import SigmaConfig

    meta = LeRobotDatasetMetadata("local/bench", root=root)
    deltas = resolve_delta_timestamps(SigmaConfig(preset="small", device="cpu"), meta)

    def load(delta_timestamps):
        return LeRobotDataset(
            "local/bench", root=root, delta_timestamps=delta_timestamps, video_backend="pyav"
        )

    lerobot_patches.install()
    patched = {"_query_hf_dataset": DatasetReader._query_hf_dataset, "get_item": DatasetReader.get_item}
    stock_methods = {
        "_query_hf_dataset": lerobot_patches._grouped_query_hf_dataset.original,
        "get_item": lerobot_patches._get_item_without_double_decode.original,
    }

    def timed(**methods) -> float:
        """ms per sample, first reads (cache off), with ``methods`` on LeRobot's DatasetReader (the others as
        sigma installs them)."""
        for name, fn in methods.items():
            setattr(DatasetReader, name, fn)
        try:
            with mock.patch.dict(os.environ, {"SIGMA_READ_CACHE_MB": "0"}):
                return _per_item_ms(load(deltas), cfg.samples)
        finally:
            for name, fn in patched.items():
                setattr(DatasetReader, name, fn)

    stock = timed(**stock_methods)
    grouped = timed(get_item=stock_methods["get_item"])
    sigma = timed()
    single = _per_item_ms(load(None), cfg.samples)
    cached = _per_item_ms(load(deltas), cfg.samples, second_pass=True)
    n_keys = sum(k.startswith("observation.") for k in meta.features)
    table = "\n".join(
        [
            f"{described} ({meta.total_frames} frames, {n_keys} observation features), {cfg.samples} samples:",
            "",
            "| read | ms / sample | vs LeRobot |",
            "|---|---|---|",
            f"| LeRobot 0.6.1, current + goal frame | {stock:.1f} | 1.0× |",
            f"| + grouped query (each queried row decoded once) | {grouped:.1f} | {stock / grouped:.1f}× faster |",
            f"| + current row read without the queried columns (sigma) | {sigma:.1f} | {stock / sigma:.1f}× faster |",
            f"| single frame (floor) | {single:.1f} | {stock / single:.1f}× faster |",
            f"| sigma, a sample read before (decoded-row cache: later epochs) | {cached:.2f} "
            f"| {stock / cached:.0f}× faster |",
        ]
    )
    print(table)
    print(
        f"bench_loader: sigma's reads {sigma:.1f} ms vs LeRobot's {stock:.1f} ms per sample "
        f"({stock / sigma:.1f}x faster)"
    )
    if cfg.publish:
        from pipelines.reporting import write_report

        write_report(
            "loader",
            "Loader: a keyframe-dataset sample as lerobot-train reads it for sigma",
            table,
            {
                "lerobot_ms": stock,
                "grouped_query_ms": grouped,
                "sigma_ms": sigma,
                "single_frame_ms": single,
                "cached_ms": cached,
                "root": str(root),
            },
            notes="sigma installs the read fixes when LeRobot loads its plugin (`sigma_policy/lerobot_patches.py`), also in "
            "lerobot-train's spawned DataLoader workers; the baseline is LeRobot's own `_query_hf_dataset` and "
            "`get_item`, timed in the same run on the same dataset. The first four rows are first reads (cache off); "
            "a training run reads each sample once per epoch, so from the second epoch on it reads at the last row's speed.",
            results_dir=cfg.results_dir,
        )
    return table


if __name__ == "__main__":
    main(draccus.parse(LoaderBenchConfig))
