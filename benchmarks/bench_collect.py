"""Collection speed: robosuite's own camera loop vs ``sigma-data collect`` on the same episodes.

Baseline: robosuite env with camera observations every step (``use_camera_obs=True``, RGB-D, default render
settings), the same scripted expert, every step's observation written frame by frame (``add_frame``) into a dense
LeRobot dataset with the same features and encoders. sigma: record without rendering, replay states, render only
stored frames with the fast settings; with ``sigma-data collect``'s defaults (one worker: render threads = cores,
the next episode recorded while this one renders and writes). "render ms/frame" is the render threads' time per
frame (threads share the cores, so it is longer than a frame rendered alone); "write/render" is the writing
thread's own time (not waiting for frames) over it. Every run goes in a fresh process, so its peak resident memory
(``ru_maxrss`` of the process and of its largest child) is its own; each clock starts after the same imports
and includes building the env(s), creating and finalizing the datasets (sigma: and merging the shards). The
scaling rows (1 worker; 1 worker with one render thread, which works in turn like each of the workers of the
last row; ``--workers``) collect twice as many episodes in shards of 10, as ``sigma-data collect`` does by default. All measured in the same run; prints a Markdown table of ratios and writes it to
``benchmarks/results/collect.md`` (+ ``.json``).

    python -m benchmarks.bench_collect                      # lift, 4 episodes (8 scaling), 4 RGB-D cameras at 128x128
    python -m benchmarks.bench_collect --episodes 20 --workers 2   # the RESULTS.md run (~20 min on 2 cores)
    python -m benchmarks.bench_collect --task=stack --episodes=6 --workers=2 --publish false
"""

from __future__ import annotations

import multiprocessing as mp
import os
import resource
import shutil
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")
import draccus
import numpy as np

import sigma_data  # noqa: F401  (headless GL before robosuite)
from sigma_data.cameras import DEFAULT_CAMERAS, RenderOptions
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
    # Episodes of the two scaling rows (1 worker vs `workers`; 0 = twice `episodes`), in shards of `shard_size`
    # as `sigma-data collect` cuts them by default.
    scaling_episodes: int = 0
    shard_size: int = 10
    # Where the datasets go (default: a temporary directory).
    workdir: Path | None = None
    # Write benchmarks/results/collect.md (+ .json), the fragment RESULTS.md includes.
    publish: bool = True
    # Where the fragment goes (default: benchmarks/results).
    results_dir: Path | None = None


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
    preload()
    import robosuite as suite
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from robosuite.controllers import load_composite_controller_config

    from sigma_data.dataset_layout import DatasetLayout, depth_encoder_config
    from sigma_data.experts.base import ExpertFailure
    from sigma_data.suite import CONTROL_FREQ, CONTROLLER, ROBOT, close_env, get_task, reset_env
    from sigma_data.writers import DenseWriter

    cams = tuple(c for c in cfg.cameras.split(","))
    task = get_task(cfg.task)
    variation = task.variations[0]
    start = time.perf_counter()  # like a sigma run: building the env and creating the dataset count
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
        depth_encoder=depth_encoder_config(),  # the encoder sigma's writers use
        video_backend="pyav",
    )
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
        close_env(env)
    wall = time.perf_counter() - start
    return {"wall": wall, "kept": kept, "steps": steps, "write_s": write_s}


def preload() -> None:
    """Import what both kinds of run use before their clocks start, so neither row pays for imports."""
    import lerobot.datasets.aggregate
    import lerobot.datasets.lerobot_dataset  # noqa: F401
    import robosuite  # noqa: F401

    import sigma_data.experts.base
    import sigma_data.record
    import sigma_data.suite  # noqa: F401


def run_sigma(c: CollectConfig) -> dict:
    """One ``sigma-data collect`` run; the numbers of the table row (plain data, so it crosses processes)."""
    preload()
    s = collect(c)
    return {
        "kept": s.kept,
        "wall": s.wall_s,
        "render_s": sum(r.render_s for r in s.shards),
        "write_s": sum(r.write_s for r in s.shards),
        "frames": sum(r.rendered_frames for r in s.shards),
    }


def _peak_self_mib() -> float:
    """Peak resident memory of this process image (``VmHWM``; ``ru_maxrss`` where /proc is missing), MiB.

    ``ru_maxrss`` of a spawned process also counts its parent's memory at the moment it was started (Linux
    carries the high-water mark over ``exec``); ``VmHWM`` is this process's own.
    """
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _with_peak_memory(fn: Callable[..., dict], *args) -> dict:
    """``fn(*args)`` plus the peak resident memory (MiB) of this process and of its largest child process."""
    out = fn(*args)
    out["peak_mib"] = _peak_self_mib()
    out["peak_child_mib"] = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    return out


def isolated(fn: Callable[..., dict], *args) -> dict:
    """Run ``fn(*args)`` in a fresh (spawned) process, so each row's peak memory is its own."""
    ctx = mp.get_context("spawn")
    with ProcessPoolExecutor(max_workers=1, mp_context=ctx) as pool:
        return pool.submit(_with_peak_memory, fn, *args).result()


def main() -> None:
    cfg = draccus.parse(BenchConfig)
    work = Path(cfg.workdir or tempfile.mkdtemp(prefix="bench_collect_"))
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    base = CollectConfig(
        tasks=cfg.task,
        episodes=cfg.episodes,
        render=RenderOptions(cameras=cfg.cameras, height=cfg.size, width=cfg.size),
        shard_size=cfg.episodes,
        progress=False,
    )
    runs: list[dict] = []  # one per table row, in order

    b = isolated(run_baseline, cfg, work / "baseline")
    base_rate = b["kept"] / b["wall"] * 60
    runs.append(
        {
            "run": "robosuite loop, cameras every step, dense written",
            "episodes": cfg.episodes,
            **b,
            "vs_baseline": 1.0,
        }
    )
    runs[-1]["notes"] = f"writer {b['write_s']:.1f} s of {b['wall']:.1f} s"

    def sigma(name: str, dense: bool = True, keyframe: bool = True, **kw) -> dict:
        c = replace(base, output=replace(base.output, dir=work / name, dense=dense, keyframe=keyframe), **kw)
        r = {"episodes": c.episodes, **isolated(run_sigma, c)}
        r["vs_baseline"] = r["kept"] / r["wall"] * 60 / base_rate
        r["notes"] = (
            f"render {1000 * r['render_s'] / max(r['frames'], 1):.1f} ms/frame, "
            f"write/render {r['write_s'] / max(r['render_s'], 1e-9):.0%}"
        )
        runs.append({"run": name, **r})
        return r

    sigma("sigma keyframe", dense=False)
    sigma("sigma dense", keyframe=False)
    n, size = cfg.scaling_episodes or 2 * cfg.episodes, cfg.shard_size
    scaling = {"dense": False, "episodes": n, "shard_size": size}
    one = sigma(f"sigma keyframe, {n} episodes in shards of {size}, 1 worker", **scaling)
    # Like for like with the workers of the next row, which have one core each and so work in turn.
    one_seq = sigma(
        f"sigma keyframe, {n} episodes in shards of {size}, 1 worker, `--render_threads 1`",
        render_threads=1,
        **scaling,
    )
    many = sigma(
        f"sigma keyframe, {n} episodes in shards of {size}, {cfg.workers} workers",
        workers=cfg.workers,
        **scaling,
    )

    def rate(r: dict) -> float:
        return r["kept"] / r["wall"]

    runs[-1]["notes"] = (  # the row (a copy of `many`)
        f"{rate(many) / rate(one):.2f}x 1 worker, {rate(many) / rate(one_seq):.2f}x 1 worker with 1 render "
        "thread; " + many["notes"]
    )

    lines = [
        f"{cfg.task}, {cfg.episodes} episodes per run (seeds 0-{cfg.episodes - 1}; the scaling rows "
        f"{cfg.scaling_episodes or 2 * cfg.episodes}), cameras {cfg.cameras} at "
        f"{cfg.size}x{cfg.size}; each run in a fresh process.",
        "",
        "| run | episodes kept / tried | wall s | episodes/min | vs baseline | peak RSS MiB (process / largest "
        "child) | notes |",
        "|---|---|---|---|---|---|---|",
        *(
            f"| {r['run']} | {r['kept']} / {r['episodes']} | {r['wall']:.1f} | {r['kept'] / r['wall'] * 60:.2f} | "
            f"{r['vs_baseline']:.2f}x | {r['peak_mib']:.0f} / "
            f"{r['peak_child_mib']:.0f} | {r['notes']} |"
            for r in runs
        ),
    ]
    table = "\n".join(lines)
    print("\n" + table)
    notes = (
        "Ratios are episodes/min against the baseline row of this run. Peak RSS: the run's own process "
        "(`VmHWM`) / its largest child process (`getrusage(RUSAGE_CHILDREN).ru_maxrss`: collection workers and "
        "helper subprocesses; an upper bound, since Linux counts the parent's resident memory at the moment a "
        "child starts)."
    )
    print(f"\n{notes} Data under {work}")
    if cfg.publish:
        from pipelines.reporting import write_report

        write_report(
            "collect",
            "Collection vs robosuite's own camera loop",
            table,
            {
                "task": cfg.task,
                "episodes": cfg.episodes,
                "cameras": cfg.cameras,
                "size": cfg.size,
                "runs": runs,
            },
            notes,
            cfg.results_dir,
        )
    keyframe = runs[1]
    print(
        f"bench_collect: {cfg.episodes} episodes of {cfg.task}: sigma keyframe {keyframe['vs_baseline']:.2f}x, "
        f"dense {runs[2]['vs_baseline']:.2f}x the robosuite camera loop"
    )


if __name__ == "__main__":
    main()
