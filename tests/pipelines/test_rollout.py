"""``pipelines/rollout.py``: the worker's start-up error reaches the evaluation as one clear error, not a pool that
replaces a failing worker forever.

The rollouts themselves run in robosuite in tests/pipelines/test_demo.py (the demo's quick run).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from pipelines import rollout
from pipelines.evaluate import EvalConfig
from pipelines.rollout import Job, init_worker, run_job


def test_a_worker_that_cannot_start_fails_its_first_episode_with_the_reason(
    tmp_path: Path, monkeypatch
) -> None:
    monkeypatch.setattr(rollout, "_WORKER_ERROR", None)  # restored afterwards: this process's worker state
    init_worker(EvalConfig(checkpoint=tmp_path / "missing", workers=1))
    with pytest.raises(RuntimeError, match="an evaluation worker could not start") as info:
        run_job(Job("lift", "lift_cube", 100_000))
    assert "missing" in str(info.value.__cause__)
