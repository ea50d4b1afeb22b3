"""PickPlace expert: pick the named object out of the clutter in ``bin1`` and set it upright in its quadrant.

Waypoints (ignore_collision label): above the grasp point +10 cm (0) -> grasp point (1) -> close (1) ->
lift so the object's bottom clears the bin walls (0) -> above the target point in its quadrant (0) ->
down until the object's bottom is 1.5 cm above the bin floor (1) -> open (1) -> retreat 10 cm up (0).

Geometry comes from the object's collision meshes (world vertices), so one expert handles the milk carton,
bread, cereal box and can: the grasp yaw minimises the object's width across the fingers at grasp height
(nearest the current hand yaw among near-minimal widths); the grasp height is 2.5 cm below the top. The
target is the point of the object's quadrant closest to the robot base with a margin from its walls: the
quadrant centre of the far quadrants is out of top-down reach (robosuite_notes §3.4).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from sigma_data.control import grip_site_pose, site_yaw, top_down_quat, wrap_angle
from sigma_data.experts.base import EpisodeRecorder, ExpertFailure, WaypointArm, check_grasp
from sigma_data.tasks.pick_place import object_index

if TYPE_CHECKING:
    from sigma_data.tasks.registry import Variation

PREGRASP_HEIGHT = 0.10
GRASP_ABOVE_BOTTOM = 0.02
# The palm's collision hull starts 3.1 cm above the grip site (fingers' pads span -0.4..+1.2 cm): grasp as
# deep as the palm allows.
PALM_CLEARANCE = 0.036
WIDTH_SLACK = 0.01  # accept grasp yaws this much wider than the narrowest (m)
MAX_GRASP_WIDTH = 0.07  # metres across the fingers (fully open: 0.078)
WALL_TOP = 0.90  # bin walls/dividers top (bin floor top 0.82, walls 10 cm above bin origin 0.8)
BIN_FLOOR = 0.82
TRAVEL_CLEARANCE = 0.07  # object bottom above the wall tops while travelling
RELEASE_HEIGHT = 0.015  # object bottom above the bin floor at release
WALL_MARGIN = 0.02  # object footprint to quadrant wall
RETREAT = 0.10


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


# Where the open gripper sweeps when it descends to a top-down grasp, in the hand frame: coordinate along
# the closing axis, across it, and height above the grip site (metres). Fingers first, then the hand body.
FINGER_BOX = ((0.038, 0.066), (-0.011, 0.011), (-0.01, 0.045))
HAND_BOX = ((-0.105, 0.105), (-0.033, 0.033), (0.031, 0.20))
BIN1_INTERIOR = ((-0.09, 0.29), (-0.49, -0.01))  # xy inside bin1's walls (wall tops at z = 0.90)


def _box_samples(box: tuple[tuple[float, float], ...], mirror: bool, n: int = 5) -> np.ndarray:
    """Grid samples (M, 3) of a hand-frame box; ``mirror`` adds its mirror image across the closing axis."""
    c, a, z = (np.linspace(lo, hi, n) for lo, hi in box)
    grid = np.stack(np.meshgrid(c, a, z, indexing="ij"), axis=-1).reshape(-1, 3)
    return np.concatenate([grid, grid * [-1, 1, 1]]) if mirror else grid


_GRIPPER_SAMPLES = np.concatenate(
    [_box_samples(FINGER_BOX, mirror=True), _box_samples(HAND_BOX, mirror=False)]
)


def blocked_samples(yaw: float, grasp: np.ndarray, obstacles: list[np.ndarray], walls: bool) -> int:
    """How many samples of the open gripper at ``grasp`` (yaw ``yaw``) lie inside obstacles or bin1's walls.

    Obstacles are point sets (N, 3); each is treated as the vertical prism over its xy convex hull up to its
    highest point.
    """
    from scipy.spatial import Delaunay

    closing = np.array([-np.sin(yaw), np.cos(yaw)])
    across = np.array([np.cos(yaw), np.sin(yaw)])
    s = _GRIPPER_SAMPLES
    xy = grasp[:2] + s[:, :1] * closing + s[:, 1:2] * across
    z = grasp[2] + s[:, 2]
    hit = np.zeros(len(s), dtype=bool)
    for pts in obstacles:
        low = z < pts[:, 2].max()
        if low.any():
            hit[low] |= Delaunay(pts[:, :2]).find_simplex(xy[low]) >= 0
    if walls:
        (x0, x1), (y0, y1) = BIN1_INTERIOR
        outside = (xy[:, 0] < x0) | (xy[:, 0] > x1) | (xy[:, 1] < y0) | (xy[:, 1] > y1)
        hit |= outside & (z < WALL_TOP)
    return int(hit.sum())


def ridge_direction(points: np.ndarray, depth: float = 0.005) -> np.ndarray | None:
    """Unit xy direction of a ridge on top of the object (top ``depth`` slice twice as long as wide), else None."""
    top = points[points[:, 2] >= points[:, 2].max() - depth][:, :2]
    if len(top) < 3:
        return None
    centred = top - top.mean(axis=0)
    evals, evecs = np.linalg.eigh(centred.T @ centred / len(top))
    return evecs[:, 1] if evals[1] > 4 * max(evals[0], 1e-12) else None


def grasp_yaw(
    points: np.ndarray, current_yaw: float, grasp: np.ndarray | None = None, obstacles: list[np.ndarray] = ()
) -> tuple[float, float]:
    """(yaw, width): a top-down grasp yaw with a near-minimal width across the fingers, near ``current_yaw``.

    Candidates are yaws within +-90 degrees of the current hand yaw (2 degree steps) whose width across the
    fingers is within ``WIDTH_SLACK`` of the minimum (e.g. both face pairs of the bread); among them, the fewest gripper samples colliding with
    ``obstacles`` / the bin walls (when ``grasp`` is given) wins, then the smallest hand rotation.
    """
    yaws = current_yaw + np.radians(np.arange(-90, 90, 2.0))
    closing = np.stack([-np.sin(yaws), np.cos(yaws)], axis=1)  # (Y, 2)
    proj = points[:, :2] @ closing.T  # (N, Y)
    widths = proj.max(axis=0) - proj.min(axis=0)
    candidates = np.flatnonzero(widths <= widths.min() + WIDTH_SLACK)
    ridge = ridge_direction(points)
    if ridge is not None:  # a gable top (milk carton): close along the ridge, onto the vertical gable ends
        along = np.abs(closing @ ridge) > np.cos(np.radians(12))
        if np.any(along[candidates]):
            candidates = candidates[along[candidates]]

    def key(i: int) -> tuple[int, float]:
        blocked = 0 if grasp is None else blocked_samples(yaws[i], grasp, list(obstacles), walls=True)
        return blocked, widths[i] + 0.005 * abs(yaws[i] - current_yaw) / (np.pi / 2)

    best = min(candidates, key=key)
    return float(yaws[best]), float(widths[best])


def quadrant_bounds(env: Any, index: int) -> tuple[np.ndarray, np.ndarray]:
    """xy low/high corners of the target quadrant ``index`` of ``bin2`` (robosuite's ``not_in_bin`` box)."""
    low = np.array(env.bin2_pos[:2], dtype=np.float64)
    if index in (0, 2):
        low[0] -= env.bin_size[0] / 2
    if index < 2:
        low[1] -= env.bin_size[1] / 2
    return low, low + np.array(env.bin_size[:2]) / 2


def place_target(env: Any, index: int, footprint_radius: float) -> np.ndarray:
    """xy target for the object centre: the quadrant point nearest the robot base, ``footprint`` off the walls."""
    low, high = quadrant_bounds(env, index)
    margin = footprint_radius + WALL_MARGIN
    if np.any(high - low < 2 * margin):
        raise ExpertFailure(f"object footprint {footprint_radius:.3f} m does not fit quadrant {index}")
    base_xy = env.sim.data.body_xpos[env.sim.model.body_name2id(env.robots[0].robot_model.root_body)][:2]
    return np.clip(base_xy, low + margin, high - margin)


def pick_place_expert(recorder: EpisodeRecorder, variation: Variation, rng: np.random.Generator) -> None:
    env = recorder.env
    arm = WaypointArm(recorder)
    name = variation.params["object"]
    index = object_index(env, name)
    obj = env.objects[index]

    pts = object_points(env, obj)
    top, bottom = pts[:, 2].max(), pts[:, 2].min()
    grasp_z = max(top - PALM_CLEARANCE, bottom + GRASP_ABOVE_BOTTOM)
    band = pts[pts[:, 2] > grasp_z - 0.02]
    centre_xy = 0.5 * (band[:, :2].max(axis=0) + band[:, :2].min(axis=0))
    grasp = np.array([*centre_xy, grasp_z])
    others = [object_points(env, o) for o in env.objects if o is not obj]
    yaw, width = grasp_yaw(band, site_yaw(grip_site_pose(env)[1]), grasp, others)
    if width > MAX_GRASP_WIDTH:
        raise ExpertFailure(f"{name} is {1000 * width:.0f} mm wide at every grasp yaw")
    yaw = wrap_angle(yaw)
    quat = top_down_quat(yaw)

    arm.move("pregrasp", grasp + [0, 0, PREGRASP_HEIGHT], quat, ignore_collision=False)
    arm.move("grasp", grasp, quat, ignore_collision=True)
    arm.grip(open=False)
    check_grasp(env, obj, name)

    below_site = (
        grip_site_pose(env)[0][2] - object_points(env, obj)[:, 2].min()
    )  # site height above the bottom
    travel_z = WALL_TOP + TRAVEL_CLEARANCE + below_site
    arm.move("lift", [*grasp[:2], travel_z], quat, ignore_collision=False)

    pts = object_points(env, obj)
    footprint = float(np.max(np.linalg.norm(pts[:, :2] - pts[:, :2].mean(axis=0), axis=1)))
    in_hand_xy = 0.5 * (pts[:, :2].max(axis=0) + pts[:, :2].min(axis=0)) - grip_site_pose(env)[0][:2]
    target_xy = place_target(env, index, footprint) - in_hand_xy
    arm.move(
        "above_bin", [*target_xy, travel_z], quat, ignore_collision=False, allow_stall=True, pos_tol=0.03
    )
    below_site = grip_site_pose(env)[0][2] - object_points(env, obj)[:, 2].min()
    release = np.array([*target_xy, BIN_FLOOR + RELEASE_HEIGHT + below_site])
    arm.move("place", release, quat, ignore_collision=True, allow_stall=True, pos_tol=0.03)
    arm.grip(open=True)
    arm.move("retreat", release + [0, 0, RETREAT], quat, ignore_collision=False)
