"""Shared result writing for the benchmarks: one Markdown fragment + one JSON file per benchmark.

Every benchmark that feeds ``RESULTS.md`` calls :func:`write_report` with its table; the fragment starts with
the command that produced it and a description of the machine, so a number is never separated from how it was
measured. ``sigma-results`` (``pipelines.results``) stitches the fragments into ``RESULTS.md``.
"""

from __future__ import annotations

import json
import os
import platform
import shlex
import sys
import time
from pathlib import Path
from typing import Any

RESULTS_DIR = Path(__file__).resolve().parent.parent / "benchmarks" / "results"
# A paragraph of a fragment that starts with this was written by hand (dated, with its own commands): a rerun of the
# benchmark keeps it, and everything after it, below the new table.
HAND_NOTES = "Notes (added by hand"


def machine_description() -> str:
    """One line: CPU model, cores usable by this process, memory, Python, torch and GPU (if any)."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    mem = ""
    try:
        kb = int(Path("/proc/meminfo").read_text().split()[1])
        mem = f", {kb / 2**20:.0f} GiB RAM"
    except (OSError, ValueError, IndexError):
        pass
    parts = [f"{cpu}, {cores} cores{mem}", f"Python {platform.python_version()}"]
    try:
        import torch

        parts.append(f"torch {torch.__version__}")
        if torch.cuda.is_available():
            parts.append(torch.cuda.get_device_name(0))
        else:
            parts.append("no GPU")
    except ImportError:
        pass
    return "; ".join(parts)


def command_line() -> str:
    """The command that is running, as a user would type it (``python -m benchmarks.x --flag v``)."""
    main = sys.modules.get("__main__")
    spec = getattr(main, "__spec__", None)
    script = Path(sys.argv[0]).name
    if spec is not None and spec.name:
        head = f"python -m {spec.name}"
    elif script.startswith("sigma-"):  # a console script of this package
        head = script
    else:
        head = f"python {sys.argv[0]}"
    return " ".join([head, *map(shlex.quote, sys.argv[1:])])


def write_report(
    name: str,
    title: str,
    markdown: str,
    data: Any,
    notes: str = "",
    results_dir: Path | None = None,
) -> Path:
    """Write ``<results_dir>/<name>.md`` (title, command, machine, date, table, notes) and ``<name>.json``.

    Hand-written notes of the fragment it replaces (from the first line that starts with :data:`HAND_NOTES` to the
    end) are kept after the new ``notes``. Returns the Markdown path. ``data`` must be JSON-serialisable (the raw
    numbers behind the table).
    """
    out = Path(results_dir or RESULTS_DIR)
    out.mkdir(parents=True, exist_ok=True)
    header = (
        f"## {title}\n\n"
        f"Command: `{command_line()}`\n\n"
        f"Machine: {machine_description()}; measured {time.strftime('%Y-%m-%d')}.\n\n"
    )
    text = header + markdown.strip() + "\n" + (f"\n{notes.strip()}\n" if notes.strip() else "")
    md_path = out / f"{name}.md"
    kept = hand_notes(md_path.read_text()) if md_path.exists() else ""
    text += f"\n{kept}" if kept else ""
    md_path.write_text(text)
    payload = {"name": name, "title": title, "command": command_line(), "machine": machine_description()}
    payload["date"] = time.strftime("%Y-%m-%d")
    payload["data"] = data
    (out / f"{name}.json").write_text(json.dumps(payload, indent=1, default=str) + "\n")
    return md_path


def hand_notes(fragment: str) -> str:
    """The hand-written tail of a fragment: from its first line that starts with :data:`HAND_NOTES` ("" if none)."""
    lines = fragment.splitlines(keepends=True)
    start = next((i for i, line in enumerate(lines) if line.startswith(HAND_NOTES)), None)
    return "" if start is None else "".join(lines[start:]).rstrip() + "\n"


def start_run_dir(output_dir: Path, fresh: bool, stages: tuple[str, ...] = ("train", "eval")) -> Path:
    """Create a pipeline's output directory; ``fresh`` deletes its ``stages`` (collected data is kept)."""
    import shutil

    output_dir = Path(output_dir)
    if fresh:
        for sub in stages:
            shutil.rmtree(output_dir / sub, ignore_errors=True)
    output_dir.mkdir(parents=True, exist_ok=True)
    return output_dir


def write_run_outputs(
    output_dir: Path, name: str, title: str, markdown: str, config: Any, data: dict, publish: bool
) -> None:
    """A pipeline's table to ``<output_dir>/<name>.md``, its config and raw numbers to ``<name>.json``; with
    ``publish`` also the RESULTS.md fragment (:func:`write_report`)."""
    import draccus

    (output_dir / f"{name}.md").write_text(markdown + "\n")
    payload = {"config": draccus.encode(config), **data}
    (output_dir / f"{name}.json").write_text(json.dumps(payload, indent=1, default=str))
    if publish:
        write_report(name, title, markdown, data)
