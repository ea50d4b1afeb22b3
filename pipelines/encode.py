"""``sigma-encode``: the instructions' text features in one file, for a machine without the text encoder.

A sigma policy reads each instruction through a frozen text encoder (the packaged MiniLM by default). Where that
encoder cannot be installed or loaded (a robot's computer, a GPU machine with no network), a feature table written
here stands in for it: with ``SIGMA_TEXT_FEATURES=FILE`` in the environment, ``lerobot-train``, ``sigma-eval`` and
every other tool that builds a policy read the features from the file and never load the model
(sigma_policy/text_encoder.py). The table holds exactly the encoder's outputs, so a policy trained with it is the
policy trained without it.

Which instructions: every instruction and paraphrase of the registered tasks named by ``--tasks`` (default: all of
them, sigma_data/suite.py), the task strings of the datasets given as ``--dataset_root`` (their
``meta/tasks.parquet``), and ``--instructions``. An instruction missing from the table is refused by name when a
policy meets it.

Example::

    sigma-encode --output outputs/text_features.safetensors
    sigma-encode --tasks '[]' --dataset_root '[outputs/sigma_data/keyframe]' --output features.safetensors
    SIGMA_TEXT_FEATURES=outputs/text_features.safetensors lerobot-train --policy.type=sigma ...
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path

import draccus


@dataclass
class EncodeConfig:
    # Where the table is written (safetensors; replaced atomically).
    output: Path = Path("outputs/text_features.safetensors")
    # Registered tasks whose instructions and paraphrases are encoded ('[all]', '[lift,stack]', '[]' for none).
    tasks: list[str] = field(default_factory=lambda: ["all"])
    # LeRobot datasets whose task strings (meta/tasks.parquet) are encoded too.
    dataset_root: list[Path] = field(default_factory=list)
    # Further instructions, verbatim.
    instructions: list[str] = field(default_factory=list)
    # The encoder, as the policy's --policy.text_encoder / --policy.text_encoder_path name it.
    text_encoder: str = "minilm"
    text_encoder_path: str | None = None


def dataset_instructions(root: Path) -> list[str]:
    """The task strings of a LeRobot v3 dataset, in its task-index order."""
    import pandas as pd
    from lerobot.datasets.utils import DEFAULT_TASKS_PATH

    path = Path(root) / DEFAULT_TASKS_PATH
    if not path.is_file():
        raise ValueError(f"{root}: not a LeRobot v3 dataset ({path} is missing)")
    tasks = pd.read_parquet(path)
    return [str(s) for s in tasks.sort_values("task_index").index]


def collect_instructions(cfg: EncodeConfig) -> list[str]:
    """Every instruction ``cfg`` names, each once, in the order named."""
    from sigma_data.suite import expand_tasks, get_task, get_variation

    out: list[str] = []
    if cfg.tasks:
        for task, variation in expand_tasks(cfg.tasks):
            out += get_variation(get_task(task), variation).instructions
    for root in cfg.dataset_root:
        out += dataset_instructions(root)
    out += cfg.instructions
    return list(dict.fromkeys(out))


def main(argv: list[str] | None = None) -> int:
    cfg = draccus.parse(EncodeConfig, args=sys.argv[1:] if argv is None else argv)
    from sigma_policy.text_encoder import TEXT_FEATURES_ENV, make_text_encoder, save_text_features

    try:
        instructions = collect_instructions(cfg)
        if not instructions:
            raise ValueError("no instructions to encode: name --tasks, --dataset_root or --instructions")
        # The table comes from the encoder itself, never from another table.
        encoder = make_text_encoder(cfg.text_encoder, cfg.text_encoder_path, allow_table=False)
        path = save_text_features(encoder, instructions, cfg.output)
    except (ValueError, OSError) as e:
        print(f"sigma-encode: {e}", file=sys.stderr)
        return 1
    print(
        f"sigma-encode: {len(instructions)} instructions, {encoder.identity}, tokens "
        f"{encoder.max_length} x {encoder.token_dim} -> {path} ({path.stat().st_size / 1e6:.1f} MB); "
        f"use it with {TEXT_FEATURES_ENV}={path}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
