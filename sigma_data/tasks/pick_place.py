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


def object_points(env: Any, obj: Any) -> np.ndarray:
    """World-frame vertices (N, 3) of a robosuite object's collision geoms (meshes and boxes)."""
    model, data = env.sim.model._model, env.sim.data._data
    points = []
    for name in obj.contact_geoms:
        gid = env.sim.model.geom_name2id(name)
        rot = data.geom_xmat[gid].reshape(3, 3)
        if model.geom_type[gid] == 7:  # mjGEOM_MESH: vertices are in the geom frame
            mid = model.geom_dataid[gid]
            start, count = model.mesh_vertadr[mid], model.mesh_vertnum[mid]
            local = model.mesh_vert[start : start + count]
        else:  # box-like bounding corners for primitives
            size = model.geom_size[gid]
            local = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * size
        points.append(data.geom_xpos[gid] + local @ rot.T)
    return np.concatenate(points)


def points(env: Any, variation: Variation) -> np.ndarray:
    """World vertices (N, 3) of the object the variation names (its collision geoms)."""
    return object_points(env, env.objects[object_index(env, variation.params["object"])])


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
