"""Rerun viewers: dataset episodes in 3D (cameras, depth, keyframes, goals) and policy decisions (virtual
views, translation heatmaps, predicted vs ground-truth keyframe poses). CLI: ``sigma-viz`` (:mod:`.cli`)."""

from pipelines.viz.blueprints import episode_blueprint, policy_blueprint
from pipelines.viz.episode import EpisodeLogOptions, EpisodeLogSummary, log_episode
from pipelines.viz.policy import PolicyFrameSummary, log_policy_frame, policy_frame_outputs

__all__ = [
    "EpisodeLogOptions",
    "EpisodeLogSummary",
    "PolicyFrameSummary",
    "episode_blueprint",
    "log_episode",
    "log_policy_frame",
    "policy_blueprint",
    "policy_frame_outputs",
]
