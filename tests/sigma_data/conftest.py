"""Fixtures shared by the tests of ``sigma_data``."""

from __future__ import annotations

import pytest

from sigma_data.suite import get_task, make_env


@pytest.fixture(scope="module")
def lift():
    """A real robosuite Lift env and its task, one per test module: (task, env)."""
    task = get_task("lift")
    env = make_env(task)
    yield task, env
    env.close()
