"""A command in its own process group: start it, find what is left of it after a kill, end it.

Used by ``scripts/fault_injection.py``, which kills a collection with SIGKILL and checks that no process of it
outlives the kill. Process trees are read with ``psutil``; a zombie nobody reaped counts as ended.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import subprocess
import time
from pathlib import Path
from typing import Any


def _die_with_this_script() -> None:  # runs in the child between fork and exec
    with contextlib.suppress(Exception):
        ctypes.CDLL(None).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG: a killed parent leaves no child


def start(command: list[str], log: Path, env: dict[str, str] | None = None) -> subprocess.Popen:
    """``command`` in a new session (its own process group), with environment ``env`` (this process's if None),
    output to ``log``; it dies with this process."""
    with log.open("w") as sink:
        return subprocess.Popen(
            command,
            stdout=sink,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            start_new_session=True,
            preexec_fn=_die_with_this_script,
            env=env,
        )


def _alive(p: Any) -> bool:
    import psutil

    try:
        return p.status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def processes_of(pid: int) -> list[Any]:
    """``pid`` and every process below it or in its process group (psutil processes)."""
    import psutil

    found: dict[int, Any] = {}
    with contextlib.suppress(psutil.NoSuchProcess):
        root = psutil.Process(pid)
        found[pid] = root
        for child in root.children(recursive=True):
            found[child.pid] = child
    for p in psutil.process_iter():
        with contextlib.suppress(OSError, psutil.Error):
            if p.pid not in found and os.getpgid(p.pid) == pid:
                found[p.pid] = p
    return list(found.values())


def survivors(known: list[Any], group: int, wait_s: float) -> list[Any]:
    """Which of ``known`` (and of process group ``group``) still run after up to ``wait_s`` seconds."""
    import psutil

    deadline = time.monotonic() + wait_s
    while True:
        alive = {p.pid: p for p in known if _alive(p)}
        for p in psutil.process_iter():
            with contextlib.suppress(OSError, psutil.Error):
                if os.getpgid(p.pid) == group and _alive(p):
                    alive[p.pid] = p
        if not alive or time.monotonic() >= deadline:
            return list(alive.values())
        time.sleep(0.2)


def end_group(proc: subprocess.Popen) -> None:
    """SIGKILL to ``proc``'s process group (cleanup on the way out)."""
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signal.SIGKILL)
    with contextlib.suppress(Exception):
        proc.wait(timeout=10)


def describe(p: Any) -> str:
    with contextlib.suppress(Exception):
        return f"{p.pid} {' '.join(p.cmdline())[:100]}"
    return str(p.pid)


def run_to_end(
    command: list[str], log: Path, timeout_s: float, env: dict[str, str] | None = None
) -> tuple[int | None, float, list[str]]:
    """Run ``command`` to completion: (exit status or None if it hung, wall seconds, processes of it
    still running afterwards)."""
    t0 = time.monotonic()
    proc = start(command, log, env)
    try:
        try:
            rc: int | None = proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            rc = None
        wall = time.monotonic() - t0
        left = survivors(processes_of(proc.pid), proc.pid, wait_s=5.0)
        return rc, wall, [describe(p) for p in left]
    finally:
        end_group(proc)


def log_tail(log: Path, lines: int = 15) -> str:
    with contextlib.suppress(OSError):
        return "\n".join(log.read_text(errors="replace").splitlines()[-lines:])
    return ""
