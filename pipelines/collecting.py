"""Scripted-expert demonstrations for a pipeline (``sigma-ablate``, ``sigma-compare``): one resumable
``sigma-data collect`` into ``<output_dir>/data``, its summary line printed, an empty collection an error."""

from __future__ import annotations

from pathlib import Path
from typing import Any


def collect_demonstrations(
    output_dir: Path,
    tasks: list[str],
    episodes: int,
    cameras: list[str],
    image_size: int,
    workers: int,
    repo_id: str,
    start_seed: int = 0,
    **output: Any,
) -> dict[str, Path]:
    """Collect ``episodes`` seeds per variation of ``tasks`` (from ``start_seed``); ``output`` are further
    ``--output.*`` fields (``dense=False``, ``dense_depth=False``...). Returns the written datasets by kind."""
    from sigma_data.cameras import RenderOptions
    from sigma_data.collect import CollectConfig, CollectOutputConfig, collect

    summary = collect(
        CollectConfig(
            tasks=",".join(tasks),
            episodes=episodes,
            start_seed=start_seed,
            output=CollectOutputConfig(dir=Path(output_dir) / "data", repo_id=repo_id, **output),
            render=RenderOptions(cameras=",".join(cameras), height=image_size, width=image_size),
            workers=workers,
            progress=False,
        )
    )
    print(summary.line(), flush=True)
    if summary.kept == 0:
        raise RuntimeError("the experts produced no successful episode; nothing to train on")
    return dict(summary.outputs)
