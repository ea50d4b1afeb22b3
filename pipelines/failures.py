"""Why a ``sigma-eval`` episode failed, read from its keyframe trace and the scene.

:func:`failure_reason` turns an episode's trace into one short, task-independent reason (wrong object, off the
handle, grasp missed, dropped, repeats, not reached, timeout); :func:`failure_kind` is the kind a table counts. The scene
probes the evaluation worker records at each keyframe live here too: :func:`nearest_variation` (which object the
hand is over), :func:`grasp_fit` (how the object sits between the fingers), :func:`handle_fit` (how far round a
handled object from its handle the hand is), :func:`placement_fit` (how the object sits over where it must end)
and :func:`other_variation_done` (the scene ended in another instruction's success).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from pipelines.rollout import EpisodeResult

# Panda fingers: each joint travels 0..0.04 m; a closed gripper whose gap is below this holds nothing.
EMPTY_GRIP_GAP_M = 0.01
# Two consecutive keyframes this close, turned this little, with the same gripper command, make no progress: the
# policy is stuck. Door's first two keyframes turn the hand in place, so the place alone is not a repeat. The policy
# turns in 5° bins: the bound lies between one bin and two, so a one-bin jitter is a repeat whatever the rounding.
REPEAT_TOLERANCE_M = 0.01
REPEAT_TOLERANCE_DEG = 7.5
# A handled object (the nuts) grasped further round from its handle than this held it by its body. Both nuts'
# handles are bars 31.75 mm wide (robosuite's square-nut.xml and round-nut.xml); the open fingers (78 mm) straddle
# one only while its centre line passes within 39 - 15.9 = 23 mm of the grip site, 25° round at the expert's grasp
# 55 mm from the centre. Inside that the closing fingers centre the bar and the nut sits in the hand as the expert
# holds it; outside, the hand holds the ring and the nut hangs off to one side of where the policy places it.
OFF_HANDLE_DEG = 25


def failure_reason(result: EpisodeResult, max_keyframes: int) -> str | None:
    """A short, task-independent reason for a failed episode, from its keyframe trace.

    In order of precedence: ``error: ...`` (an exception); ``wrong object: did <variation>`` (the scene ended in
    another variation's success state: the policy did the other instruction); ``wrong object at keyframe k: went
    for <variation>`` (the gripper first closed nearer another variation's object than the instructed one, see
    :func:`nearest_variation`: the policy did not ground the instruction); ``grasped off the handle at keyframe k
    (...); then <what followed>`` (a handled object held by its body, more than ``OFF_HANDLE_DEG`` round from its
    handle, :func:`handle_fit`; the rest of the trace then decides what followed, usually a drop beside the goal);
    ``grasp missed at keyframe k`` (the
    gripper closed on nothing: finger gap below 1 cm once the close has finished, :func:`_settled_gap`; where the
    task's objects have ``points``, followed by how the object sat between the open fingers, :func:`grasp_fit`:
    wider than the 78 mm gap means the hand's yaw was wrong, far off centre its position; where they have a handle,
    :func:`handle_fit`: how far round the object from its handle the hand came down);
    ``dropped at keyframe k`` (something was held, then the gripper opened away from success; where the task has a
    ``placement``, followed by how the object sat over its goal, :func:`placement_fit`); ``repeats keyframe
    k`` (the next keyframe is the same position, within 1 cm, the same orientation, within 7.5°, and the same gripper
    command: stuck; Door's in-place turns of the hand are not repeats); ``keyframe k not reached
    (stalled|budget)`` (the executor could not get the arm there); ``timeout after N keyframes`` (every move
    converged but the task never succeeded). The last two end with where the task's joints were at the end, for a
    task that has them (``TaskSpec.progress``: Door's hinge and lever).
    """
    import numpy as np

    from pipelines.keyframe_errors import geodesic_deg

    if result.success:
        return None
    if result.error is not None:
        return f"error: {result.error.splitlines()[0][:120]}"
    if result.other_variation is not None:
        return f"wrong object: did {result.other_variation}"
    held = False
    # "grasped off the handle at keyframe k (...); then ", once the hand holds a nut by its ring
    off_handle = ""
    for i, step in enumerate(result.trace):
        k = step["keyframe"]
        nearest = step.get("nearest")
        if step["closed_now"] and not held and nearest is not None and nearest != result.variation:
            return f"wrong object at keyframe {k}: went for {nearest}"
        if step["closed_now"] and _settled_gap(result.trace, i) < EMPTY_GRIP_GAP_M:
            return off_handle + f"grasp missed at keyframe {k}" + _fit_text(result.trace, i)
        if step["closed_now"] and not held and abs(_handle_angle(result.trace, i)) > OFF_HANDLE_DEG:
            off_handle = f"grasped off the handle at keyframe {k}" + _fit_text(result.trace, i) + "; then "
        held = held or step["closed_now"]
        if held and step["opened_now"]:
            return off_handle + f"dropped at keyframe {k}" + _placement_text(result.trace, i)
    for prev, step in zip(result.trace, result.trace[1:], strict=False):
        same_place = math.dist(prev["action"][:3], step["action"][:3]) < REPEAT_TOLERANCE_M
        same_turn = (
            geodesic_deg(np.array(prev["action"][3:7]), np.array(step["action"][3:7])) < REPEAT_TOLERANCE_DEG
        )
        if same_place and same_turn and prev["action"][7] == step["action"][7]:
            return off_handle + f"repeats keyframe {prev['keyframe']}"
    for step in result.trace:
        if step["arm_status"] != "converged":
            return (
                off_handle
                + f"keyframe {step['keyframe']} not reached ({step['arm_status']})"
                + _progress_text(result.trace)
            )
    return (
        off_handle
        + f"timeout after {len(result.trace)} keyframes"
        + ("" if len(result.trace) >= max_keyframes else " (stopped)")
        + _progress_text(result.trace)
    )


def _progress_text(trace: list[dict]) -> str:
    """Where the task's joints ended (``TaskSpec.progress``, e.g. Door's ``hinge_rad`` and ``lever_rad``), as
    ``"; at the end hinge_rad 0.05, lever_rad 0.8"``; empty for a task without them."""
    progress = trace[-1].get("progress") if trace else None
    if not progress:
        return ""
    return "; at the end " + ", ".join(f"{name} {value}" for name, value in progress.items())


def _placement_text(trace: list[dict], i: int) -> str:
    """How the object sat over its goal when the gripper opened at ``trace[i]`` (:func:`placement_fit`), from the
    keyframe before (the pose it was let go from) else the opening itself, as ``" (from peg 9 mm, turned 12°, peg
    margin -2 mm)"``; empty where neither recorded it (the object was not over its goal)."""
    step = _before_or_at(trace, i, "placement")
    if step is None:
        return ""
    parts = []
    for name, value in step["placement"].items():
        words, _, unit = name.rpartition("_")
        parts.append(f"{words.replace('_', ' ')} {value}" + ("°" if unit == "deg" else f" {unit}"))
    return " (" + ", ".join(parts) + ")"


def _handle_angle(trace: list[dict], i: int) -> float:
    """How far round its object from its handle (degrees) the hand was for the close at ``trace[i]``
    (:func:`handle_fit`, from the grasp pose before it as :func:`_fit_text` reads it); 0 where neither recorded it."""
    handle = _before_or_at(trace, i, "round_from_handle_deg")
    return 0.0 if handle is None else float(handle["round_from_handle_deg"])


def _fit_text(trace: list[dict], i: int) -> str:
    """How the object sat between the fingers for the close at ``trace[i]`` (:func:`grasp_fit`), or where round a
    handled object the hand was (:func:`handle_fit`), from the keyframe before it where the hand was already down
    (the grasp pose, fingers open), else from the close itself."""
    handle = _before_or_at(trace, i, "round_from_handle_deg")
    if handle is not None:
        return (
            f" ({handle['round_from_handle_deg']}° round the object from its handle,"
            f" {handle['from_centre_mm']} mm from its centre)"
        )
    fit = _before_or_at(trace, i, "across_fingers_mm")
    if fit is None:
        return ""
    ridge = f", closing {fit['ridge_deg']}° off its ridge" if "ridge_deg" in fit else ""
    return (
        f" ({fit['across_fingers_mm']} mm across the fingers, {fit['off_centre_mm']} mm off centre,"
        f" {fit['below_top_mm']} mm below its top{ridge})"
    )


def _before_or_at(trace: list[dict], i: int, key: str) -> dict | None:
    """The keyframe before ``trace[i]`` (a close or an opening: the pose the hand acted from) if it recorded ``key``,
    else ``trace[i]`` if it did, else None."""
    return next((trace[j] for j in (i - 1, i) if j >= 0 and key in trace[j]), None)


def _settled_gap(trace: list[dict], i: int) -> float:
    """The finger gap once the close at ``trace[i]`` has finished: a close whose arm stalled (blocked on the object)
    can end before the fingers meet, so the next keyframe's gap counts too unless it opens the gripper."""
    gap = trace[i]["finger_gap_m"]
    if i + 1 < len(trace) and not trace[i + 1]["opened_now"]:
        gap = min(gap, trace[i + 1]["finger_gap_m"])
    return gap


def nearest_variation(env) -> dict[str, str]:
    """``{"nearest": <variation>}``: the variation of ``env``'s task whose object (``TaskSpec.target``) is nearest
    the grip site in the horizontal plane, e.g. which PickPlace object the hand is over; ``{}`` for a task with
    one object."""
    import numpy as np

    from sigma_data.poses import grip_site_frame

    task = env.task
    if task.target is None or len(task.variations) < 2:
        return {}
    site = grip_site_frame(env.env)[0][:2]
    dist = {v.name: float(np.linalg.norm(task.target(env.env, v)[:2] - site)) for v in task.variations}
    return {"nearest": min(dist, key=dist.get)}


# The finger pads reach this far below the grip site (m): an object's vertices above it are what they close on
# (the vertices above, not a band at the pads' height: a can's or a box's mesh has vertices only at its corners).
PAD_BELOW_SITE_M = 0.01


def grasp_fit(env, variation: str) -> dict[str, int]:
    """How the object of ``variation`` sits between the fingers now, from its vertices (``TaskSpec.points``) above
    the pads' lower edge; ``{}`` for a task without ``points`` or a hand not down at the object:

    * ``across_fingers_mm``: its width along the closing axis (wider than the open gap, 78 mm for the Panda, it
      cannot be grasped at this yaw);
    * ``off_centre_mm``: how far its middle is from the fingers' midpoint along that axis;
    * ``below_top_mm``: how far the grip site is below the object's top (the expert grasps 36 mm below it, the
      palm's clearance, or 20 mm above the bottom of a short object; near 0 or negative: the hand is on top of it);
    * ``ridge_deg``, only for an object whose top is elongated (the milk carton's gable ridge; the long axis of the
      cereal box's top): the angle between the closing axis and it, 0-90 (the expert closes along the carton's
      ridge, within 12°, onto the vertical gable ends).

    At the expert's grasp (seed 0) PickPlace's objects are 31-50 mm across the fingers; turned 45° from it the
    cereal box is 93 mm (it no longer fits), the bread 62 mm and the milk carton 56 mm (they still do), the can 50.
    """
    import numpy as np

    from sigma_data.poses import grip_site_frame
    from sigma_data.suite import get_variation
    from sigma_data.tasks.geometry import ridge_direction

    task = env.task
    if task.points is None:
        return {}
    site, rot = grip_site_frame(env.env)
    pts = task.points(env.env, get_variation(task, variation))
    band = pts[pts[:, 2] > site[2] - PAD_BELOW_SITE_M]
    if len(band) == 0:
        return {}
    closing = rot[:2, 0] / np.linalg.norm(rot[:2, 0])  # the site's x axis points from one finger to the other
    proj = band[:, :2] @ closing
    middle = 0.5 * (proj.max() + proj.min())
    fit = {
        "across_fingers_mm": round(1000 * float(proj.max() - proj.min())),
        "off_centre_mm": round(1000 * abs(float(middle - site[:2] @ closing))),
        "below_top_mm": round(1000 * float(pts[:, 2].max() - site[2])),
    }
    ridge = ridge_direction(pts)
    if ridge is not None:
        fit["ridge_deg"] = round(float(np.degrees(np.arccos(min(1.0, abs(float(closing @ ridge)))))))
    return fit


# A hand this far from a handled object's centre (horizontally, m) is not at the object: no handle_fit.
HANDLE_NEAR_M = 0.12


def handle_fit(env, variation: str) -> dict[str, int]:
    """Where the hand is round an object grasped by a handle off its middle (``TaskSpec.centre``; the nuts), seen
    from above; ``{}`` for a task without one or a hand more than ``HANDLE_NEAR_M`` from the object's centre:

    * ``round_from_handle_deg``: the angle at the object's centre from its handle (``TaskSpec.target``) to the grip
      site, -180..180 (counter-clockwise positive);
    * ``from_centre_mm``: the grip site's distance from the centre.

    The expert grasps 8 mm beyond the handle site (0°, 62 mm from the square nut's centre): a grasp at the handle's
    distance but tens of degrees round came down where the handle would be were the nut turned, on its ring.
    """
    import numpy as np

    from sigma_data.poses import grip_site_frame, wrap_angle
    from sigma_data.suite import get_variation

    task = env.task
    if task.centre is None or task.target is None:
        return {}
    v = get_variation(task, variation)
    centre = task.centre(env.env, v)[:2]
    to_handle = task.target(env.env, v)[:2] - centre
    to_site = grip_site_frame(env.env)[0][:2] - centre
    if np.linalg.norm(to_site) > HANDLE_NEAR_M:
        return {}
    angle = np.arctan2(to_site[1], to_site[0]) - np.arctan2(to_handle[1], to_handle[0])
    return {
        "round_from_handle_deg": round(float(np.degrees(wrap_angle(float(angle))))),
        "from_centre_mm": round(1000 * float(np.linalg.norm(to_site))),
    }


def placement_fit(env) -> dict[str, dict[str, int]]:
    """``{"placement": {...}}``: how the instructed object sits over where it must end (``TaskSpec.placement``,
    e.g. the nut's distance from its peg and how far inside its hole the peg stays); ``{}`` for a task without one
    or an object not over its goal."""
    task = env.task
    fit = task.placement(env.env, env.variation) if task.placement is not None else {}
    return {"placement": fit} if fit else {}


def other_variation_done(env) -> str | None:
    """The name of another variation of ``env``'s task whose success check passes now, if any."""
    for variation in env.task.variations:
        if variation.name != env.variation.name and env.task.success(env.env, variation):
            return variation.name
    return None


FAILURE_KINDS = (
    "error",
    "wrong object",
    "off the handle",
    "grasp missed",
    "dropped",
    "repeats",
    "not reached",
    "timeout",
)


def failure_kind(reason: str) -> str:
    """``grasp missed at keyframe 3`` -> ``grasp missed``: the kind of a :func:`failure_reason`, the first of
    :data:`FAILURE_KINDS` it names (``grasped off the handle at keyframe 3 (...); then dropped at keyframe 7`` is
    ``off the handle``: the first thing that went wrong)."""
    return next((kind for kind in FAILURE_KINDS if kind in reason), reason)
