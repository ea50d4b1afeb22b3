"""Lift: one cube (red, half-size 2.0-2.2 cm) near the table centre; lift it off the table."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from sigma_data.tasks.spec import Variation

LIFT_HEIGHT = 0.04  # the cube centre must rise this far above the table top (robosuite's own threshold)


def success(env: Any, variation: Variation) -> bool:
    """robosuite's check: the cube centre is more than 4 cm above the table top."""
    return bool(env._check_success())
