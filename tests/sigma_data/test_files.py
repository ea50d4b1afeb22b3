"""``sigma_data/files.py``: a file is written whole or not at all, and a file's digest is its bytes' SHA-256."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from sigma_data.files import atomic_path, sha256, temporary_name, write_json_atomic, write_text_atomic


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
