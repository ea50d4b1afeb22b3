"""The keyframe executor (``sigma_data/keyframe_executor.py``) on a real robosuite Lift env."""

from __future__ import annotations

import numpy as np
import pytest

from sigma_data.control import EnvDriver
from sigma_data.keyframe_executor import KeyframeExecutor
from sigma_data.suite import reset_env


def test_executor_replays_lift_expert_keyframes(lift):
    task, env = lift
    variation = task.variations[0]
    reset_env(env, task, variation, seed=3)
    demo = EnvDriver(env)
    task.expert(demo, variation, np.random.default_rng(3))
    assert task.success(env, variation)

    reset_env(env, task, variation, seed=3)
    assert not task.success(env, variation)
    replay = EnvDriver(env)
    results = KeyframeExecutor(replay).execute_all(demo.keyframes)
    assert task.success(env, variation)
    assert [r.gripper_steps > 0 for r in results] == [False, False, True, False]
    assert replay.num_steps <= task.max_steps


def test_executor_rejects_malformed_keyframes(lift):
    _, env = lift
    with pytest.raises(ValueError, match="9 finite values"):
        KeyframeExecutor(EnvDriver(env)).execute(np.zeros(7))
