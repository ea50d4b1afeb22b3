"""The renderer's reused memory: an output is handed out again only once nothing references it, and scratch
tensors grow to the largest request and are views of one buffer."""

from __future__ import annotations

import pytest
import torch

from sigma_policy.render_memory import OutputPool, Workspace, cpu_pool


def test_an_output_is_reused_only_after_every_reference_to_it_is_gone():
    pool = OutputPool(keep=2)
    first = pool.get((2, 3))
    first_ptr = first.untyped_storage().data_ptr()
    view = first[0]  # a view the caller keeps: the memory is still in use
    del first
    second = pool.get((2, 3))
    assert second.untyped_storage().data_ptr() != first_ptr
    del view
    third = pool.get((2, 3))
    if torch._C.__dict__.get("_storage_Use_Count") is None:
        pytest.skip("this torch has no storage use count: every request allocates")
    assert third.untyped_storage().data_ptr() == first_ptr and third.shape == (2, 3)


def test_scratch_grows_to_the_largest_request_and_is_reused_below_it():
    ws = Workspace(reuse=True)
    big = ws.get("keys", (4, 5), torch.int64, torch.device("cpu"))
    small = ws.get("keys", (2, 3), torch.int64, torch.device("cpu"))
    assert small.untyped_storage().data_ptr() == big.untyped_storage().data_ptr()
    fresh = Workspace(reuse=False).get("keys", (2, 3), torch.int64, torch.device("cpu"))
    assert fresh.shape == (2, 3)


def test_the_thread_pool_is_made_once_per_size():
    assert cpu_pool(2) is cpu_pool(2)
