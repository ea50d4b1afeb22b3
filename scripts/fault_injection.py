"""Fault injection for ``sigma-data collect``: ``kill -9`` at random points of a small collection, rerun it, and
compare the result with a clean run.

    .venv/bin/python scripts/fault_injection.py --kills=20 --seed=0

A clean collection runs once (Lift, 4 episodes of one seed per shard, 32² ``agentview``, 2 worker processes, both
datasets) and its wall time is measured. Then, for each kill point, the same collection starts in a fresh
directory and at a time drawn uniformly over the clean run's wall time (seeded) the collection is killed with
SIGKILL: its whole process group (``--target=group``: the parent and its helpers at once), only the parent
(``parent``: the helpers must end by themselves) or each in turn (``alternate``). Then:

* **no orphans**: within 15 s no process of the killed run is left (a zombie nobody reaped counts as ended);
* **nothing partial at a final path**: a merged ``dense``/``keyframe`` dataset the killed run left is complete
  (equal to the clean run's), and ``collect.json`` reads as JSON;
* **partial output is never trusted**: each shard directory the killed run left is classified by
  ``sigma_data.collect.check_shard`` (the check a rerun makes); the rerun must reuse exactly the shards that
  verify and redo, saying why, every other shard it found;
* **the rerun equals the clean run**: the same command run to completion (exit 0, within ``--timeout_s``, and
  no process of it left afterwards) leaves the same files as the clean run: byte for byte, except where bytes
  legitimately vary between two runs of the same collection and the content is compared instead (run timings in
  ``shard.json``/``collect.json``, the random ``datasets`` fingerprint in a shard's image parquet metadata, key
  order in ``meta/stats.json``); a video whose bytes differ is decoded and compared frame by frame. Every shard
  of the rerun passes ``check_shard`` (its recorded sizes, rows and SHA-256 match its files).

The clean run is checked once: both datasets pass ``sigma-data validate`` and every video decodes to the frame
count its dataset records. Collections run with ``--render_threads=1``: render threads give the same images but
for rare single depth pixels (``docs/robosuite.md`` §2), so only one render thread per worker is exact to the
pixel; with it, the merged datasets of every rerun measured so far were equal to the clean run's byte for byte
(but for the key order of ``meta/stats.json``).

Resumable: everything lives under ``--output_dir``. The clean run is recorded in ``clean.json`` only after it
finished and verified, and each kill point in ``kill-NN.json`` only once it is decided (both written to a
temporary name and renamed); a rerun of this script with the same options reuses the clean run and the kill points
that passed, and redoes anything else (``--fresh=true`` starts over: do so after changing sigma, since a recorded
clean run is matched by its options only). A passed kill point's directory is deleted
(``--keep=true`` keeps it); a failed one is kept for inspection. Prints one line per kill point and a summary;
exits 1 if any kill point failed, 2 if the clean run itself failed.
"""

from __future__ import annotations

import contextlib
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import draccus

# Siblings under scripts/ (on sys.path when this file runs as a script; tests/scripts/script_module.py adds it).
import process_group
from collection_compare import Comparison, compare_trees, files_under, video_frames
from process_group import describe, end_group, log_tail, processes_of, survivors

os.environ.setdefault("HF_HUB_OFFLINE", "1")

TARGETS = ("group", "parent", "alternate")
# How long the processes of a killed run may take to end.
ORPHAN_WAIT_S = 15.0


@dataclass
class FaultInjectionConfig:
    """Options of ``scripts/fault_injection.py``."""

    # Kill points: each one is a fresh collection killed at a random time, then rerun and compared.
    kills: int = 20
    # Seed of the kill times (uniform over the clean run's wall time).
    seed: int = 0
    # What SIGKILL hits: "group" (the collection's process group: the parent and its helpers), "parent" (only the
    # parent: its helpers must end by themselves) or "alternate" (group on even kill points, parent on odd).
    target: str = "group"
    # Where the clean run, the kill points' directories and the results go.
    output_dir: Path = Path("outputs/fault_injection")
    # The collection (sigma-data collect's options of the same names): --tasks.
    tasks: str = "lift"
    # --episodes (seeds per variation).
    episodes: int = 4
    # --shard_size (seeds per shard, the unit of resume).
    shard_size: int = 1
    # --render.cameras.
    cameras: str = "agentview"
    # --render.height and --render.width.
    size: int = 32
    # --workers (this process and workers - 1 helpers).
    workers: int = 2
    # --render_threads: 1 is exact to the pixel (docs/robosuite.md §2); more threads may differ in rare depth
    # pixels between runs.
    render_threads: int = 1
    # --output.dense: write the dense dataset (videos) besides the keyframe dataset.
    dense: bool = True
    # Seconds a collection may run before it counts as hung.
    timeout_s: float = 900.0
    # Keep the directories of the kill points that passed (a failed one is always kept).
    keep: bool = False
    # Start over: delete this script's earlier clean run and results in output_dir.
    fresh: bool = False

    def __post_init__(self) -> None:
        if self.target not in TARGETS:
            raise ValueError(f"--target must be one of {', '.join(TARGETS)}, got {self.target!r}")
        if self.kills < 0:
            raise ValueError(f"--kills must be >= 0, got {self.kills}")

    def collect_args(self, out: Path) -> list[str]:
        """The ``sigma-data`` arguments of the collection, into ``out``."""
        return [
            "collect",
            f"--tasks={self.tasks}",
            f"--episodes={self.episodes}",
            f"--shard_size={self.shard_size}",
            f"--render.cameras={self.cameras}",
            f"--render.height={self.size}",
            f"--render.width={self.size}",
            f"--workers={self.workers}",
            f"--render_threads={self.render_threads}",
            f"--output.dense={str(self.dense).lower()}",
            f"--output.dir={out}",
            "--progress=false",
        ]

    def collection(self) -> dict[str, Any]:
        """What decides the clean run (a recorded clean run is reused only with the same)."""
        keys = ("tasks", "episodes", "shard_size", "cameras", "size", "workers", "render_threads", "dense")
        return {k: getattr(self, k) for k in keys}

    def target_of(self, point: int) -> str:
        if self.target == "alternate":
            return "group" if point % 2 == 0 else "parent"
        return self.target


# ---------------------------------------------------------------------------------------------------------------
# Files written whole or not at all


def write_json(path: Path, data: Any) -> None:
    """``path`` written whole or not at all (sigma_data/files.py): a kill leaves the old file or none."""
    from sigma_data.files import write_json_atomic

    write_json_atomic(path, data)


def read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    else:
        path.unlink(missing_ok=True)


# ---------------------------------------------------------------------------------------------------------------
# The collection as a process


def sigma_data_command() -> list[str]:
    script = Path(sys.executable).with_name("sigma-data")
    return [str(script)] if script.exists() else [sys.executable, "-m", "sigma_data.cli"]


def offline_env() -> dict[str, str]:
    """This process's environment with the Hugging Face hub offline (a collection never downloads)."""
    return {**os.environ, "HF_HUB_OFFLINE": "1"}


def start(args: list[str], log: Path) -> subprocess.Popen:
    """``sigma-data args`` in its own process group, output to ``log`` (scripts/process_group.py)."""
    return process_group.start(sigma_data_command() + args, log, offline_env())


def run_to_end(args: list[str], log: Path, timeout_s: float) -> tuple[int | None, float, list[str]]:
    """``sigma-data args`` run to completion (scripts/process_group.py)."""
    return process_group.run_to_end(sigma_data_command() + args, log, timeout_s, offline_env())


# ---------------------------------------------------------------------------------------------------------------
# Checking a collection


def collect_config(cfg: FaultInjectionConfig, out: Path) -> Any:
    """The ``CollectConfig`` the collection's command line parses to (what ``sigma-data collect`` runs with)."""
    from sigma_data.collect import CollectConfig

    return draccus.parse(config_class=CollectConfig, args=cfg.collect_args(out)[1:])


def shard_states(cfg: FaultInjectionConfig, out: Path) -> dict[str, str]:
    """Each shard directory under ``out/shards`` -> "" if a rerun may reuse it (``check_shard`` verifies it), else
    why it must be redone."""
    from sigma_data.collect import check_shard

    ccfg = collect_config(cfg, out)
    states = {}
    for shard in sorted(p for p in (out / "shards").glob("*") if p.is_dir()):
        result, why = check_shard(shard, ccfg)
        states[shard.name] = "" if result is not None else (why or "not a shard")
    return states


def check_clean(cfg: FaultInjectionConfig, clean: Path) -> list[str]:
    """Problems of the clean run: a dataset that does not validate, a video that does not decode to its frame
    count, a shard that does not verify, a file left under a temporary name."""
    from sigma_data.validate import ValidateConfig, validate_dataset

    problems = []
    kinds = ["dense", "keyframe"] if cfg.dense else ["keyframe"]
    for kind in kinds:
        root = clean / kind
        if not root.is_dir():
            problems.append(f"the clean run wrote no {kind} dataset")
            continue
        report = validate_dataset(ValidateConfig(root=root))
        if report.num_errors:
            problems.append(
                f"clean {kind} dataset: {report.num_errors} validation error(s)\n{report.table()}"
            )
        # A video file per camera stream and chunk: together they hold every frame of the dataset.
        info = json.loads((root / "meta" / "info.json").read_text())
        for key, feature in info["features"].items():
            if feature.get("dtype") != "video":
                continue
            frames = sum(len(video_frames(p)) for p in sorted((root / "videos" / key).rglob("*.mp4")))
            if frames != info["total_frames"]:
                problems.append(
                    f"clean {kind} {key}: {frames} decoded frames, {info['total_frames']} recorded"
                )
    for name, why in shard_states(cfg, clean).items():
        if why:
            problems.append(f"clean shard {name} does not verify: {why}")
    problems += [f"left under a temporary name: {p}" for p in files_under(clean) if "/." in f"/{p}"]
    return problems


# ---------------------------------------------------------------------------------------------------------------
# The clean run and one kill point


def clean_run(cfg: FaultInjectionConfig) -> dict[str, Any]:
    """The recorded clean run (reused when recorded with the same collection options), else run it now."""
    out, record = cfg.output_dir / "clean", cfg.output_dir / "clean.json"
    stored = read_json(record)
    if isinstance(stored, dict) and stored.get("collection") == cfg.collection() and out.is_dir():
        print(f"clean run: recorded in {record} ({stored['wall_s']:.1f} s), reused", flush=True)
        return stored
    record.unlink(missing_ok=True)
    if out.exists():
        shutil.rmtree(out)
    log = cfg.output_dir / "clean.log"
    print(f"clean run: sigma-data {' '.join(cfg.collect_args(out))}", flush=True)
    rc, wall, left = run_to_end(cfg.collect_args(out), log, cfg.timeout_s)
    if rc != 0:
        print(f"the clean run failed (exit {rc}, see {log}):\n{log_tail(log)}", file=sys.stderr)
        raise SystemExit(2)
    problems = check_clean(cfg, out) + [f"still running after it exited: {p}" for p in left]
    if problems:
        print("the clean run is not a reference:\n" + "\n".join(problems), file=sys.stderr)
        raise SystemExit(2)
    summary = log_tail(log, 1)
    stored = {"collection": cfg.collection(), "wall_s": wall, "summary": summary}
    write_json(record, stored)
    print(f"clean run: {wall:.1f} s, validated, videos decode: {summary}", flush=True)
    return stored


def kill_times(cfg: FaultInjectionConfig, wall_s: float) -> list[float]:
    """The kill points, seconds after the start, uniform over the clean run's wall time (the first n are the same
    for any ``--kills`` >= n)."""
    rng = random.Random(cfg.seed)
    return [rng.uniform(0.0, wall_s) for _ in range(cfg.kills)]


def _where(states: dict[str, str], n_shards: int, run: Path, exited: bool) -> str:
    """Where the kill landed, from what the killed run left on disk."""
    if exited:
        return "the run had already finished"
    verified = sum(not why for why in states.values())
    where = f"{verified}/{n_shards} shards finished"
    partial = len(states) - verified
    if partial:
        where += f", {partial} interrupted"
    merged = [k for k in ("dense", "keyframe") if (run / k).is_dir()]
    merging = [k for k in ("dense", "keyframe") if (run / f".{k}.merging").exists()]
    if merged:
        where += f", {'+'.join(merged)} merged"
    if merging:
        where += f", merging {'+'.join(merging)}"
    if not (run / "collect.json").exists():
        where += ", no collect.json yet"
    return where


def kill_point(cfg: FaultInjectionConfig, point: int, at_s: float, clean: Path) -> dict[str, Any]:
    """Start the collection in a fresh directory, SIGKILL it ``at_s`` seconds in, check what it left, rerun it to
    completion and compare with ``clean``. Returns the kill point's record (``problems`` empty if it passed)."""
    from sigma_data.collect import plan_shards

    base = cfg.output_dir / f"kill-{point:02d}"
    if base.exists():
        shutil.rmtree(base)
    base.mkdir(parents=True)
    run = base / "run"
    args = cfg.collect_args(run)
    target = cfg.target_of(point)
    problems: list[str] = []
    record: dict[str, Any] = {"point": point, "at_s": at_s, "target": target, "seed": cfg.seed}

    # 1. Start, wait, kill.
    t0 = time.monotonic()
    proc = start(args, base / "killed.log")
    try:
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout=max(0.0, t0 + at_s - time.monotonic()))
        exited = proc.poll() is not None
        if exited and proc.returncode != 0:
            problems.append(
                f"the run failed before the kill (exit {proc.returncode}):\n{log_tail(base / 'killed.log')}"
            )
        members = processes_of(proc.pid)
        if not exited:
            if target == "group":
                os.killpg(proc.pid, signal.SIGKILL)
            else:
                os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        left = survivors(members, proc.pid, wait_s=ORPHAN_WAIT_S)
        if left:
            problems.append(f"processes outlived the kill: {'; '.join(describe(p) for p in left)}")
    finally:
        end_group(proc)  # survivors (already counted) end here, so that the rerun starts alone
    record["killed_after_s"] = time.monotonic() - t0
    record["processes"] = len(members)

    # 2. What the killed run left: nothing partial at a final path, and which shards a rerun may trust.
    for kind in ("dense", "keyframe"):
        if (run / kind).exists():
            partial = compare_trees(clean / kind, run / kind)
            problems += [f"killed run's {kind}: {p}" for p in partial.problems]
    if (run / "collect.json").exists() and read_json(run / "collect.json") is None:
        problems.append("the killed run left a collect.json that does not read")
    states = shard_states(cfg, run) if (run / "shards").is_dir() else {}
    record["where"] = _where(states, len(plan_shards(collect_config(cfg, run))), run, exited)

    # 3. Rerun to completion.
    rc, wall, still = run_to_end(args, base / "rerun.log", cfg.timeout_s)
    record["rerun_s"] = wall
    if rc != 0:
        what = "hung" if rc is None else f"exit {rc}"
        problems.append(f"the rerun failed ({what}):\n{log_tail(base / 'rerun.log')}")
    problems += [f"still running after the rerun exited: {p}" for p in still]

    # 4. The rerun trusted exactly the shards that verified, and redid the others saying why.
    reused = redone = new = 0
    stored = read_json(run / "collect.json") if rc == 0 else None
    if rc == 0 and not (isinstance(stored, dict) and isinstance(stored.get("shards"), list)):
        problems.append("the rerun's collect.json does not read")
    elif rc == 0:
        for shard in stored["shards"]:
            name, why = shard["name"], states.get(shard["name"])
            if why == "":  # verified after the kill: must be reused as it was
                reused += 1
                if not shard.get("skipped"):
                    problems.append(f"shard {name} verified after the kill but the rerun did not reuse it")
            elif why is not None:  # left partial or damaged: must be redone, with the reason said
                redone += 1
                if shard.get("skipped"):
                    problems.append(f"the rerun reused shard {name}, which did not verify ({why})")
                elif not shard.get("redone"):
                    problems.append(f"the rerun redid shard {name} without saying why")
            else:
                new += 1
                if shard.get("skipped") or shard.get("redone"):
                    problems.append(
                        f"shard {name} was not on disk, yet the rerun reports it reused or redone"
                    )
        unverified = [f"{n} ({w})" for n, w in shard_states(cfg, run).items() if w]
        problems += [f"after the rerun, shard {u} does not verify" for u in unverified]
    record["rerun"] = {"reused": reused, "redone": redone, "new": new}

    # 5. The same files as the clean run.
    comparison = compare_trees(clean, run) if rc == 0 else Comparison()
    problems += comparison.problems
    record["comparison"] = asdict(comparison)
    record["compared"] = comparison.line()
    record["problems"] = problems
    return record


def point_line(record: dict[str, Any], total: int, wall_s: float, recorded: bool = False) -> str:
    r = record["rerun"]
    head = (
        f"kill {record['point'] + 1:>2}/{total} at {record['at_s']:5.1f} s of {wall_s:.1f} ({record['target']}): "
        f"{record['where']} | rerun {record.get('rerun_s', 0.0):.1f} s: {r['reused']} reused, {r['redone']} redone, "
        f"{r['new']} new | "
    )
    if record["problems"]:
        tail = "FAILED:\n  " + "\n  ".join(p.replace("\n", "\n    ") for p in record["problems"])
    else:
        tail = f"equal to the clean run ({record['compared']}), no orphans"
    return head + tail + (" [recorded]" if recorded else "")


def main(cfg: FaultInjectionConfig) -> int:
    out = cfg.output_dir
    if cfg.fresh:
        for path in [out / "clean", out / "clean.json", out / "clean.log", out / "results.json"]:
            if path.exists():
                remove(path)
        for path in [*out.glob("kill-*")]:
            remove(path)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    clean = clean_run(cfg)
    wall = clean["wall_s"]
    records = []
    for point, at in enumerate(kill_times(cfg, wall)):
        path = out / f"kill-{point:02d}.json"
        stored = read_json(path)
        key = {"collection": cfg.collection(), "at_s": at, "target": cfg.target_of(point), "seed": cfg.seed}
        if isinstance(stored, dict) and stored.get("key") == key and not stored["record"]["problems"]:
            records.append(stored["record"])
            print(point_line(stored["record"], cfg.kills, wall, recorded=True), flush=True)
            continue
        path.unlink(missing_ok=True)
        record = kill_point(cfg, point, at, out / "clean")
        write_json(path, {"key": key, "record": record})
        if not record["problems"] and not cfg.keep:
            shutil.rmtree(out / f"kill-{point:02d}", ignore_errors=True)
        records.append(record)
        print(point_line(record, cfg.kills, wall), flush=True)
    passed = sum(not r["problems"] for r in records)
    landed = sum(r["where"] != "the run had already finished" for r in records)
    write_json(
        out / "results.json", {"collection": cfg.collection(), "clean_wall_s": wall, "points": records}
    )
    verdict = "rerun equal to the clean run" if passed == len(records) else "FAILED"
    print(
        f"{passed}/{len(records)} kill points: {verdict} ({landed} killed mid-run, {cfg.target} kills, "
        f"seed {cfg.seed}, {time.monotonic() - t0:.0f} s; details in {out / 'results.json'})",
        flush=True,
    )
    return 0 if passed == len(records) else 1


if __name__ == "__main__":
    code = main(draccus.parse(config_class=FaultInjectionConfig, args=sys.argv[1:]))
    # Everything is written and printed by now. Leave without the interpreter's teardown: pyarrow's thread pool
    # (the parquet reads of the comparison and the validation) can still be joinable when the C++ runtime's
    # static destructors run, which aborts an otherwise finished run with SIGABRT and "terminate called without an
    # active exception" (https://github.com/apache/arrow/issues/34314; seen once in a CI run of this script).
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
