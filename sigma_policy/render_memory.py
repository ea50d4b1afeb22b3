"""Memory the CPU renderer reuses across calls (sigma_policy/renderer.py): scratch tensors per thread, output
tensors handed out again once the caller has dropped them, and the process-wide pool of render threads.

A fresh multi-megabyte CPU allocation is page-faulted in on first touch, which costs more than the arithmetic of
a render (``python -m benchmarks.bench_renderer``), so on the CPU both scratch and output memory are kept; on CUDA,
whose caching allocator already recycles memory, every request is a new ``torch.empty``.
"""

from __future__ import annotations

import math
import threading
from concurrent.futures import ThreadPoolExecutor

import torch
from torch import Tensor

__all__ = ["OutputPool", "Workspace", "cpu_pool", "output_pool", "workspace"]


class Workspace:
    """Named scratch tensors. With ``reuse`` (CPU) they persist across calls: a fresh large CPU allocation is
    page-faulted in on first touch, which costs more than the arithmetic of a render. Without it (CUDA, whose
    caching allocator already recycles memory) every request is a new ``torch.empty``."""

    def __init__(self, reuse: bool) -> None:
        self.reuse = reuse
        self._store: dict[str, Tensor] = {}

    def get(self, name: str, shape: tuple[int, ...], dtype: torch.dtype, device: torch.device) -> Tensor:
        numel = math.prod(shape)
        if not self.reuse:
            return torch.empty(shape, dtype=dtype, device=device)
        t = self._store.get(name)
        if t is None or t.dtype != dtype or t.device != device or t.numel() < numel:
            t = self._store[name] = torch.empty(numel, dtype=dtype, device=device)
        return t[:numel].view(shape)


_CPU_WORKSPACES = threading.local()  # one per thread, so concurrent renders never share scratch memory


def workspace(device: torch.device) -> Workspace:
    if device.type != "cpu":
        return Workspace(reuse=False)
    # Tensors made under torch.inference_mode() cannot be updated in place outside it (and vice versa would
    # leak inference tensors into autograd code): keep one workspace per mode.
    name = "ws_inference" if torch.is_inference_mode_enabled() else "ws"
    if not hasattr(_CPU_WORKSPACES, name):
        setattr(_CPU_WORKSPACES, name, Workspace(reuse=True))
    return getattr(_CPU_WORKSPACES, name)


_STORAGE_USE_COUNT = getattr(torch._C, "_storage_Use_Count", None)  # what torch's CUDA-graph trees use, too


class OutputPool:
    """CPU output tensors handed out again once nothing outside the pool references their memory.

    The pool keeps a base tensor per output and returns a new tensor on the same storage (not an autograd view),
    so every tensor or view the caller still holds -- or autograd saved for backward -- counts in the storage's use
    count; a base is reused only when the pool's own reference is the last one. Without the use-count function
    (a future torch), every request allocates."""

    def __init__(self, keep: int = 2, max_bytes: int = 1 << 30) -> None:
        self.keep, self.max_bytes = keep, max_bytes
        self._bases: list[Tensor] = []

    @staticmethod
    def _unreferenced(base: Tensor) -> bool:
        storage = base.untyped_storage()  # this Python handle is a reference of its own: 2 = base + handle
        return _STORAGE_USE_COUNT(storage._cdata) <= 2

    def get(self, shape: tuple[int, ...]) -> Tensor:
        numel = math.prod(shape)
        if _STORAGE_USE_COUNT is None or 4 * numel > self.max_bytes:
            return torch.empty(shape)
        base = next((b for b in self._bases if b.numel() == numel and self._unreferenced(b)), None)
        if base is None:
            base = torch.empty(numel)
            self._bases = [*self._bases, base][-self.keep :]
        else:  # most recently used last, so the list keeps the live ones
            self._bases = [b for b in self._bases if b is not base] + [base]
        return torch.empty(0).set_(base.untyped_storage(), 0, shape)


def output_pool() -> OutputPool:
    name = "pool_inference" if torch.is_inference_mode_enabled() else "pool"
    if not hasattr(_CPU_WORKSPACES, name):
        setattr(_CPU_WORKSPACES, name, OutputPool())
    return getattr(_CPU_WORKSPACES, name)


_POOLS: dict[int, ThreadPoolExecutor] = {}
_POOL_LOCK = threading.Lock()


def cpu_pool(threads: int) -> ThreadPoolExecutor:
    """A process-wide pool of ``threads`` render threads (created once per size)."""
    with _POOL_LOCK:
        if threads not in _POOLS:
            _POOLS[threads] = ThreadPoolExecutor(threads, thread_name_prefix="sigma-render")
        return _POOLS[threads]
