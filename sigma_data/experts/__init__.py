"""Scripted waypoint experts, one per task, on robosuite's default OSC_POSE controller.

Each expert has the signature ``expert(recorder, variation, rng) -> None`` (see :mod:`sigma_data.experts.base`)
and raises :class:`ExpertFailure` when it gives up.
"""

from sigma_data.experts.base import EpisodeRecorder, ExpertFailure, ExpertFn, WaypointArm

__all__ = ["EpisodeRecorder", "ExpertFailure", "ExpertFn", "WaypointArm"]
