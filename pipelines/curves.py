"""Learning curves of ``sigma-diagnose`` (``pipelines/diagnostics.py``): per-head errors against training step, for
the training and the held-out keyframes, as a PNG and as Rerun scalars.

Entity paths logged (``curves.rrd``): ``diagnostics/<set>/<metric>`` on the ``step`` timeline, one per metric of
``pipelines/keyframe_errors.py`` (``<set>`` is ``train`` or ``heldout``) and ``swap_nearest`` where the set has
instruction-swap scenes.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any


def plot_curves(curves: dict[str, Any], path: Path) -> None:
    """Translation (cm), rotation (deg) and head accuracies against training step, train vs held-out."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = curves["steps"]
    panels = [
        ("translation error, median (cm)", "trans_cm_median"),
        ("rotation error, median (deg)", "rot_deg_median"),
        ("yaw error, mean (deg)", "yaw_deg_mean"),
        ("gripper accuracy", "gripper_acc"),
    ]
    fig, axes = plt.subplots(1, len(panels), figsize=(4 * len(panels), 3.2))
    for ax, (title, metric) in zip(axes, panels, strict=True):
        for name, series in curves["sets"].items():
            ax.plot(steps, series[metric], marker="o", label=name)
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("training step")
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def log_curves_rerun(curves: dict[str, Any], path: Path) -> None:
    """Rerun scalars: ``diagnostics/<set>/<metric>`` on the ``step`` timeline."""
    import rerun as rr

    rec = rr.RecordingStream("sigma-diagnose")
    rec.save(str(path))
    for i, step in enumerate(curves["steps"]):
        rec.set_time("step", sequence=step)
        for name, series in curves["sets"].items():
            for metric in series:
                value = series[metric][i]
                if value is not None and math.isfinite(value):
                    rec.log(f"diagnostics/{name}/{metric}", rr.Scalars(value))
    rec.flush()
