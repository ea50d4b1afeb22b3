"""Running the shards of a collection in this process and ``workers - 1`` spawned helper processes
(:class:`Helpers`, :func:`_run_processes`).

Each shard is written by one process; a process builds one env per task and reuses it for all its shards
(:mod:`sigma_data.collect.envs`). Helpers never outlive this process
(:mod:`sigma_data.collect.lifetime`): a shard a helper was writing when it died has no marker and the next run
redoes it.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import queue
import threading
from collections import deque
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from sigma_data.cameras import RenderConfig
from sigma_data.collect.config import CollectConfig, ShardResult, ShardSpec
from sigma_data.collect.envs import cached_env, check_cameras_exist
from sigma_data.collect.lifetime import exit_with_parent
from sigma_data.collect.shard import collect_shard

# A helper's end of the progress queue (one item per episode done), set by its initializer.
_PROGRESS: Any = None


def _warm_up(parent: int, progress: Any, task_name: str, render: RenderConfig, model_seed: int) -> None:
    """A helper's first act: tie its life to ``parent``'s, keep the progress queue, then the imports and the env
    its first shard needs (seconds that would otherwise be spent inside that shard). A failure of the imports or
    the env is left for the shard itself to report."""
    global _PROGRESS
    exit_with_parent(parent)
    _PROGRESS = progress
    import sigma_data  # noqa: F401  (headless GL before robosuite in a fresh process)

    with contextlib.suppress(Exception):
        import lerobot.datasets.lerobot_dataset  # noqa: F401  (~5 s: LeRobot imports transformers, torchvision)

        cached_env(task_name, render, model_seed)


def _worker(spec: ShardSpec, cfg: CollectConfig, shard_dir: Path) -> ShardResult:
    import sigma_data  # noqa: F401  (headless GL before robosuite in a fresh process)

    progress = _PROGRESS
    return collect_shard(spec, cfg, shard_dir, on_episode=(lambda: progress.put(1)) if progress else None)


class Helpers:
    """``n`` spawned helper processes for a run, started as soon as the run knows it has work for them, so
    their start-up (interpreter, imports, env: ~8 s) overlaps this process's own; they exit while this process
    merges the shards. Spawned, not forked: no inherited GL contexts or MuJoCo state. Their progress comes back
    through a plain queue handed to them as they start (no Manager process that could outlive this one)."""

    def __init__(self, n: int, cfg: CollectConfig, first_task: str) -> None:
        ctx = mp.get_context("spawn")
        self.progress = ctx.Queue()
        self.pool = ProcessPoolExecutor(
            max_workers=n,
            mp_context=ctx,
            initializer=_warm_up,
            initargs=(os.getpid(), self.progress, first_task, cfg.render.config(), cfg.model_seed),
        )
        self.n = n
        # One trivial job per helper: the pool spawns its processes now, not at the first shard.
        for _ in range(n):
            self.pool.submit(int)

    def release(self) -> None:
        """No more shards: the helpers exit in the background (call :meth:`close` later to reap them)."""
        self.pool.shutdown(wait=False, cancel_futures=True)

    def close(self) -> None:
        self.pool.shutdown(wait=True, cancel_futures=True)
        self.progress.close()


def _run_processes(
    todo: list[ShardSpec], cfg: CollectConfig, shards_dir: Path, pbar: Any, helpers: Helpers | None
) -> list[ShardResult]:
    """Collect ``todo`` with this process and the spawned ``helpers``.

    Shards are handed out one at a time: each helper gets the next one from the front of the queue when it is
    free (a feeder thread per helper), while this process starts at once and takes shards from the back. A
    shard that raises stops the hand-out and the error is re-raised; finished shards stay for a rerun.
    """
    tasks = list(dict.fromkeys(s.task for s in todo))

    def run_here(spec: ShardSpec, after_episode: Callable[[], None]) -> ShardResult:
        return collect_shard(spec, cfg, shards_dir / spec.name, on_episode=after_episode)

    if helpers is None:
        check_cameras_exist(cfg, tasks, reuse=True)  # this process's envs, built once per task
        return [run_here(s, lambda: pbar.update(1)) for s in todo]

    pending = deque(todo)
    lock = threading.Lock()
    results: dict[str, ShardResult] = {}
    errors: list[BaseException] = []
    pool, progress = helpers.pool, helpers.progress

    def feed() -> None:  # keeps one helper busy until the queue is empty or a shard failed
        while True:
            with lock:
                if errors or not pending:
                    return
                spec = pending.popleft()
            try:
                results[spec.name] = pool.submit(_worker, spec, cfg, shards_dir / spec.name).result()
            except BaseException as exc:
                with lock:
                    errors.append(exc)
                return

    def tick() -> None:  # progress of every process; stop on a helper's error
        pbar.update(1)
        with contextlib.suppress(queue.Empty):
            while True:
                pbar.update(progress.get_nowait())
        if errors:
            raise errors[0]

    feeders = [threading.Thread(target=feed, daemon=True) for _ in range(helpers.n)]
    for t in feeders:
        t.start()
    try:
        check_cameras_exist(cfg, tasks, reuse=True)  # while the helpers start (seconds of imports)
        while True:
            with lock:
                if errors or not pending:
                    break
                spec = pending.pop()
            results[spec.name] = run_here(spec, tick)
        while any(t.is_alive() for t in feeders):
            with contextlib.suppress(queue.Empty):
                pbar.update(progress.get(timeout=0.2))
        if errors:
            raise errors[0]
    except BaseException:
        with lock:
            pending.clear()  # helpers finish their current shard and stop
        raise
    with contextlib.suppress(queue.Empty):
        while True:
            pbar.update(progress.get_nowait())
    # A helper's last ticks may still be in its queue's feeder thread: every episode of ``todo`` is done.
    if pbar.total is not None and pbar.n < pbar.total:
        pbar.update(pbar.total - pbar.n)
    return [results[s.name] for s in todo]
