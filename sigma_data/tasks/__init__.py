"""The robosuite task suite: registry (tasks, variations, workspace bounds) and per-task success checks."""

from sigma_data.tasks.registry import (
    TASKS,
    TaskSpec,
    Variation,
    get_task,
    get_variation,
    make_env,
    reset_env,
    scene_bounds,
)

__all__ = [
    "TASKS",
    "TaskSpec",
    "Variation",
    "get_task",
    "get_variation",
    "make_env",
    "reset_env",
    "scene_bounds",
]
