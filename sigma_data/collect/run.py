"""A whole collection (:func:`collect`): plan the shards, claim ``output.dir``, reuse the finished shards that
verify and redo the rest (saying which and why), run the remaining shards with the chosen executor, merge each
dataset kind, and record the run in ``collect.json``."""

from __future__ import annotations

import logging
import shutil
import time
from dataclasses import asdict
from pathlib import Path

from sigma_data.collect.config import (
    MARKER,
    RECORD,
    RECORD_TMP,
    CollectConfig,
    CollectSummary,
    ShardResult,
    ShardSpec,
)
from sigma_data.collect.envs import check_cameras_exist, close_envs
from sigma_data.collect.merge import merge_shards
from sigma_data.collect.planning import check_shard, claim_output_dir, entries, plan_shards, write_record
from sigma_data.collect.scheduler import Helpers, _run_processes

log = logging.getLogger(__name__)


def _run_datatrove(todo: list[ShardSpec], cfg: CollectConfig) -> list[ShardResult]:
    try:
        from sigma_data.collect.datatrove import run_local
    except ImportError as exc:
        raise ImportError(
            "executor='datatrove' needs the optional dependency datatrove: pip install -e '.[cluster]' "
            f"(or 'datatrove>=0.4,<1'); {exc}"
        ) from exc
    return run_local(todo, cfg)


def _reusable(
    shards: list[ShardSpec], shards_dir: Path, cfg: CollectConfig
) -> tuple[dict[str, ShardResult], dict[str, str]]:
    """The finished shards that verify, by name, and why each other shard found on disk must be redone (one
    warning per shard)."""
    done: dict[str, ShardResult] = {}
    redo: dict[str, str] = {}
    for spec in shards:
        result, why = check_shard(shards_dir / spec.name, cfg)
        if result is not None:
            done[spec.name] = result
        elif why:
            redo[spec.name] = why
            log.warning("sigma-data collect: redoing shard %s: %s", spec.name, why)
    return done, redo


def collect(cfg: CollectConfig) -> CollectSummary:
    """Run (or resume) a collection and merge the shards. Returns per-shard results and output roots."""

    start = time.perf_counter()
    shards = plan_shards(cfg)
    out = Path(cfg.output.dir)
    shards_dir = out / "shards"
    fresh = not entries(out)
    claim_output_dir(cfg)
    try:
        return _collect(cfg, shards, out, shards_dir, start)
    except BaseException:
        if fresh and not any(shards_dir.glob(f"*/{MARKER}")):
            _forget(out)  # rejected before any shard finished (unknown camera...): leave no trace
        raise


def _forget(out: Path) -> None:
    """Remove what :func:`claim_output_dir` and the run put into a directory that was empty before it."""
    (out / RECORD).unlink(missing_ok=True)
    (out / RECORD_TMP).unlink(missing_ok=True)
    shutil.rmtree(out / "shards", ignore_errors=True)
    if out.is_dir() and not any(out.iterdir()):
        out.rmdir()


def _collect(
    cfg: CollectConfig, shards: list[ShardSpec], out: Path, shards_dir: Path, start: float
) -> CollectSummary:
    from tqdm import tqdm

    done, redo = _reusable(shards, shards_dir, cfg)
    todo = [s for s in shards if s.name not in done]
    total = sum(len(s.seeds) for s in todo)
    n_helpers = min(cfg.workers, len(todo)) - 1 if cfg.executor != "datatrove" else 0
    helpers = Helpers(n_helpers, cfg, todo[0].task) if n_helpers > 0 else None
    try:  # the helpers are reaped on every way out; after an error a helper first finishes its current shard
        try:
            if todo and cfg.executor == "datatrove":
                check_cameras_exist(cfg, list(dict.fromkeys(s.task for s in todo)), reuse=False)
            shards_dir.mkdir(parents=True, exist_ok=True)
            with tqdm(total=total, desc="episodes", unit="ep", disable=not cfg.progress) as pbar:
                if cfg.executor == "datatrove":
                    results = _run_datatrove(todo, cfg) if todo else []
                    pbar.update(total)
                else:
                    results = _run_processes(todo, cfg, shards_dir, pbar, helpers) if todo else []
        finally:
            close_envs()
        if helpers is not None:
            helpers.release()  # they exit while the shards are merged
        for r in results:
            r.redone = redo.get(r.name, "")
            done[r.name] = r
        ordered = [done[s.name] for s in shards]

        outputs: dict[str, Path] = {}
        for kind in cfg.datasets():
            roots = [shards_dir / r.name / kind for r in ordered if r.episodes.get(kind, 0) > 0]
            target = out / kind
            if not roots:
                shutil.rmtree(target, ignore_errors=True)
                continue
            merge_shards(kind, roots, target, f"{cfg.output.repo_id}_{kind}", progress=cfg.progress)
            outputs[kind] = target
    finally:
        if helpers is not None:
            helpers.close()
    summary = CollectSummary(ordered, outputs, time.perf_counter() - start)
    write_record(out, {"config": cfg.data_options(), "shards": [asdict(s) for s in ordered]})
    return summary
