"""Collect scripted-expert demonstrations into the dense and keyframe LeRobot datasets (``sigma-data collect``).

Work is cut into shards of seeds (``shard_size`` seeds of one task variation). Each shard is written by one
worker process into ``<output.dir>/shards/<name>/{dense,keyframe}`` and ends with a ``shard.json`` marker that
lists the files it wrote; the shards are then merged with LeRobot's ``aggregate_datasets`` into
``<output.dir>/{dense,keyframe}`` (a single shard is copied).

* Rerunning reuses the shards whose marker matches the configuration and whose recorded files are intact (size,
  SHA-256, parquet row counts) and load with the recorded episode counts; anything else (an interrupted or
  damaged shard, or one from before markers listed files) is deleted and redone, with one warning per shard
  saying why. The merge is redone every run.
* Same configuration and seeds give identical data: the model (e.g. Lift's random cube size, drawn when the
  env is built) is built under ``model_seed``, every episode under its own seed.
* ``workers - 1`` helper processes collect beside this one and exit when it does, however it ends.
* ``executor = "datatrove"`` runs the same shards through DataTrove's ``LocalPipelineExecutor``
  (:mod:`sigma_data.collect.datatrove`; on a Slurm cluster its step runs under ``SlurmPipelineExecutor``, see
  ``docs/cluster.md``); it needs the optional extra ``cluster`` (``datatrove``).

Modules, one concept each (each imports only those above it; ``run`` imports ``datatrove`` only for that
executor):

* :mod:`~sigma_data.collect.config`: the options (:class:`CollectConfig`), shards, results and run summary.
* :mod:`~sigma_data.collect.manifest`: the files a finished shard recorded, and the check that they are intact.
* :mod:`~sigma_data.collect.planning`: the shards of a run, claiming ``output.dir``, which shards to reuse.
* :mod:`~sigma_data.collect.envs`: this process's envs and render threads, reused across its shards.
* :mod:`~sigma_data.collect.shard`: one shard: record, filter, render, write, mark.
* :mod:`~sigma_data.collect.scheduler`: the shards over this process and its spawned helpers.
* :mod:`~sigma_data.collect.merge`: the shards merged into one dataset per kind.
* :mod:`~sigma_data.collect.datatrove`: the shards as a DataTrove pipeline step (optional extra).
* :mod:`~sigma_data.collect.run`: a whole collection, :func:`collect`.
"""

from __future__ import annotations

from sigma_data.collect.config import (
    DATASETS,
    MARKER,
    RECORD,
    RUN_OPTIONS,
    CollectConfig,
    CollectOutputConfig,
    CollectSummary,
    ShardResult,
    ShardSpec,
)
from sigma_data.collect.envs import build_env, cached_env, cached_replay, check_cameras_exist, close_envs
from sigma_data.collect.manifest import shard_files
from sigma_data.collect.merge import merge_shards
from sigma_data.collect.planning import (
    check_shard,
    claim_output_dir,
    finished_shard,
    option_changes,
    plan_shards,
)
from sigma_data.collect.run import collect
from sigma_data.collect.scheduler import Helpers
from sigma_data.collect.shard import collect_shard

__all__ = [
    "DATASETS",
    "MARKER",
    "RECORD",
    "RUN_OPTIONS",
    "CollectConfig",
    "CollectOutputConfig",
    "CollectSummary",
    "Helpers",
    "ShardResult",
    "ShardSpec",
    "build_env",
    "cached_env",
    "cached_replay",
    "check_cameras_exist",
    "check_shard",
    "claim_output_dir",
    "close_envs",
    "collect",
    "collect_shard",
    "finished_shard",
    "merge_shards",
    "option_changes",
    "plan_shards",
    "shard_files",
]
