"""NutAssembly with both nuts present (``single_object_mode=0``).

The square nut belongs on ``peg1`` (square), the round nut on ``peg2`` (round). The variation's
``params["nut"]`` (``"square"`` / ``"round"``) names the one nut the instruction asks for.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from sigma_data.poses import body_pose, object_yaw

if TYPE_CHECKING:
    from sigma_data.tasks.spec import Variation

NUTS = ("square", "round")  # robosuite's nut_to_id order; peg1 is square, peg2 round
# The holes and pegs, from robosuite's square-nut.xml, round-nut.xml and pegs_arena.xml (m): the square nut's hole
# is a square of half-side 33.25 - 10.5 = 22.75 mm round a square peg of half-side 16 mm; the round nut's hole an
# octagon of inner radius 42.45 - 11.25 = 31.2 mm round a cylinder of radius 20 mm.
SQUARE_HOLE_HALF, SQUARE_PEG_HALF = 0.02275, 0.016
ROUND_HOLE_RADIUS, ROUND_PEG_RADIUS = 0.0312, 0.02
# A nut this far from its peg (horizontally, m) is not over it: no placement reading.
PEG_NEAR_M = 0.1
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
    return body_pose(env, nut_object(env, variation.params["nut"]).root_body)[0]


def peg_margin(offset: np.ndarray, turn: float, nut: str) -> float:
    """How far (m) the peg stays inside the nut's hole, seen from above, for the nut's centre ``offset`` (2,) from
    the peg's axis and (square nut) the nut turned ``turn`` rad from the peg's faces; negative: the nut lands on the
    peg. For the square nut the deepest of the peg's four corners in the hole's frame counts: centred, the margin is
    6.75 mm at 0°, 4.2 mm at 10° and 2.2 mm at 20°."""
    if nut == "round":
        return ROUND_HOLE_RADIUS - ROUND_PEG_RADIUS - float(np.linalg.norm(offset))
    c, s = np.cos(turn), np.sin(turn)
    to_nut = np.array([[c, s], [-s, c]])  # world -> the nut's frame
    corners = SQUARE_PEG_HALF * np.array([[1, 1], [1, -1], [-1, 1], [-1, -1]]) - offset
    return SQUARE_HOLE_HALF - float(np.abs(corners @ to_nut.T).max())


def placement(env: Any, variation: Variation) -> dict[str, int]:
    """How the named nut sits over its own peg now, seen from above; ``{}`` where it is more than ``PEG_NEAR_M``
    from it:

    * ``from_peg_mm``: its centre's distance from the peg's axis;
    * ``turned_deg`` (square nut only): its yaw from the peg's faces, -45..45;
    * ``peg_margin_mm``: :func:`peg_margin`, how far inside the hole the peg stays (negative: it slides down only
      if something pushes it across).
    """
    nut = variation.params["nut"]
    position, rot = body_pose(env, nut_object(env, nut).root_body)
    offset = (position - env.sim.data.body_xpos[peg_body_id(env, nut)])[:2]
    if np.linalg.norm(offset) > PEG_NEAR_M:
        return {}
    fit = {"from_peg_mm": round(1000 * float(np.linalg.norm(offset)))}
    turn = 0.0
    if nut == "square":
        turn = (object_yaw(rot) + np.pi / 4) % (np.pi / 2) - np.pi / 4
        fit["turned_deg"] = round(float(np.degrees(turn)))
    return fit | {"peg_margin_mm": round(1000 * peg_margin(offset, turn, nut))}


def success(env: Any, variation: Variation) -> bool:
    """The named nut sits around its own peg (robosuite's ``on_peg``) and the gripper is away from it."""
    obj_pos = centre(env, variation)
    site_pos = env.sim.data.site_xpos[env.robots[0].eef_site_id["right"]]
    gripper_away = np.linalg.norm(site_pos - obj_pos) > MIN_GRIPPER_DISTANCE
    return bool(env.on_peg(obj_pos, nut_index(env, variation.params["nut"])) and gripper_away)
