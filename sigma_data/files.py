"""Files written whole or not at all, and files named by their content.

Every record a rerun trusts (a shard's marker, a collection's record, a dataset's sidecar, an evaluation's results
and episode log, a text-feature table) is written under a temporary name beside its place and then renamed onto it.
A rename within one directory is atomic on POSIX file systems, so a run killed mid-write leaves the previous file or
none, never a torn one that the next run would read as complete. The temporary name is hidden (``.<name>.tmp``), and
a write that raises removes it.

Depends on nothing but the standard library, so every layer may use it (the policy included).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any


def temporary_name(path: Path) -> Path:
    """Where :func:`atomic_path` writes ``path`` before renaming it: ``.<name>.tmp`` in the same directory."""
    return path.with_name(f".{path.name}.tmp")


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path to write ``path``'s content to; on a clean exit it is renamed onto ``path``, on an
    exception it is removed and ``path`` is left as it was. The parent directory is created."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temporary_name(path)
    try:
        yield tmp
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)


def write_text_atomic(path: str | Path, text: str) -> None:
    """Write ``text`` to ``path`` whole or not at all (:func:`atomic_path`)."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def write_json_atomic(path: str | Path, data: Any, indent: int = 1, default: Any = None) -> None:
    """Write ``data`` as JSON to ``path`` whole or not at all (:func:`atomic_path`); ``default`` as in
    :func:`json.dumps`."""
    write_text_atomic(path, json.dumps(data, indent=indent, default=default))


def sha256(path: str | Path) -> str:
    """The SHA-256 of a file's bytes, as hex (read in blocks: a checkpoint's weights are not loaded whole)."""
    with Path(path).open("rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def tree_sha256(directory: str | Path) -> str:
    """The SHA-256 of every file under ``directory``: their paths relative to it and their bytes, in path order
    (hidden temporaries skipped), so two trees with the same files hash alike wherever they lie."""
    directory = Path(directory)
    if not directory.is_dir():
        raise FileNotFoundError(f"{directory} is not a directory")
    digest = hashlib.sha256()
    for path in sorted(p for p in directory.rglob("*") if p.is_file() and not p.name.startswith(".")):
        digest.update(path.relative_to(directory).as_posix().encode() + b"\0" + sha256(path).encode() + b"\0")
    return digest.hexdigest()
