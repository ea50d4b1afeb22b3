"""Collection speed: robosuite's own camera loop vs ``sigma-data collect`` on the same episodes.

Baseline: robosuite env with camera observations every step (``use_camera_obs=True``, RGB-D, default render
settings), the same scripted expert, every step's observation written frame by frame (``add_frame``) into a dense
LeRobot dataset with the same features and encoders. sigma: record without rendering, replay states, render only
stored frames with the fast settings. All measured in the same run; prints a Markdown table of ratios.

    python benchmarks/bench_collect.py                      # lift, 4 episodes, 4 RGB-D cameras at 128x128
    python benchmarks/bench_collect.py --task=stack --episodes=6 --workers=2
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")
import draccus
import numpy as np

import sigma_data  # noqa: F401  (headless GL before robosuite)
from sigma_data.cameras import DEFAULT_CAMERAS
from sigma_data.collect import CollectConfig, collect


@dataclass
class BenchConfig:
    # Registry task whose expert runs in every row.
    task: str = "lift"
    # Episodes (seeds 0..episodes-1) per row.
    episodes: int = 4
    # Cameras, comma-separated.
    cameras: str = ",".join(DEFAULT_CAMERAS)
    # Image size in pixels (square).
    size: int = 128
    # Worker count for the scaling row (compared with 1 worker, keyframe dataset).
    workers: int = 2
    # Where the datasets go (default: a temporary directory).
    workdir: Path | None = None
    # Write benchmarks/results/collect.md (+ .json), the fragment RESULTS.md includes.
    publish: bool = True


class BaselineDriver:
    """Drives the expert on an env with camera observations; writes every step's observation."""

    def __init__(self, env, dataset, cameras, size, instruction):
        self.env, self.dataset, self.cameras, self.size, self.instruction = (
            env,
            dataset,
            cameras,
            size,
            instruction,
        )
        self.steps = 0
        self.write_s = 0.0

    @property
    def num_steps(self) -> int:
        return self.steps

    def mark_keyframe(self, gripper_open: bool, ignore_collision: bool) -> None:
        pass

    def step(self, action) -> None:
        from robosuite.utils import camera_utils as cu

        from sigma_data.record import robot_state

        obs, *_ = self.env.step(action)
        t0 = time.perf_counter()
        sim = self.env.sim
        frame = {}
        for cam in self.cameras:
            frame[f"observation.images.{cam}"] = np.ascontiguousarray(obs[f"{cam}_image"][::-1])
            depth = cu.get_real_depth_map(sim, obs[f"{cam}_depth"])[::-1]
            frame[f"observation.images.{cam}_depth"] = np.minimum(depth, 3.0).astype(np.float32)
            frame[f"observation.camera.{cam}.intrinsics"] = cu.get_camera_intrinsic_matrix(
                sim, cam, self.size, self.size
            ).astype(np.float32)
            frame[f"observation.camera.{cam}.extrinsics"] = cu.get_camera_extrinsic_matrix(sim, cam).astype(
                np.float32
            )
        frame["observation.state"] = robot_state(self.env, bool(action[-1] < 0))
        frame["action"] = np.asarray(action, dtype=np.float32)
        frame["sigma.is_keyframe"] = np.array([False])
        frame["sigma.next_keyframe_index"] = np.array([0], dtype=np.int64)
        self.dataset.add_frame({**frame, "task": self.instruction})
        self.write_s += time.perf_counter() - t0
        self.steps += 1


def run_baseline(cfg: BenchConfig, root: Path) -> dict:
    import robosuite as suite
    from lerobot.configs.video import DepthEncoderConfig
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from robosuite.controllers import load_composite_controller_config

    from sigma_data.experts.base import ExpertFailure
    from sigma_data.tasks import get_task, reset_env
    from sigma_data.tasks.registry import CONTROL_FREQ, CONTROLLER, ROBOT
    from sigma_data.writers import DatasetLayout, DenseWriter

    cams = tuple(c for c in cfg.cameras.split(","))
    task = get_task(cfg.task)
    variation = task.variations[0]
    np.random.seed(0)
    env = suite.make(
        task.env_name,
        robots=ROBOT,
        controller_configs=load_composite_controller_config(controller=CONTROLLER, robot=ROBOT),
        control_freq=CONTROL_FREQ,
        has_renderer=False,
        has_offscreen_renderer=True,
        use_camera_obs=True,
        camera_names=list(cams),
        camera_heights=cfg.size,
        camera_widths=cfg.size,
        camera_depths=True,
        ignore_done=True,
        hard_reset=False,
        **dict(task.env_kwargs),
    )
    features = DenseWriter.features_for(DatasetLayout(cams, cfg.size, cfg.size), "video")
    dataset = LeRobotDataset.create(
        "local/baseline",
        fps=20,
        features=features,
        root=root,
        robot_type="panda",
        streaming_encoding=True,
        depth_encoder=DepthEncoderConfig(depth_min=0.02, depth_max=3.0),
        video_backend="pyav",
    )
    start = time.perf_counter()
    kept = steps = 0
    write_s = 0.0
    try:
        for seed in range(cfg.episodes):
            reset_env(env, task, variation, seed)
            driver = BaselineDriver(env, dataset, cams, cfg.size, variation.instruction)
            try:
                task.expert(driver, variation, np.random.default_rng(seed))
                ok = task.success(env, variation)
            except ExpertFailure:
                ok = False
            t0 = time.perf_counter()
            if ok:
                dataset.save_episode()
                kept += 1
            else:
                dataset.clear_episode_buffer()
            write_s += driver.write_s + time.perf_counter() - t0
            steps += driver.steps
    finally:
        t0 = time.perf_counter()
        dataset.finalize()
        write_s += time.perf_counter() - t0
        env.close()
    wall = time.perf_counter() - start
    return {"wall": wall, "kept": kept, "steps": steps, "write_s": write_s}


def main() -> None:
    cfg = draccus.parse(BenchConfig)
    work = Path(cfg.workdir or tempfile.mkdtemp(prefix="bench_collect_"))
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    base = CollectConfig(
        tasks=cfg.task,
        episodes=cfg.episodes,
        cameras=cfg.cameras,
        height=cfg.size,
        width=cfg.size,
        shard_size=cfg.episodes,
        progress=False,
    )
    rows = []

    b = run_baseline(cfg, work / "baseline")
    base_rate = b["kept"] / b["wall"] * 60
    rows.append(
        ("robosuite loop, cameras every step, dense written", b["kept"], b["wall"], base_rate, "1.00x", "")
    )

    def sigma(name: str, **kw) -> tuple:
        c = replace(base, output_dir=work / name, **kw)
        s = collect(c)
        rate = s.kept / s.wall_s * 60
        render = sum(r.render_s for r in s.shards)
        write = sum(r.write_s for r in s.shards)
        frames = sum(r.rendered_frames for r in s.shards)
        note = f"render {1000 * render / max(frames, 1):.1f} ms/frame, write/render {write / max(render, 1e-9):.0%}"
        return (name, s.kept, s.wall_s, rate, f"{rate / base_rate:.2f}x", note), s

    row, _ = sigma("sigma keyframe", dense=False)
    rows.append(row)
    row, _ = sigma("sigma dense", keyframe=False)
    rows.append(row)
    row1, _ = sigma("sigma keyframe, 1 worker, 1-episode shards", dense=False, shard_size=1)
    rowN, _ = sigma(f"sigma keyframe, {cfg.workers} workers", dense=False, shard_size=1, workers=cfg.workers)
    rowN = (*rowN[:5], f"{rowN[3] / row1[3]:.2f}x vs 1 worker; " + rowN[5])
    rows += [row1, rowN]

    import resource

    peak_mb = {
        who: resource.getrusage(flag).ru_maxrss / 1024
        for who, flag in (
            ("this process", resource.RUSAGE_SELF),
            ("worker processes", resource.RUSAGE_CHILDREN),
        )
    }
    lines = [
        f"{cfg.task}, {cfg.episodes} episodes, cameras {cfg.cameras} at {cfg.size}x{cfg.size}, same seeds.",
        "",
        "| run | kept | wall s | episodes/min | vs baseline | notes |",
        "|---|---|---|---|---|---|",
        *(
            f"| {name} | {kept} | {wall:.1f} | {rate:.2f} | {ratio} | {note} |"
            for name, kept, wall, rate, ratio, note in rows
        ),
    ]
    table = "\n".join(lines)
    print("\n" + table)
    notes = (
        f"Baseline writer time {b['write_s']:.1f} s of {b['wall']:.1f} s. Peak resident memory: "
        + ", ".join(f"{who} {mb:.0f} MiB" for who, mb in peak_mb.items())
        + " (the largest single process of each kind)."
    )
    print(f"\n{notes} Data under {work}")
    if cfg.publish:
        from pipelines.reporting import write_report

        data = [
            dict(zip(("run", "kept", "wall_s", "episodes_per_min", "vs_baseline", "notes"), r, strict=True))
            for r in rows
        ]
        write_report(
            "collect",
            "Collection vs robosuite's own camera loop",
            table,
            {"rows": data, "peak_mb": peak_mb},
            notes,
        )


if __name__ == "__main__":
    main()
