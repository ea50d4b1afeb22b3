"""``sigma-viz``: Rerun viewers for sigma datasets and policies.

Sub-commands (options are draccus dataclass fields, as in LeRobot's CLIs)::

    sigma-viz episode --root DIR --episode_index 0 [--save out.rrd | --web true]
    sigma-viz policy  --checkpoint DIR --root DATASET --episode_index 0 --frame_index 3 [--save out.rrd | --web true]

Delivery: ``--save PATH`` writes an ``.rrd`` (blueprint included; open it with ``rerun PATH``), ``--web true``
serves a web viewer (gRPC + web ports), otherwise a local native viewer is spawned.
"""

from __future__ import annotations

import logging
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import draccus
import rerun as rr
import rerun.blueprint as rrb

from pipelines.viz.blueprints import episode_blueprint, policy_blueprint
from pipelines.viz.episode import EpisodeLogOptions, log_episode
from pipelines.viz.episode_tracks import discover_cameras, load_episode_dataset
from sigma_data.contract import dataset_kind

logger = logging.getLogger(__name__)
SUBCOMMANDS = ("episode", "policy")


@dataclass
class ViewerDelivery:
    """Where the recording goes: ``save`` (an .rrd path) wins over ``web``; neither spawns a local viewer."""

    save: Path | None = None  # write an .rrd here (default layout included); open with `rerun PATH`
    web: bool = False  # serve a web viewer instead of spawning a native one
    web_port: int = 9090  # web viewer port (with --web true)
    grpc_port: int = 9876  # data port the web viewer connects to (with --web true)
    open_browser: bool = False  # open a browser tab on the web viewer


@dataclass
class EpisodeViewConfig(ViewerDelivery):
    root: Path | None = None  # local LeRobot dataset directory (required)
    episode_index: int = 0
    repo_id: str | None = None  # name only (no network); defaults to local/<root dir name>
    log: EpisodeLogOptions = field(default_factory=EpisodeLogOptions)


@dataclass
class PolicyViewConfig(ViewerDelivery):
    checkpoint: Path | None = None  # directory saved by SigmaPolicy.save_pretrained (required)
    root: Path | None = None  # local LeRobot (keyframe) dataset directory (required)
    episode_index: int = 0
    frame_index: int = 0  # episode-relative
    repo_id: str | None = None
    device: str = "cpu"
    point_budget: int = 50_000


def open_recording(
    application_id: str, delivery: ViewerDelivery, blueprint: rrb.Blueprint
) -> rr.RecordingStream:
    """A recording stream connected to the chosen sink, with ``blueprint`` as its default layout."""
    rec = rr.RecordingStream(application_id)
    if delivery.save is not None:
        path = Path(delivery.save)
        path.parent.mkdir(parents=True, exist_ok=True)
        rec.save(path, default_blueprint=blueprint)
    elif delivery.web:
        uri = rec.serve_grpc(grpc_port=delivery.grpc_port, default_blueprint=blueprint)
        rr.serve_web_viewer(web_port=delivery.web_port, open_browser=delivery.open_browser, connect_to=uri)
        logger.info("web viewer on http://localhost:%d (data at %s)", delivery.web_port, uri)
    else:
        rec.spawn(default_blueprint=blueprint)
    return rec


def close_recording(rec: rr.RecordingStream, delivery: ViewerDelivery) -> None:
    """Flush everything; a served web viewer keeps running until Ctrl-C."""
    rec.flush()
    if delivery.save is None and delivery.web:
        print(f"serving http://localhost:{delivery.web_port} — Ctrl-C to stop", flush=True)
        try:
            while True:
                time.sleep(1)
        except KeyboardInterrupt:
            pass
    rec.disconnect()


def run_episode_view(cfg: EpisodeViewConfig) -> str:
    """Log one dataset episode and return the one-line summary."""
    if cfg.root is None:
        raise ValueError("sigma-viz episode: --root (the local dataset directory) is required")
    ds = load_episode_dataset(cfg.root, cfg.episode_index, cfg.repo_id)
    kind = dataset_kind(Path(cfg.root), ds.features)
    cameras = [c.name for c in discover_cameras(ds.features)]
    blueprint = episode_blueprint(cameras)
    rec = open_recording(f"sigma/{Path(cfg.root).name}/episode_{cfg.episode_index}", cfg, blueprint)
    try:
        summary = log_episode(rec, ds, kind, cfg.episode_index, cfg.log)
    finally:
        close_recording(rec, cfg)
    where = f" -> {cfg.save}" if cfg.save is not None else ""
    return summary.one_line() + where


def run_policy_view(cfg: PolicyViewConfig) -> str:
    """Run the policy on one dataset frame and log its virtual views, heatmaps and prediction."""
    import torch
    from lerobot.datasets import LeRobotDataset, LeRobotDatasetMetadata
    from lerobot.datasets.factory import resolve_delta_timestamps
    from torch.utils.data import default_collate

    from pipelines.checkpoints import load_policy
    from pipelines.viz.policy import log_policy_frame, policy_frame_outputs

    if cfg.checkpoint is None or cfg.root is None:
        raise ValueError("sigma-viz policy: --checkpoint and --root are required")
    if not Path(cfg.checkpoint).is_dir():
        raise FileNotFoundError(
            f"{cfg.checkpoint}: checkpoint directory not found (pass a local pretrained_model dir)"
        )
    policy, preprocessor, _ = load_policy(cfg.checkpoint, cfg.device)

    repo_id = cfg.repo_id or f"local/{Path(cfg.root).name}"
    meta = LeRobotDatasetMetadata(repo_id, root=cfg.root)
    if not 0 <= cfg.episode_index < meta.total_episodes:
        raise ValueError(
            f"{cfg.root}: episode index {cfg.episode_index} out of range ({meta.total_episodes} episodes)"
        )
    ds = LeRobotDataset(
        repo_id,
        root=cfg.root,
        episodes=[cfg.episode_index],
        delta_timestamps=resolve_delta_timestamps(policy.config, meta),
        depth_output_unit=policy.config.depth_unit,  # the unit the policy was trained on
        video_backend="pyav",  # torchcodec cannot load without system FFmpeg; skip its noisy probe
    )
    if not 0 <= cfg.frame_index < len(ds):
        raise ValueError(
            f"{cfg.root}: episode {cfg.episode_index} has {len(ds)} frames; frame {cfg.frame_index} asked"
        )
    item = ds[cfg.frame_index]
    if int(item["frame_index"]) != cfg.frame_index:
        raise ValueError(
            f"{cfg.root}: row {cfg.frame_index} of episode {cfg.episode_index} is frame {item['frame_index']}"
        )
    batch = preprocessor(default_collate([item]))
    with torch.no_grad():
        outputs = policy_frame_outputs(policy, batch)

    num_views = len(outputs["views"])
    rec = open_recording(f"sigma/policy/{Path(cfg.root).name}", cfg, policy_blueprint(outputs["view_names"]))
    try:
        rec.set_time("frame_index", sequence=cfg.frame_index)
        summary = log_policy_frame(rec, **outputs, point_budget=cfg.point_budget)
    finally:
        close_recording(rec, cfg)
    err = (
        f", translation error {1000 * summary.translation_error_m:.1f} mm, rotation error {summary.rotation_error_deg:.1f} deg"
        if summary.translation_error_m is not None
        else ""
    )
    where = f" -> {cfg.save}" if cfg.save is not None else ""
    return f"policy frame {cfg.frame_index} of episode {cfg.episode_index}: {num_views} views{err}{where}"


def _underscore_keys(args: list[str]) -> list[str]:
    """Accept ``--episode-index`` as well as draccus' ``--episode_index`` (only option names are rewritten)."""
    out = []
    for arg in args:
        if arg.startswith("--"):
            key, sep, value = arg[2:].partition("=")
            arg = "--" + key.replace("-", "_") + sep + value
        out.append(arg)
    return out


def main(argv: list[str] | None = None) -> None:
    """Entry point of ``sigma-viz``: dispatch ``episode`` / ``policy`` to their draccus configs."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] not in SUBCOMMANDS:
        print(f"usage: sigma-viz {{{'|'.join(SUBCOMMANDS)}}} [--help] [options]", file=sys.stderr)
        raise SystemExit(2)
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    command, rest = argv[0], _underscore_keys(argv[1:])
    if command == "episode":
        print(run_episode_view(draccus.parse(EpisodeViewConfig, args=rest, prog="sigma-viz episode")))
    else:
        print(run_policy_view(draccus.parse(PolicyViewConfig, args=rest, prog="sigma-viz policy")))


if __name__ == "__main__":
    main()
