"""Door (latched): turn the lever to release the latch, then pull the door open about its hinge."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from sigma_data.tasks.spec import Variation

OPEN_ANGLE = 0.3  # rad; robosuite's success threshold on the hinge joint
BOUNDS = (-0.35, -0.55, 0.75, 0.35, 0.15, 1.45)


def hinge_angle(env: Any) -> float:
    """Door hinge angle (rad, positive = open)."""
    return float(env.sim.data.qpos[env.hinge_qpos_addr])


def lever_angle(env: Any) -> float:
    """Lever (latch) joint angle (rad): the latch clears the frame only beyond ~1.25 (``sigma_data/experts/door.py``)."""
    return float(env.sim.data.qpos[env.handle_qpos_addr])


def progress(env: Any) -> dict[str, float]:
    """How far the door is: ``{"hinge_rad": ..., "lever_rad": ...}`` (absolute lever angle), to 0.01 rad (a shut
    door reads 0.0, not -0.0)."""
    return {"hinge_rad": round(hinge_angle(env), 2) + 0.0, "lever_rad": round(abs(lever_angle(env)), 2)}


def success(env: Any, variation: Variation) -> bool:
    """robosuite's check: the hinge is open by more than 0.3 rad."""
    return hinge_angle(env) > OPEN_ANGLE
