"""A collection worker process ends with the process that started it (the spawned helpers of
:mod:`sigma_data.collect.scheduler` and DataTrove's pool workers in :mod:`sigma_data.collect.datatrove`).

A killed ``sigma-data collect`` used to leave its workers collecting on their own; the shard a worker was writing
when it died has no marker, so the next run redoes it.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import threading
import time

# How often a worker checks that its parent is alive (seconds).
PARENT_POLL_S = 1.0
_PR_SET_PDEATHSIG = 1  # linux/prctl.h


def exit_with_parent(parent: int) -> None:
    """End this process as soon as ``parent`` is no longer its parent, however the parent died.

    On Linux the kernel sends it SIGKILL when the parent dies (``PR_SET_PDEATHSIG``: immediate, needs no Python
    thread to run; a polling thread alone was seen to let a helper finish its shard 2 s after its parent was
    killed). The kernel's "parent" is the thread that forked this process, so the caller's process must be forked
    by a thread that outlives it (the scheduler's collection thread; the main thread of DataTrove's pool or its
    forkserver). A watcher thread backs this up where ``prctl`` is missing and covers a parent that died before it
    was set: a process whose parent dies is reparented (to init or a subreaper), so a changed ``os.getppid()``
    means the parent is gone; it then leaves with ``os._exit``, without cleanup that could wait on the dead
    parent."""
    with contextlib.suppress(Exception):
        ctypes.CDLL(None).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)  # libc's, linked into the interpreter

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(PARENT_POLL_S)
        os._exit(1)

    threading.Thread(target=watch, name="sigma-parent-watch", daemon=True).start()
