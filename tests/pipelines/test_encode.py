"""sigma-encode: the named tasks' instructions, a dataset's task strings and extra ones, in one table."""

from __future__ import annotations

from pathlib import Path

from pipelines.encode import main
from sigma_data.suite import get_task
from sigma_policy.text_encoder import TextFeatureTable, minilm_identity
from tests.sigma_policy.tiny_dataset import write_tiny_keyframe_dataset


def test_encode_writes_every_named_instruction(tmp_path: Path, capsys) -> None:
    root = write_tiny_keyframe_dataset(tmp_path / "tiny", episodes=2, size=32)
    out = tmp_path / "features.safetensors"
    args = [
        "--tasks",
        "[door]",
        "--dataset_root",
        f"[{root}]",
        "--instructions",
        "[wave]",
        "--output",
        str(out),
    ]
    assert main(args) == 0
    table = TextFeatureTable(out, expected_encoder=minilm_identity())
    door = list(get_task("door").variations[0].instructions)
    assert list(table._cache)[: len(door)] == door and list(table._cache)[-1] == "wave"
    assert len(table._cache) > len(door) + 1  # the dataset's task strings are in between
    assert f"-> {out}" in capsys.readouterr().out


def test_encode_refuses_nothing_to_encode_and_a_missing_dataset(tmp_path: Path, capsys) -> None:
    assert main(["--tasks", "[]", "--output", str(tmp_path / "f.safetensors")]) == 1
    assert "no instructions to encode" in capsys.readouterr().err
    assert main(["--tasks", "[]", "--dataset_root", f"[{tmp_path / 'nope'}]"]) == 1
    assert f"{tmp_path / 'nope'}: not a LeRobot v3 dataset" in capsys.readouterr().err
    assert not (tmp_path / "f.safetensors").exists()
