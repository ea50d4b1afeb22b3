"""``sigma_data/files.py``: files written whole or not at all; a file's or a tree's digest is its SHA-256."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from sigma_data.files import (
    atomic_path,
    sha256,
    temporary_name,
    tree_sha256,
    write_json_atomic,
    write_text_atomic,
)


def test_a_write_that_fails_leaves_the_old_file_and_no_temporary(tmp_path: Path) -> None:
    path = tmp_path / "record.json"
    write_json_atomic(path, {"shards": 3})
    with pytest.raises(RuntimeError), atomic_path(path) as tmp:
        tmp.write_text('{"shards": ')  # killed mid-write, as far as this file knows
        raise RuntimeError("the run died here")
    assert json.loads(path.read_text()) == {"shards": 3}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["record.json"]


def test_a_write_lands_whole_under_its_name_and_makes_its_directory(tmp_path: Path) -> None:
    path = tmp_path / "eval" / "episodes.jsonl"
    write_text_atomic(path, "one\ntwo\n")
    assert path.read_text() == "one\ntwo\n"
    assert temporary_name(path) == tmp_path / "eval" / ".episodes.jsonl.tmp"
    assert not temporary_name(path).exists()


def test_sha256_is_the_digest_of_the_bytes(tmp_path: Path) -> None:
    path = tmp_path / "weights.bin"
    data = bytes(range(256)) * 5000  # over one read block
    path.write_bytes(data)
    assert sha256(path) == hashlib.sha256(data).hexdigest()


def test_tree_sha256_follows_names_and_bytes_not_place(tmp_path: Path) -> None:
    def tree(root: Path, files: dict[str, bytes]) -> Path:
        for name, data in files.items():
            (root / name).parent.mkdir(parents=True, exist_ok=True)
            (root / name).write_bytes(data)
        return root

    files = {"info.json": b"{}", "episodes/chunk-000/file-000.parquet": b"rows"}
    first = tree_sha256(tree(tmp_path / "a" / "meta", files))
    assert tree_sha256(tree(tmp_path / "b" / "meta", files)) == first  # the same files elsewhere
    assert tree_sha256(tree(tmp_path / "c" / "meta", {**files, "info.json": b"{ }"})) != first  # other bytes
    assert tree_sha256(tree(tmp_path / "d" / "meta", {**files, "stats.json": b""})) != first  # one more file
    moved = {"info.json": b"{}", "episodes/chunk-000/file-001.parquet": b"rows"}
    assert tree_sha256(tree(tmp_path / "e" / "meta", moved)) != first  # the same bytes under another name
    (tmp_path / "a" / "meta" / ".info.json.tmp").write_bytes(b"half")  # a write in progress is not content
    assert tree_sha256(tmp_path / "a" / "meta") == first
    with pytest.raises(FileNotFoundError, match="not a directory"):
        tree_sha256(tmp_path / "missing")
