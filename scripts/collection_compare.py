"""Two runs of one collection compared file by file: equal byte for byte, equal in content, or different.

Used by ``scripts/fault_injection.py`` to check that a collection killed and rerun leaves the same files as a clean
run. Where bytes legitimately vary between two runs of the same collection the content is compared instead: run
timings in ``shard.json``/``collect.json``, the random ``datasets`` fingerprint in a parquet file's metadata, key
order in JSON; a video whose bytes differ is decoded and compared frame by frame.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

# Fields of shard.json / collect.json that differ between two runs of the same collection (times, and whether
# this run reused or redid a shard); a file's sha256 is left out because each file is compared itself.
VOLATILE = frozenset({"record_s", "render_s", "write_s", "total_s", "skipped", "redone"})


@dataclass
class Comparison:
    """Files equal byte for byte, files equal in content only (by reason), and the differences."""

    identical: int = 0
    equivalent: dict[str, int] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)

    def line(self) -> str:
        same = f"{self.identical} files identical"
        if self.equivalent:
            same += ", " + ", ".join(f"{n} equal in {why}" for why, n in sorted(self.equivalent.items()))
        return same


def files_under(root: Path) -> list[str]:
    return sorted(p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file() or p.is_symlink())


def _normalized_record(data: Any) -> Any:
    """A ``shard.json`` / ``collect.json`` without what legitimately differs between two runs."""
    if isinstance(data, dict):
        return {k: _normalized_record(v) for k, v in data.items() if k not in VOLATILE and k != "sha256"}
    if isinstance(data, list):
        return [_normalized_record(v) for v in data]
    return data


def _parquet_equal(a: Path, b: Path) -> bool:
    """Same schema, same rows, same schema metadata but for the ``datasets`` fingerprint (random per run when
    ``datasets`` cannot hash how the table was made)."""
    import pyarrow.parquet as pq

    ta, tb = pq.read_table(a), pq.read_table(b)
    if not ta.equals(tb):
        return False

    def meta(t: Any) -> dict[bytes, Any]:
        out: dict[bytes, Any] = dict(t.schema.metadata or {})
        if b"huggingface" in out:
            hf = json.loads(out[b"huggingface"])
            hf.pop("fingerprint", None)
            out[b"huggingface"] = hf
        return out

    return meta(ta) == meta(tb)


def video_frames(path: Path) -> list[Any]:
    """Every frame of a video file, decoded (NumPy arrays)."""
    import av

    with av.open(str(path)) as container:
        return [f.to_ndarray() for f in container.decode(video=0)]


def _videos_equal(a: Path, b: Path) -> bool:
    import numpy as np

    fa, fb = video_frames(a), video_frames(b)
    return len(fa) == len(fb) and all(np.array_equal(x, y) for x, y in zip(fa, fb, strict=True))


def compare_file(a: Path, b: Path) -> str | None:
    """``"bytes"`` if equal byte for byte, the reason they are equal in content (``"run timings"``, ``"key order"``,
    ``"parquet fingerprint"``, ``"decoded frames"``), or None if they differ."""
    if a.stat().st_size == b.stat().st_size and a.read_bytes() == b.read_bytes():
        return "bytes"
    try:
        if a.name in ("shard.json", "collect.json"):
            same = _normalized_record(json.loads(a.read_text())) == _normalized_record(
                json.loads(b.read_text())
            )
            return "run timings" if same else None
        if a.suffix == ".json":
            return "key order" if json.loads(a.read_text()) == json.loads(b.read_text()) else None
        if a.suffix == ".parquet":
            return "parquet fingerprint" if _parquet_equal(a, b) else None
        if a.suffix == ".mp4":
            return "decoded frames" if _videos_equal(a, b) else None
    except Exception:  # unreadable in one of the runs: not equal
        return None
    return None


def compare_trees(clean: Path, run: Path) -> Comparison:
    """Every file under ``run`` against the same path under ``clean`` (and files only one of them has)."""
    result = Comparison()
    if not run.is_dir():
        result.problems.append(f"{run} is missing")
        return result
    a, b = files_under(clean), files_under(run)
    only_clean, only_run = sorted(set(a) - set(b)), sorted(set(b) - set(a))
    if only_clean:
        result.problems.append(f"missing from {run}: {', '.join(only_clean[:5])}")
    if only_run:
        result.problems.append(f"not in the clean run: {', '.join(only_run[:5])}")
    for rel in sorted(set(a) & set(b)):
        how = compare_file(clean / rel, run / rel)
        if how is None:
            result.problems.append(f"{rel} differs from the clean run's")
        elif how == "bytes":
            result.identical += 1
        else:
            result.equivalent[how] = result.equivalent.get(how, 0) + 1
    return result
