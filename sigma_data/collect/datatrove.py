"""Collection shards as a DataTrove pipeline step, for clusters (optional extra ``cluster``: ``datatrove``).

:class:`CollectShards` runs :func:`sigma_data.collect.shard.collect_shard` for the shards of a collection under
any DataTrove executor: task ``rank`` of ``world_size`` takes shards ``rank, rank + world_size, ...``.
``sigma-data collect --executor=datatrove`` runs it with ``LocalPipelineExecutor`` on this machine
(:func:`run_local`); on a Slurm cluster, run it with ``SlurmPipelineExecutor`` (one job array task per shard) and
then ``sigma-data collect`` with the same options, which reuses every finished shard that verifies and only
merges (``docs/cluster.md``). Shard markers, not DataTrove's completion files, decide what is done, so reruns
and mixed executors agree.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from datatrove.executor import LocalPipelineExecutor
from datatrove.pipeline.base import PipelineStep

from sigma_data.collect.config import CollectConfig, ShardResult, ShardSpec
from sigma_data.collect.envs import close_envs
from sigma_data.collect.lifetime import exit_with_parent
from sigma_data.collect.planning import finished_shard, plan_shards
from sigma_data.collect.shard import collect_shard


class CollectShards(PipelineStep):
    """DataTrove step collecting ``shards`` (default: every shard of ``config`` not finished yet) under
    ``<config.output.dir>/shards``."""

    name = "sigma-data collect"
    type = "robosuite"

    def __init__(self, config: CollectConfig, shards: list[ShardSpec] | None = None):
        super().__init__()
        self.config = config
        self.root = Path(config.output.dir) / "shards"
        if shards is None:
            shards = [s for s in plan_shards(config) if finished_shard(self.root / s.name, config) is None]
        self.shards = list(shards)
        self.started_by = os.getpid()

    def run(self, data: Any = None, rank: int = 0, world_size: int = 1) -> Any:
        import sigma_data  # noqa: F401  (headless GL before robosuite in a fresh process)

        if os.getpid() != self.started_by:
            # A pool worker (its parent: this collection's process)
            # or a cluster task: it ends with its parent rather than collect on its own.
            exit_with_parent(os.getppid())
        try:
            for spec in self.shards[rank::world_size]:
                collect_shard(spec, self.config, self.root / spec.name)
                self.stat_update("shards")
        finally:
            close_envs()
        return data


class _Anchor:
    """Keeps an after-fork hook registered (multiprocess holds it by weak reference)."""


def run_local(shards: list[ShardSpec], config: CollectConfig) -> list[ShardResult]:
    """Collect ``shards`` with DataTrove's ``LocalPipelineExecutor`` (``config.workers`` processes); raises if one
    is left unfinished."""
    import multiprocess.util  # DataTrove's multiprocessing

    root = Path(config.output.dir) / "shards"
    # The executor forks a Manager server before its pool: it ends with this process too (the pool workers tie
    # themselves to their parent in CollectShards.run). The hook lives as long as ``anchor``, i.e. this call.
    anchor, parent = _Anchor(), os.getpid()
    multiprocess.util.register_after_fork(anchor, lambda _: exit_with_parent(parent))
    LocalPipelineExecutor(
        pipeline=[CollectShards(config, shards)],
        tasks=len(shards),
        workers=config.workers,
        logging_dir=str(Path(config.output.dir) / "datatrove_logs"),
        skip_completed=False,  # shard markers decide what is done
        # Pool workers as children of this process (DataTrove's default, a forkserver, outlives a killed parent)
        # and fresh interpreters (no inherited GL contexts or MuJoCo state).
        start_method="spawn",
    ).run()
    results = [finished_shard(root / s.name, config) for s in shards]
    missing = [s.name for s, r in zip(shards, results, strict=True) if r is None]
    if missing:
        raise RuntimeError(
            f"datatrove run left shards unfinished: {missing} (logs in {config.output.dir}/datatrove_logs)"
        )
    for r in results:
        r.skipped = False
    return results
