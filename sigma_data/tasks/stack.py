"""Stack: robosuite's ``cubeA`` (red, half-size 2 cm) and ``cubeB`` (green, half-size 2.5 cm).

The variation's ``params`` name the ``top`` and ``bottom`` cube (``"cubeA"``/``"cubeB"``). robosuite's own check
only knows "A on B"; :func:`success` applies the same rule to either order.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from sigma_data.tasks.spec import Variation

CUBES = ("cubeA", "cubeB")
LIFTED = 0.04  # the top cube's centre must be this far above the table top (robosuite's threshold)


def cube(env: Any, name: str) -> Any:
    """The robosuite ``BoxObject`` called ``name`` ("cubeA" or "cubeB")."""
    if name not in CUBES:
        raise ValueError(f"unknown Stack cube '{name}'; known: {CUBES}")
    return getattr(env, name)


def cube_half_size(env: Any, name: str) -> float:
    """Half edge length (m) of a Stack cube."""
    return float(np.max(cube(env, name).size))


def target(env: Any, variation: Variation) -> np.ndarray:
    """World position of the cube the variation picks up (its top cube)."""
    body = cube(env, variation.params["top"]).root_body
    return np.array(env.sim.data.body_xpos[env.sim.model.body_name2id(body)], dtype=np.float64)


def success(env: Any, variation: Variation) -> bool:
    """The top cube is lifted above the table, touches the bottom cube and is not grasped (robosuite's rule)."""
    top, bottom = cube(env, variation.params["top"]), cube(env, variation.params["bottom"])
    lifted = target(env, variation)[2] > env.table_offset[2] + LIFTED
    grasped = env._check_grasp(gripper=env.robots[0].gripper, object_geoms=top)
    return bool(lifted and not grasped and env.check_contact(top, bottom))
