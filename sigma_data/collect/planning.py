"""Before any shard runs: which shards a collection has (:func:`plan_shards`), whether ``output.dir`` may be
written (:func:`claim_output_dir`), and which shards on disk a rerun can reuse (:func:`check_shard`).

Resume works shard by shard. A shard is reused when its ``shard.json`` marker (written last) matches the
configuration, every file it recorded is intact (:mod:`sigma_data.collect.manifest`) and its datasets load with
the recorded episode counts. Anything else there, an interrupted shard, a damaged one or one whose marker predates
the file list, is deleted and redone, and the run says which and why.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from sigma_data.collect.config import (
    MARKER,
    RECORD,
    RECORD_TMP,
    CollectConfig,
    ShardResult,
    ShardSpec,
    recorded_options,
)
from sigma_data.collect.manifest import damage
from sigma_data.contract import SIDECAR
from sigma_data.files import write_json_atomic


def plan_shards(cfg: CollectConfig) -> list[ShardSpec]:
    """Shards of the run, in a fixed order (task, variation, seed). Raises ``ValueError`` on bad names."""
    from sigma_data.suite import get_task

    if cfg.episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {cfg.episodes}")
    if cfg.shard_size < 1 or cfg.workers < 1:
        raise ValueError(f"shard_size and workers must be >= 1, got {cfg.shard_size}, {cfg.workers}")
    cfg.output.kinds()  # ValueError if there is nothing to write
    names = cfg.task_names()
    tasks = [get_task(n) for n in names]
    wanted = (
        None
        if cfg.variations.strip() == "all"
        else {v.strip() for v in cfg.variations.split(",") if v.strip()}
    )
    if wanted is not None:
        known = {v.name for t in tasks for v in t.variations}
        unknown = sorted(wanted - known)
        if unknown:
            raise ValueError(
                f"unknown variation(s) {unknown} for tasks {names}; known: {', '.join(sorted(known))}"
            )
    seeds = list(range(cfg.start_seed, cfg.start_seed + cfg.episodes))
    shards = []
    for task in tasks:
        for var in task.variations:
            if wanted is not None and var.name not in wanted:
                continue
            for i in range(0, len(seeds), cfg.shard_size):
                shards.append(ShardSpec(task.name, var.name, tuple(seeds[i : i + cfg.shard_size])))
    return shards


def write_record(out: Path, data: dict) -> None:
    """``<out>/collect.json`` written under a temporary name (:data:`RECORD_TMP`) and renamed: a kill mid-write
    leaves the previous record or none, never a torn one that every rerun would fail to read."""
    write_json_atomic(out / RECORD, data)


def entries(out: Path) -> list[str]:
    """Names in ``out`` (none if it does not exist), but for a temporary record a killed run may have left."""
    if not out.is_dir():
        return []
    return sorted(p.name for p in out.iterdir() if p.name != RECORD_TMP)


def option_changes(out: Path, cfg: CollectConfig) -> str:
    """How the data options recorded in ``out``'s ``collect.json`` differ from ``cfg``'s, as ``"name recorded ->
    wanted, ..."``; empty when they agree. An option added since that collection counts as its default then."""
    previous = recorded_options(json.loads((out / RECORD).read_text()).get("config", {}))
    defaults = CollectConfig().data_options()
    mine = cfg.data_options()
    differ = [k for k in mine if previous.get(k, defaults[k]) != mine[k]]
    return ", ".join(f"{k} {previous.get(k, defaults[k])} -> {mine[k]}" for k in differ)


def claim_output_dir(cfg: CollectConfig) -> None:
    """Make sure ``output.dir`` holds nothing but this collection (or a resumable run of it), then record the
    options in ``collect.json`` before any shard is written. Anything else there raises ``FileExistsError``
    (``--output.overwrite=true`` replaces it): a directory of someone else's files, datasets from another tool,
    or a collection made with other options (other tasks, seeds, image size...). A ``collect.json`` written before
    the options were grouped names them the old way (``height``, ``dense``...): they are read as today's."""
    out = Path(cfg.output.dir)
    record = out / RECORD
    mine = cfg.data_options()
    present = entries(out)
    if present and not cfg.output.overwrite:
        hint = "pass --output.overwrite=true to replace it, or choose another --output.dir"
        if RECORD not in present:
            raise FileExistsError(
                f"{out} is not empty ({', '.join(present[:5])}) and holds no {RECORD}: {hint}"
            )
        changes = option_changes(out, cfg)
        if changes:
            raise FileExistsError(f"{out} holds a collection made with other options ({changes}): {hint}")
    if present and cfg.output.overwrite:
        for name in ("dense", "keyframe", "shards", RECORD, RECORD_TMP):
            path = out / name
            if path.is_dir():
                shutil.rmtree(path)
            elif path.exists():
                path.unlink()
    out.mkdir(parents=True, exist_ok=True)
    if not record.exists():
        write_record(out, {"config": mine, "shards": []})


def check_shard(shard_dir: Path, cfg: CollectConfig) -> tuple[ShardResult | None, str]:
    """``(stored result, "")`` if ``shard_dir`` is a finished shard of ``cfg`` whose files are intact; else
    ``(None, why it must be redone)``, with ``why`` empty when there is no shard there at all."""
    marker = shard_dir / MARKER
    if not marker.exists():
        return None, "no shard.json: interrupted before it finished" if shard_dir.exists() else ""
    try:
        stored = json.loads(marker.read_text())
        files = stored.pop("files", None)
        result = ShardResult(**stored)
    except (json.JSONDecodeError, TypeError, AttributeError) as exc:
        return None, f"shard.json does not read ({type(exc).__name__}: {exc})"
    if result.fingerprint != cfg.fingerprint():
        return None, f"collected with other options (fingerprint {result.fingerprint} != {cfg.fingerprint()})"
    if not isinstance(files, dict):
        return None, "shard.json lists no files (it predates file lists), so the shard cannot be verified"
    kinds = [k for k in cfg.datasets() if result.episodes.get(k, 0) > 0]
    unlisted = [k for k in kinds if k not in files]
    if unlisted:
        return None, f"shard.json lists no files of its {', '.join(unlisted)} dataset"
    try:
        why = damage(shard_dir, files, result.frames)
    except (KeyError, TypeError, ValueError) as exc:
        why = f"shard.json's file list does not read ({type(exc).__name__}: {exc})"
    if why:
        return None, why
    # Imported only once a marker is found, so a fresh run starts its helpers without waiting for LeRobot (~5 s).
    from lerobot.datasets.dataset_metadata import LeRobotDatasetMetadata

    for kind in kinds:
        root = shard_dir / kind
        try:
            meta = LeRobotDatasetMetadata(f"{cfg.output.repo_id}_{kind}", root=root)
        except Exception as exc:
            return None, f"{kind} metadata does not load ({type(exc).__name__}: {exc})"
        if meta.total_episodes != result.episodes[kind]:
            expected = result.episodes[kind]
            return None, f"{kind} has {meta.total_episodes} episodes, shard.json records {expected}"
        if not (root / SIDECAR).exists():
            return None, f"{kind}/{SIDECAR} is missing"
    result.skipped = True
    return result, ""


def finished_shard(shard_dir: Path, cfg: CollectConfig) -> ShardResult | None:
    """The stored result if ``shard_dir`` is complete, intact and matches ``cfg``; None if it must be (re)done."""
    return check_shard(shard_dir, cfg)[0]
