"""Scripted-expert demonstrations for a pipeline (``sigma-ablate``, ``sigma-compare``, the benchmarks): one
resumable ``sigma-data collect`` into ``<output_dir>/data``, its summary line printed, an empty collection an error.
Tasks are named as ``sigma-eval`` names them: ``"pick_place"`` (every variation) or ``"pick_place:bread"`` (one)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from sigma_data.collect import CollectConfig


def demonstration_config(
    output_dir: Path,
    tasks: list[str],
    episodes: int,
    cameras: list[str],
    image_size: int,
    workers: int,
    repo_id: str,
    start_seed: int = 0,
    pregrasp_jitter_m: float = 0.0,
    **output: Any,
) -> CollectConfig:
    """The ``sigma-data collect`` options of ``episodes`` seeds per variation of ``tasks`` (from ``start_seed``; the
    experts' approach waypoints moved by up to ``pregrasp_jitter_m``) into ``output_dir``/data; ``output`` are
    further ``--output.*`` fields (``dense=False``, ``dense_depth=False``...)."""
    from sigma_data.cameras import RenderOptions
    from sigma_data.collect import CollectConfig, CollectOutputConfig

    names, variations = split_variations(tasks)
    return CollectConfig(
        tasks=",".join(names),
        variations=variations,
        episodes=episodes,
        start_seed=start_seed,
        output=CollectOutputConfig(dir=Path(output_dir) / "data", repo_id=repo_id, **output),
        render=RenderOptions(cameras=",".join(cameras), height=image_size, width=image_size),
        workers=workers,
        pregrasp_jitter_m=pregrasp_jitter_m,
        progress=False,
    )


def collect_demonstrations(*args: Any, **kwargs: Any) -> dict[str, Path]:
    """Collect what :func:`demonstration_config` describes (the same arguments), printing the summary line. Returns
    the written datasets by kind; an empty collection raises ``RuntimeError``."""
    from sigma_data.collect import collect

    summary = collect(demonstration_config(*args, **kwargs))
    print(summary.line(), flush=True)
    if summary.kept == 0:
        raise RuntimeError("the experts produced no successful episode; nothing to train on")
    return dict(summary.outputs)


def split_variations(tasks: list[str]) -> tuple[list[str], str]:
    """``sigma-data collect``'s ``--tasks`` and ``--variations`` for task specs like ``["lift", "pick_place:bread"]``
    (:func:`sigma_data.suite.expand_tasks`): the task names in order, and ``"all"`` or the comma-separated variations
    (every variation of a task named without one). An unknown task or variation raises ``ValueError``."""
    from sigma_data.suite import expand_tasks

    pairs = expand_tasks(tasks)
    names = list(dict.fromkeys(task for task, _ in pairs))
    if all(":" not in spec for spec in tasks):
        return names, "all"
    return names, ",".join(variation for _, variation in pairs)
