"""Merging the shards' datasets of one kind into ``<output.dir>/{dense,keyframe}`` with LeRobot's
``aggregate_datasets`` (:func:`merge_shards`; a single shard is copied), with the provenance sidecars merged
beside, and the two LeRobot 0.6.1 workarounds the merge needs. The merge is redone every run and swapped in
whole; an error names the shards it was merging (and, where their markers tell, the damaged one)."""

from __future__ import annotations

import contextlib
import functools
import json
import shutil
from pathlib import Path

from sigma_data.collect.config import MARKER
from sigma_data.collect.manifest import damage
from sigma_data.contract import SIDECAR


@contextlib.contextmanager
def _typed_parquet_writes(features: dict[str, dict]):
    """Work around LeRobot 0.6.1's ``aggregate_datasets`` on datasets without image features: it rebuilds the
    data parquet with ``pa.Table.from_pandas(df)`` and no schema, which fails on 2-D features such as the
    (3, 3) intrinsics ("Did not pass numpy.dtype object"). Within this context the same writer is given the
    datasets' own HF schema (used with ``concatenate_data=False``: its append path re-reads files untyped). Only
    the module attribute that function looks up is swapped, and restored."""
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


@contextlib.contextmanager
def _aggregate_bars(enabled: bool):
    """LeRobot's own merge bars ("Validate all meta data", "Copy data and videos") on or off: ``aggregate`` calls
    ``tqdm.tqdm`` through its module attribute ``tqdm``, swapped for the call and restored."""
    from lerobot.datasets import aggregate

    if enabled:
        yield
        return
    import types

    import tqdm

    original = aggregate.tqdm
    aggregate.tqdm = types.SimpleNamespace(tqdm=functools.partial(tqdm.tqdm, disable=True))
    try:
        yield
    finally:
        aggregate.tqdm = original


def _blame(kind: str, shard_roots: list[Path]) -> str:
    """Which of the shards being merged is damaged, as far as their markers' file lists tell; else all of them."""
    damaged = []
    for root in shard_roots:
        try:
            stored = json.loads((root.parent / MARKER).read_text())
            why = damage(root.parent, {kind: stored["files"][kind]}, stored["frames"])
        except Exception as exc:
            why = f"its {MARKER} does not tell ({type(exc).__name__}: {exc})"
        if why:
            damaged.append(f"{root.parent} ({why})")
    if damaged:
        return "damaged shard(s): " + "; ".join(damaged)
    return "shards being merged: " + ", ".join(str(r.parent) for r in shard_roots)


def merge_shards(kind: str, shard_roots: list[Path], out: Path, repo_id: str, progress: bool = True) -> None:
    """Merge shard datasets of one kind with LeRobot's ``aggregate_datasets`` and merge their sidecars (LeRobot's
    bars only with ``progress``). An error is raised as a ``RuntimeError`` naming the shard directories involved."""
    try:
        _merge(shard_roots, out, repo_id, progress)
    except Exception as exc:
        raise RuntimeError(
            f"merging {len(shard_roots)} {kind} shard dataset(s) into {out} failed: {type(exc).__name__}: "
            f"{exc}; {_blame(kind, shard_roots)}. Delete a damaged shard's directory (or its {MARKER}) and "
            "rerun to redo it"
        ) from exc


def _merge(shard_roots: list[Path], out: Path, repo_id: str, progress: bool) -> None:
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
        # LeRobot's own "Copy data and videos" bar stays with progress (one for the merge); per-file bars go.
        with _typed_parquet_writes(features), _datasets_bars_stay_off(), _aggregate_bars(progress):
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
