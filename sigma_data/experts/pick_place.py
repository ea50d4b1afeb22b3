"""PickPlace expert: pick the named object out of the clutter in ``bin1`` and set it upright in its quadrant.

Waypoints (ignore_collision label): above the grasp point, 10 cm up and 4 cm above the tallest other object
(0) -> grasp point (1) -> close (1) -> lift so the object's bottom clears the bin walls (0) -> above the target
point in its quadrant (0) -> down until the object's bottom is 1.5 cm above the bin floor (1) -> open (1) ->
retreat 10 cm up (0). Before planning, the expert holds still until the objects have settled (some initial
placements tip over).

Geometry comes from the object's collision meshes (world vertices), so one expert handles the milk carton,
bread, cereal box and can. :func:`plan_grasp` picks the top-down grasp: a yaw with a near-minimal width across
the fingers (wider ones only as a fallback), slid along the pads' axis if that helps, such that the open
gripper, hand and wrist do not come down on a neighbour or the bin walls, and the wrist (joint 7) keeps room for
the carry to bin2. The grasp height is 3.6 cm below the top (palm clearance), at least 2 cm above the bottom.
The target is the point of the object's quadrant closest to the robot base with a margin from its walls: the
quadrant centre of the far quadrants is out of top-down reach (docs/robosuite.md §6).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from sigma_data.experts.base import EpisodeRecorder, ExpertFailure, WaypointArm, check_grasp
from sigma_data.poses import grip_site_frame, site_yaw, top_down_quat, wrap_angle
from sigma_data.tasks.geometry import ridge_direction
from sigma_data.tasks.pick_place import object_index, object_points

if TYPE_CHECKING:
    from sigma_data.tasks.spec import Variation

PREGRASP_HEIGHT = 0.10
# The open fingers reach ~1.2 cm below the grip site and the hand sweeps +-10.5 cm along the closing axis:
# the pregrasp is also this high above the tallest other object, so the approach does not shove the clutter.
PREGRASP_CLEARANCE = 0.04
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
SETTLE_SPEED = 0.0005  # m per control step: objects count as at rest below this
SETTLE_MAX_STEPS = 30


# Where the open gripper sweeps when it descends to a top-down grasp, in the hand frame: coordinate along
# the closing axis, across it, and height above the grip site (metres). Fingers first, then the hand body
# (its collision hull, +-10.5 cm x +-3.3 cm from 3.1 cm above the site, inflated by 5 mm), then the round
# wrist link 7 above it.
FINGER_BOX = ((0.038, 0.066), (-0.011, 0.011), (-0.01, 0.045))
HAND_BOX = ((-0.11, 0.11), (-0.038, 0.038), (0.031, 0.20))
WRIST_BOX = ((-0.065, 0.065), (-0.065, 0.065), (0.11, 0.25))
SAMPLE_SPACING = 0.012  # metres between gripper samples in the horizontal plane
BIN1_INTERIOR = ((-0.09, 0.29), (-0.49, -0.01))  # xy inside bin1's walls (wall tops at z = 0.90)


def _box_samples(box: tuple[tuple[float, float], ...], mirror: bool, z_levels: int = 4) -> np.ndarray:
    """Grid samples (M, 3) of a hand-frame box; ``mirror`` adds its mirror image across the closing axis."""
    (c0, c1), (a0, a1), (z0, z1) = box
    c = np.linspace(c0, c1, int(np.ceil((c1 - c0) / SAMPLE_SPACING)) + 1)
    a = np.linspace(a0, a1, int(np.ceil((a1 - a0) / SAMPLE_SPACING)) + 1)
    z = np.linspace(z0, z1, z_levels)
    grid = np.stack(np.meshgrid(c, a, z, indexing="ij"), axis=-1).reshape(-1, 3)
    return np.concatenate([grid, grid * [-1, 1, 1]]) if mirror else grid


_GRIPPER_SAMPLES = np.concatenate(
    [
        _box_samples(FINGER_BOX, mirror=True),
        _box_samples(HAND_BOX, mirror=False),
        _box_samples(WRIST_BOX, False),
    ]
)


class Obstacle:
    """An object the gripper must not touch: the vertical prism over its xy convex hull up to its top."""

    def __init__(self, points: np.ndarray):
        from scipy.spatial import Delaunay

        self.top = float(points[:, 2].max())
        self.hull = Delaunay(points[:, :2])

    def contains(self, xy: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Boolean mask (M,) of the points (xy (M, 2), z (M,)) inside the prism."""
        inside = z < self.top
        if inside.any():
            inside[inside] = self.hull.find_simplex(xy[inside]) >= 0
        return inside


def blocked_samples(yaw: float, grasp: np.ndarray, obstacles: Sequence[Obstacle], walls: bool) -> int:
    """How many samples of the open gripper at ``grasp`` (yaw ``yaw``) lie inside obstacles or bin1's walls."""
    closing = np.array([-np.sin(yaw), np.cos(yaw)])
    across = np.array([np.cos(yaw), np.sin(yaw)])
    s = _GRIPPER_SAMPLES
    xy = grasp[:2] + s[:, :1] * closing + s[:, 1:2] * across
    z = grasp[2] + s[:, 2]
    hit = np.zeros(len(s), dtype=bool)
    for obstacle in obstacles:
        hit |= obstacle.contains(xy, z)
    if walls:
        (x0, x1), (y0, y1) = BIN1_INTERIOR
        outside = (xy[:, 0] < x0) | (xy[:, 0] > x1) | (xy[:, 1] < y0) | (xy[:, 1] > y1)
        hit |= outside & (z < WALL_TOP)
    return int(hit.sum())


# Joint 7 at the grasp (rad, range +-2.9): carrying the object to bin2 turns it by +0.4..+1.3 rad more.
GRASP_WRIST_RANGE = (-2.5, 1.3)
GRASP_SHIFTS = np.array([0.0, -0.01, 0.01, -0.02, 0.02, -0.03, 0.03])  # m along the fingers' pad axis
PAD_HALF_WIDTH = 0.011  # finger pad half extent across the closing axis (m)
PAD_MARGIN = 0.004  # keep the pads this far inside the object's extent when sliding the grasp


def grasp_band(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the vertices the pads may close on, the grasp point (3,)) of an object's world vertices ``pts``: the grasp
    height is ``PALM_CLEARANCE`` below the top, at least ``GRASP_ABOVE_BOTTOM`` above the bottom; the band is every
    vertex from 2 cm below it up, and the grasp point the middle of the band's footprint. :func:`plan_grasp` then
    chooses the yaw."""
    top, bottom = pts[:, 2].max(), pts[:, 2].min()
    grasp_z = max(top - PALM_CLEARANCE, bottom + GRASP_ABOVE_BOTTOM)
    band = pts[pts[:, 2] > grasp_z - 0.02]
    centre_xy = 0.5 * (band[:, :2].max(axis=0) + band[:, :2].min(axis=0))
    return band, np.array([*centre_xy, grasp_z])


def plan_grasp(
    points: np.ndarray,
    current_yaw: float,
    grasp: np.ndarray,
    obstacles: Sequence[np.ndarray] = (),
    wrist: float | None = None,
) -> tuple[float, float, np.ndarray]:
    """(yaw, width, grasp point (3,)): a top-down grasp of ``points`` that keeps the open gripper off ``obstacles``.

    Candidate yaws lie within +-150 degrees of the current hand yaw (2 degree steps; the servo turns the short
    way) and, given the current ``wrist`` angle (joint 7, rad), keep its predicted value at the grasp inside
    ``GRASP_WRIST_RANGE`` (joint 7 turns opposite to the site yaw). Preferred are widths across the fingers
    within ``WIDTH_SLACK`` of the minimum (e.g. both face pairs of the bread); for a gable top (milk
    carton) only those closing along the ridge. Each may slide the grasp point along the pads' axis by
    ``GRASP_SHIFTS`` while the pads stay on the object. The candidate with the fewest gripper samples inside
    ``obstacles`` / bin1's walls wins, then the smallest slide, then the narrowest width with the smallest hand
    rotation: in clutter the hand descends beside its neighbours instead of onto them.
    """
    yaws = current_yaw + np.radians(np.arange(-150, 151, 2.0))
    if wrist is not None:
        predicted = wrist - (yaws - current_yaw)
        reachable = (predicted >= GRASP_WRIST_RANGE[0]) & (predicted <= GRASP_WRIST_RANGE[1])
        if not reachable.any():
            raise ExpertFailure(f"no grasp yaw keeps the wrist in range (joint 7 at {wrist:.2f} rad)")
        yaws = yaws[reachable]
    closing = np.stack([-np.sin(yaws), np.cos(yaws)], axis=1)  # (Y, 2)
    proj = points[:, :2] @ closing.T  # (N, Y)
    widths = proj.max(axis=0) - proj.min(axis=0)
    preferred = widths <= widths.min() + WIDTH_SLACK
    ridge = ridge_direction(points)
    if ridge is not None:  # a gable top (milk carton): close along the ridge, onto the vertical gable ends
        along = np.abs(closing @ ridge) > np.cos(np.radians(12))
        if np.any(along & preferred):
            preferred &= along
    # Wider yaws are fallbacks for when every preferred grasp is blocked (a small object boxed in).
    candidates = np.flatnonzero(preferred | ((widths <= MAX_GRASP_WIDTH - 0.01) & (ridge is None)))
    hulls = [Obstacle(pts) for pts in obstacles]

    best_key, best = None, None
    for i in candidates:
        across = np.array([np.cos(yaws[i]), np.sin(yaws[i])])
        extent = (points[:, :2] - grasp[:2]) @ across
        room = PAD_HALF_WIDTH + PAD_MARGIN
        for shift in GRASP_SHIFTS if preferred[i] else (0.0,):
            if shift != 0.0 and not (extent.min() + room <= shift <= extent.max() - room):
                continue
            point = grasp + np.array([*(shift * across), 0.0])
            blocked = blocked_samples(yaws[i], point, hulls, walls=True)
            rotation = 0.005 * abs(yaws[i] - current_yaw) / (np.pi / 2)
            key = (blocked, not preferred[i], abs(shift), widths[i] + rotation)
            if best_key is None or key < best_key:
                best_key, best = key, (float(yaws[i]), float(widths[i]), point)
    return best


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


def settle(arm: WaypointArm, objects: Sequence[Any], max_steps: int = SETTLE_MAX_STEPS) -> None:
    """Hold still until every object moves less than ``SETTLE_SPEED`` for 3 steps in a row (<= ``max_steps``).

    Some initial placements are unstable (a box resting on a neighbour's edge tips over in the first
    ~15 steps); planning on them grasps where the object was.
    """
    env = arm.env
    ids = [env.sim.model.body_name2id(o.root_body) for o in objects]
    prev = np.array(env.sim.data.body_xpos[ids])
    still = 0
    for _ in range(max_steps):
        arm.hold(1)
        now = np.array(env.sim.data.body_xpos[ids])
        still = still + 1 if np.max(np.linalg.norm(now - prev, axis=1)) < SETTLE_SPEED else 0
        prev = now
        if still >= 3:
            return


def pick_place_expert(recorder: EpisodeRecorder, variation: Variation, rng: np.random.Generator) -> None:
    env = recorder.env
    arm = WaypointArm(recorder, rng=rng)
    name = variation.params["object"]
    index = object_index(env, name)
    obj = env.objects[index]
    settle(arm, env.objects)

    band, grasp = grasp_band(object_points(env, obj))
    others = [object_points(env, o) for o in env.objects if o is not obj]
    wrist = float(env.sim.data.qpos[env.robots[0]._ref_joint_pos_indexes[6]])
    yaw, width, grasp = plan_grasp(band, site_yaw(grip_site_frame(env)[1]), grasp, others, wrist)
    if width > MAX_GRASP_WIDTH:
        raise ExpertFailure(f"{name} is {1000 * width:.0f} mm wide at every grasp yaw")
    yaw = wrap_angle(yaw)
    quat = top_down_quat(yaw)

    clutter_top = max(o[:, 2].max() for o in others)
    pregrasp_z = max(grasp[2] + PREGRASP_HEIGHT, clutter_top + PREGRASP_CLEARANCE)
    arm.move("pregrasp", [*grasp[:2], pregrasp_z], quat, ignore_collision=False, approach=True)
    arm.move("grasp", grasp, quat, ignore_collision=True)
    arm.grip(open=False)
    check_grasp(env, obj, name)

    below_site = (
        grip_site_frame(env)[0][2] - object_points(env, obj)[:, 2].min()
    )  # site height above the bottom
    travel_z = WALL_TOP + TRAVEL_CLEARANCE + below_site
    arm.move("lift", [*grasp[:2], travel_z], quat, ignore_collision=False)

    pts = object_points(env, obj)
    footprint = float(np.max(np.linalg.norm(pts[:, :2] - pts[:, :2].mean(axis=0), axis=1)))
    in_hand_xy = 0.5 * (pts[:, :2].max(axis=0) + pts[:, :2].min(axis=0)) - grip_site_frame(env)[0][:2]
    target_xy = place_target(env, index, footprint) - in_hand_xy
    arm.move(
        "above_bin", [*target_xy, travel_z], quat, ignore_collision=False, allow_stall=True, pos_tol=0.03
    )
    below_site = grip_site_frame(env)[0][2] - object_points(env, obj)[:, 2].min()
    release = np.array([*target_xy, BIN_FLOOR + RELEASE_HEIGHT + below_site])
    arm.move("place", release, quat, ignore_collision=True, allow_stall=True, pos_tol=0.03)
    arm.grip(open=True)
    # Near the far corner of bin2 the stretched arm may stall short of the full retreat; the success check
    # (object in its quadrant, gripper away from it) decides.
    arm.move(
        "retreat", release + [0, 0, RETREAT], quat, ignore_collision=False, allow_stall=True, pos_tol=0.04
    )
