"""Undoing an empty grasp in ``sigma-eval``: the fingers closed on nothing, so the hand opens and goes back to
where it approached from, and the policy is asked again (``--regrasps``).

A keyframe policy acts once per keyframe from what it sees, so an empty close is not the end of an episode: the
gripper's finger gap, which the policy reads too (``agent_pos``), says nothing is held. Retrying a missed grasp
is what a grasping system does on a real robot (the gripper's width is its cheapest sensor); here it is an
evaluation option, off by default, and every retreat is a keyframe of the episode's budget (``max_keyframes``), so
an episode with retries has fewer keyframes left for the task, never more.

:func:`grasp_is_empty` says when to retreat; :func:`retreat_keyframe` says where to: the last keyframe before the
close that was at least :data:`APPROACH_RISE_M` above it with the gripper open (the approach the policy chose
before going down), else straight up from the close by :data:`FALLBACK_RISE_M`, with the gripper opened there
(the executor moves the arm first, then the gripper: ``sigma_data/keyframe_executor.py``).
"""

from __future__ import annotations

import numpy as np

from pipelines.failures import EMPTY_GRIP_GAP_M

__all__ = ["APPROACH_RISE_M", "FALLBACK_RISE_M", "grasp_is_empty", "retreat_keyframe"]

# A keyframe at least this far above the close, with the gripper open, is the approach the hand came down from.
APPROACH_RISE_M = 0.03
# Without such a keyframe (the policy closed where it arrived) the hand rises this far above the close.
FALLBACK_RISE_M = 0.08


def grasp_is_empty(step: dict) -> bool:
    """True when the keyframe traced in ``step`` left the gripper commanded closed with its fingers together
    (gap under ``EMPTY_GRIP_GAP_M``, the rule ``pipelines/failures.py`` calls a missed grasp)."""
    return step["action"][7] <= 0.5 and step["finger_gap_m"] < EMPTY_GRIP_GAP_M


def retreat_keyframe(trace: list[dict]) -> np.ndarray:
    """The 9-D keyframe that undoes the last close of ``trace`` (see the module docstring): the approach pose the
    policy came down from, or the close's pose raised by ``FALLBACK_RISE_M``; gripper open, collisions ignored."""
    close = max((i for i, step in enumerate(trace) if step["closed_now"]), default=len(trace) - 1)
    closed_at = np.asarray(trace[close]["action"][:7], dtype=np.float64)
    for step in reversed(trace[:close]):
        action = step["action"]
        if action[7] > 0.5 and action[2] >= closed_at[2] + APPROACH_RISE_M:
            return np.array([*action[:7], 1.0, 1.0])
    return np.array([*closed_at[:2], closed_at[2] + FALLBACK_RISE_M, *closed_at[3:7], 1.0, 1.0])
