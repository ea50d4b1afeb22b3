"""The keyframes a sigma checkpoint is scored on (``sigma-diagnose``, ``pipelines/diagnostics.py``, and the probes
in ``benchmarks/``).

A :class:`KeyframeSet` is the frames of a keyframe dataset that have a goal (every frame but each episode's last: frame
k predicts keyframe k + 1), with their keyframe step. The training set is the dataset and episodes the checkpoint's
``train_config.json`` names (or ``--root``); the held-out set is another dataset (``--heldout_root``) or the
training dataset's episodes the run did not train on. :func:`scored_data` names both by their roots, episodes and a
digest of each dataset's ``meta/``, so a saved score can be matched to the data it was taken on. :func:`row_labels`
reads what sigma recorded for each row's episode (task, variation) from ``meta/sigma.json``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pipelines.gripper_swap import GripperPair
from pipelines.instruction_swap import SwapScene
from sigma_data.contract import SIDECAR, read_sidecar
from sigma_data.files import tree_sha256


@dataclass
class KeyframeSet:
    """Frames of a keyframe dataset that have a goal, with their recorded actions and keyframe step."""

    name: str
    dataset: Any  # LeRobotDataset
    indices: list[int]  # dataset rows
    steps: np.ndarray  # keyframe step within the episode (frame_index)
    episodes: list[int] | None = None  # the dataset episodes it covers (None = all)
    swap: list[SwapScene] = field(default_factory=list)  # scenes for the instruction-swap check
    gripper: list[GripperPair] = field(default_factory=list)  # frame pairs for the gripper-swap check


def goal_rows(
    dataset: Any, episodes: list[int] | None = None, max_frames: int = 0
) -> tuple[list[int], list[int]]:
    """Rows of ``dataset`` (restricted to ``episodes``) except each episode's last frame; evenly thinned to
    ``max_frames``. Returns (rows, their frame index in the episode)."""
    eps = dataset.meta.episodes
    rows, steps = [], []
    wanted = None if episodes is None else set(episodes)
    for ep in range(len(eps)):
        index = int(eps["episode_index"][ep])
        if wanted is not None and index not in wanted:
            continue
        start, stop = int(eps["dataset_from_index"][ep]), int(eps["dataset_to_index"][ep])
        for k, row in enumerate(range(start, stop - 1)):
            rows.append(row)
            steps.append(k)
    if max_frames and len(rows) > max_frames:
        keep = np.linspace(0, len(rows) - 1, max_frames).round().astype(int)
        rows, steps = [rows[i] for i in keep], [steps[i] for i in keep]
    return rows, steps


def open_dataset(root: Path, depth_unit: str = "mm") -> Any:
    """A sigma keyframe dataset read by stock LeRobot, depth in ``depth_unit`` (the checkpoint's
    ``policy.depth_unit``; LeRobot's default is mm)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    if not (Path(root) / "meta" / "info.json").exists():
        raise FileNotFoundError(f"{root} is not a LeRobot dataset (no meta/info.json)")
    return LeRobotDataset(
        f"local/{Path(root).name}", root=root, video_backend="pyav", depth_output_unit=depth_unit
    )


def trained_episodes(checkpoint: Path) -> tuple[Path | None, list[int] | None]:
    """The dataset root and episode subset recorded in a checkpoint's ``train_config.json``."""
    path = Path(checkpoint) / "train_config.json"
    if not path.exists():
        return None, None
    ds = json.loads(path.read_text()).get("dataset", {})
    root = ds.get("root")
    return (Path(root) if root else None), ds.get("episodes")


def training_data(checkpoint: Path, root: Path | None = None) -> tuple[Path, list[int] | None]:
    """The training dataset's root (``root``, or the one the checkpoint's ``train_config.json`` names) and the
    episodes trained on (all when None)."""
    recorded, episodes = trained_episodes(checkpoint)
    root = root or recorded
    if root is None:
        raise ValueError(f"no --root given and {checkpoint}/train_config.json names no dataset root")
    return Path(root), episodes


def scored_data(
    checkpoint: Path, root: Path | None = None, heldout_root: Path | None = None
) -> dict[str, Any]:
    """What a checkpoint is scored on: the training dataset and its episodes as :func:`training_data` resolves them,
    and each dataset's ``meta/`` digest, so that a dataset collected again at the same path is other data."""
    root, episodes = training_data(checkpoint, root)
    data: dict[str, Any] = {
        "root": str(root),
        "episodes": episodes,
        "meta_sha256": tree_sha256(root / "meta"),
    }
    if heldout_root is not None:
        data["heldout_meta_sha256"] = tree_sha256(Path(heldout_root) / "meta")
    return data


def keyframe_sets(
    checkpoint: Path, root: Path | None = None, heldout_root: Path | None = None, max_frames: int = 200
) -> list[KeyframeSet]:
    """The training keyframes (:func:`training_data`), and the held-out keyframes when there are any: those of
    ``heldout_root``, else the training dataset's episodes not trained on; at most ``max_frames`` each (0 = all)."""
    root, episodes = training_data(checkpoint, root)
    from sigma_policy.configuration_sigma import SigmaConfig

    depth_unit = SigmaConfig.from_pretrained(checkpoint).depth_unit
    train_ds = open_dataset(root, depth_unit)
    rows, steps = goal_rows(train_ds, episodes, max_frames)
    sets = [KeyframeSet("train", train_ds, rows, np.asarray(steps), episodes)]
    if heldout_root is not None:
        ho = open_dataset(heldout_root, depth_unit)
        rows, steps = goal_rows(ho, None, max_frames)
        sets.append(KeyframeSet("heldout", ho, rows, np.asarray(steps)))
    elif episodes is not None:
        rest = sorted(set(range(train_ds.meta.total_episodes)) - set(episodes))
        if rest:
            rows, steps = goal_rows(train_ds, rest, max_frames)
            sets.append(KeyframeSet("heldout", train_ds, rows, np.asarray(steps), rest))
    return sets


def row_labels(
    dataset: Any, rows: list[int], keys: tuple[str, ...] = ("task", "variation")
) -> dict[str, np.ndarray] | None:
    """What ``meta/sigma.json`` records under each of ``keys`` for the episode of each dataset row ("unknown" where
    an episode lacks it), read once for all keys; None for a dataset sigma did not collect (no sidecar)."""
    root = Path(dataset.root)
    if not (root / SIDECAR).exists():
        return None
    records = {int(e["episode_index"]): e for e in read_sidecar(root).get("episodes", [])}
    eps = dataset.meta.episodes
    row_episode: dict[int, int] = {}
    for ep in range(len(eps)):
        index = int(eps["episode_index"][ep])
        row_episode.update(
            dict.fromkeys(range(int(eps["dataset_from_index"][ep]), int(eps["dataset_to_index"][ep])), index)
        )
    episodes = [row_episode[int(r)] for r in rows]
    return {key: np.array([str(records.get(e, {}).get(key, "unknown")) for e in episodes]) for key in keys}
