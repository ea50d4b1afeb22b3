"""Shape measures of an object's vertices (world frame, z up), shared by the experts and the evaluation."""

from __future__ import annotations

import numpy as np


def ridge_direction(points: np.ndarray, depth: float = 0.005) -> np.ndarray | None:
    """Unit xy direction of a ridge on top of an object with vertices ``points (N, 3)``: the long axis of its top
    ``depth`` slice when that slice is twice as long as wide (its second moment 4x larger along it), else None.
    The milk carton's gable ridge and the long side of the cereal box's top have one; a can's round top has none."""
    top = points[points[:, 2] >= points[:, 2].max() - depth][:, :2]
    if len(top) < 3:
        return None
    centred = top - top.mean(axis=0)
    evals, evecs = np.linalg.eigh(centred.T @ centred / len(top))
    return evecs[:, 1] if evals[1] > 4 * max(evals[0], 1e-12) else None
