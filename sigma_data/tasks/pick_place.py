"""PickPlace with all four objects on the table (``single_object_mode=0``): milk, bread, cereal, can.

Objects start scattered in the left bin (``bin1``); each has its own quadrant of the right bin (``bin2``).
The variation's ``params["object"]`` names the one object the instruction asks for; only that object counts.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from sigma_data.tasks.spec import Variation

OBJECTS = ("milk", "bread", "cereal", "can")  # robosuite's object_to_id order
# robosuite counts an object as placed only when the grip site is away from it: 1 - tanh(10 d) < 0.6.
MIN_GRIPPER_DISTANCE = float(np.arctanh(0.4) / 10.0)  # ~0.042 m


def object_index(env: Any, name: str) -> int:
    """robosuite's id of a PickPlace object (also its target-bin quadrant index)."""
    if name not in env.object_to_id:
        raise ValueError(f"unknown PickPlace object '{name}'; known: {sorted(env.object_to_id)}")
    return int(env.object_to_id[name])


def object_body_id(env: Any, name: str) -> int:
    """MuJoCo body id of the (collision) object ``name``."""
    return int(env.obj_body_id[env.objects[object_index(env, name)].name])


def target(env: Any, variation: Variation) -> np.ndarray:
    """World position of the object the variation names."""
    return np.array(env.sim.data.body_xpos[object_body_id(env, variation.params["object"])], dtype=np.float64)


def success(env: Any, variation: Variation) -> bool:
    """The named object is inside its bin quadrant (robosuite's ``not_in_bin``) and the gripper is away."""
    i = object_index(env, variation.params["object"])
    obj_pos = target(env, variation)
    site_pos = env.sim.data.site_xpos[env.robots[0].eef_site_id["right"]]
    gripper_away = np.linalg.norm(site_pos - obj_pos) > MIN_GRIPPER_DISTANCE
    return bool(not env.not_in_bin(obj_pos, i) and gripper_away)
