"""Default Rerun layouts, shipped in code and saved in every recording (``rec.save(path, default_blueprint=...)``).

They only reference the entity paths written by :mod:`pipelines.viz.episode` and :mod:`pipelines.viz.policy`;
the viewer lets users rearrange them freely.
"""

from __future__ import annotations

from collections.abc import Sequence

import rerun.blueprint as rrb


def episode_blueprint(camera_names: Sequence[str], with_depth: bool = True) -> rrb.Blueprint:
    """Layout of the episode viewer.

    Left: the 3D world (cameras as frusta at their per-frame pose, RGB on the image planes, the fused colour
    cloud of all cameras, end-effector path, keyframe axes, goal link) above the time series (state,
    action, distance to the goal keyframe). Right: one 2D view per camera (RGB, then depth) above the
    instruction. Playback starts on the ``frame_index`` timeline. The per-camera depth images stay out of the
    3D view (Rerun would back-project each one as its own cloud and bury the fused colour cloud under them);
    add them back there with the viewer's entity panel.
    """
    rgb_views = [
        rrb.Spatial2DView(origin=f"world/cameras/{cam}", contents=["$origin/rgb"], name=f"{cam} rgb")
        for cam in camera_names
    ]
    depth_views = [
        rrb.Spatial2DView(origin=f"world/cameras/{cam}", contents=["$origin/depth"], name=f"{cam} depth")
        for cam in camera_names
    ]
    cameras = rrb.Grid(*rgb_views, *(depth_views if with_depth else []), grid_columns=len(camera_names))
    series = rrb.Tabs(
        rrb.TimeSeriesView(origin="timeseries/state", name="state"),
        rrb.TimeSeriesView(origin="timeseries/action", name="action"),
        rrb.TimeSeriesView(origin="timeseries/goal_distance", name="distance to goal"),
    )
    layout = rrb.Horizontal(
        rrb.Vertical(
            rrb.Spatial3DView(
                origin="world",
                contents=["+ $origin/**", *(f"- $origin/cameras/{cam}/depth" for cam in camera_names)],
                name="3D world",
            ),
            series,
            row_shares=[3, 2],
        ),
        rrb.Vertical(
            cameras, rrb.TextDocumentView(origin="instruction", name="instruction"), row_shares=[3, 1]
        ),
        column_shares=[3, 2],
    )
    return rrb.Blueprint(layout, rrb.TimePanel(timeline="frame_index"), collapse_panels=False)


def policy_blueprint(view_names: Sequence[str], root: str = "policy") -> rrb.Blueprint:
    """Layout of the policy viewer.

    Left: the 3D scene (point cloud, predicted vs ground-truth keyframe pose, error arrow) above a text
    summary (instruction, errors, gripper / collision decisions). Right: one 2D view per virtual view (RGB
    with the translation heatmap overlaid, heatmap peak and ground-truth pixel marked), tabs with the raw
    heatmaps, depth and xyz channels, and bar charts of the rotation-bin, gripper and collision probabilities.
    """
    overlay_views = [
        rrb.Spatial2DView(
            origin=f"{root}/views/{v}",
            contents=["$origin/rgb", "$origin/heatmap_overlay", "$origin/markers/**"],
            name=f"{v}: rgb + heatmap",
        )
        for v in view_names
    ]
    heatmap_views = [
        rrb.TensorView(origin=f"{root}/views/{v}/heatmap", name=f"{v} heatmap") for v in view_names
    ]
    depth_views = [
        rrb.Spatial2DView(origin=f"{root}/views/{v}", contents=["$origin/depth"], name=f"{v} depth")
        for v in view_names
    ]
    xyz_views = [
        rrb.Spatial2DView(origin=f"{root}/views/{v}", contents=["$origin/xyz"], name=f"{v} xyz")
        for v in view_names
    ]
    cols = min(len(view_names), 3)
    channels = rrb.Tabs(
        rrb.Grid(*heatmap_views, grid_columns=cols, name="heatmaps"),
        rrb.Grid(*depth_views, grid_columns=cols, name="depth"),
        rrb.Grid(*xyz_views, grid_columns=cols, name="xyz"),
    )
    bars = rrb.Horizontal(
        rrb.BarChartView(origin=f"{root}/probs/rotation/x", name="rot x bins"),
        rrb.BarChartView(origin=f"{root}/probs/rotation/y", name="rot y bins"),
        rrb.BarChartView(origin=f"{root}/probs/rotation/z", name="rot z bins"),
        rrb.BarChartView(origin=f"{root}/probs/gripper", name="gripper [closed, open]"),
        rrb.BarChartView(origin=f"{root}/probs/collision", name="collision [avoid, ignore]"),
    )
    layout = rrb.Horizontal(
        rrb.Vertical(
            rrb.Spatial3DView(origin=f"{root}/world", name="3D prediction"),
            rrb.TextDocumentView(origin=f"{root}/summary", name="summary"),
            row_shares=[3, 1],
        ),
        rrb.Vertical(
            rrb.Grid(*overlay_views, grid_columns=cols, name="virtual views"),
            channels,
            bars,
            row_shares=[3, 2, 1],
        ),
        column_shares=[2, 3],
    )
    return rrb.Blueprint(layout, collapse_panels=False)
