"""Shape measures of object vertices (sigma_data/tasks/geometry.py) on synthetic boxes with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from sigma_data.tasks.geometry import ridge_direction


def box_vertices(length: float, width: float, height: float, yaw: float) -> np.ndarray:
    """The 8 corners of a box turned by ``yaw`` about z, its long side along x before the turn."""
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (0, 2)]) * [
        length / 2,
        width / 2,
        height / 2,
    ]
    c, s = np.cos(yaw), np.sin(yaw)
    return corners @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T


@pytest.mark.parametrize("yaw_deg", [0, 30, 90, 135])
def test_an_elongated_top_has_its_long_axis_as_ridge(yaw_deg):
    yaw = np.radians(yaw_deg)
    ridge = ridge_direction(box_vertices(0.10, 0.03, 0.2, yaw))
    assert ridge is not None
    assert abs(float(ridge @ [np.cos(yaw), np.sin(yaw)])) == pytest.approx(1.0, abs=1e-9)


def test_a_square_top_has_no_ridge():
    assert ridge_direction(box_vertices(0.06, 0.06, 0.1, 0.3)) is None


def test_only_the_top_slice_counts():
    """A long base under a square lid: the lid decides, so no ridge."""
    base = box_vertices(0.20, 0.03, 0.1, 0.0)
    lid = box_vertices(0.05, 0.05, 0.02, 0.0) + [0, 0, 0.1]
    assert ridge_direction(np.concatenate([base, lid])) is None
