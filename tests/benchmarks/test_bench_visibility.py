"""The visibility count: which pixels show an object, and the refusal of a task without object geometry."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from benchmarks.bench_visibility import VisibilityConfig, main, object_pixels


def test_object_pixels_counts_points_inside_the_objects_box_above_its_floor():
    box = np.array([[0.0, 0.0, 0.0], [0.1, 0.1, 0.2]])  # an object's vertices: its corners
    world = np.array(
        [
            [
                [0.05, 0.05, 0.1],
                [0.05, 0.05, 0.001],
                [0.3, 0.0, 0.1],
                [0.05, 0.05, 0.1],
            ],  # inside, floor, beside
            [
                [0.104, 0.05, 0.1],
                [0.11, 0.05, 0.1],
                [0.05, 0.05, 0.204],
                [0.05, 0.05, 0.21],
            ],  # margin: 2 of 4
        ]
    )
    filled = np.array([[True, True, True, False], [True, True, True, True]])
    assert object_pixels(world, filled, box, margin_m=0.005, floor_clear_m=0.005).tolist() == [1, 2]


def test_a_task_without_object_geometry_is_refused():
    with pytest.raises(ValueError, match="'lift' has no object geometry"):
        main(VisibilityConfig(checkpoint=Path("unused"), task="lift"))
