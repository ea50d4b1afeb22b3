"""NutAssembly with both nuts present (``single_object_mode=0``).

The square nut belongs on ``peg1`` (square), the round nut on ``peg2`` (round). The variation's
``params["nut"]`` (``"square"`` / ``"round"``) names the one nut the instruction asks for.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from sigma_data.tasks.spec import Variation

NUTS = ("square", "round")  # robosuite's nut_to_id order; peg1 is square, peg2 round
MIN_GRIPPER_DISTANCE = float(np.arctanh(0.4) / 10.0)  # robosuite's r_reach < 0.6, ~0.042 m


def nut_index(env: Any, nut: str) -> int:
    if nut not in env.nut_to_id:
        raise ValueError(f"unknown nut '{nut}'; known: {sorted(env.nut_to_id)}")
    return int(env.nut_to_id[nut])


def nut_object(env: Any, nut: str) -> Any:
    """The robosuite nut object (``SquareNut`` / ``RoundNut``)."""
    return env.nuts[nut_index(env, nut)]


def peg_body_id(env: Any, nut: str) -> int:
    """MuJoCo body id of the peg that matches ``nut``."""
    return int((env.peg1_body_id, env.peg2_body_id)[nut_index(env, nut)])


def target(env: Any, variation: Variation) -> np.ndarray:
    """World position of the handle of the nut the variation names (where it is grasped)."""
    site = nut_object(env, variation.params["nut"]).important_sites["handle"]
    return np.array(env.sim.data.site_xpos[env.sim.model.site_name2id(site)], dtype=np.float64)


def centre(env: Any, variation: Variation) -> np.ndarray:
    """World position of the centre of the nut the variation names (its body; the handle sticks out from it)."""
    nut = nut_object(env, variation.params["nut"])
    return np.array(env.sim.data.body_xpos[env.obj_body_id[nut.name]], dtype=np.float64)


def success(env: Any, variation: Variation) -> bool:
    """The named nut sits around its own peg (robosuite's ``on_peg``) and the gripper is away from it."""
    obj_pos = centre(env, variation)
    site_pos = env.sim.data.site_xpos[env.robots[0].eef_site_id["right"]]
    gripper_away = np.linalg.norm(site_pos - obj_pos) > MIN_GRIPPER_DISTANCE
    return bool(env.on_peg(obj_pos, nut_index(env, variation.params["nut"])) and gripper_away)
