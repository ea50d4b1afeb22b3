"""This process's robosuite envs and render threads, built once and reused by every shard of a task.

Building a robosuite env compiles its model (~1.5 s), so a process keeps one env per (task, render settings,
model seed) for all its shards. ``reset_env`` makes each episode depend on its seed only, not on what the env ran
before (the resume test compares a reused env with a fresh one). The model (e.g. Lift's random cube size, drawn
when the env is built) is built under ``model_seed``.
"""

from __future__ import annotations

import atexit
import contextlib
from typing import Any

from sigma_data.cameras import CameraRig, RenderConfig
from sigma_data.collect.config import CollectConfig
from sigma_data.replay_render import ReplayRenderer


def build_env(task: Any, render: RenderConfig, model_seed: int) -> Any:
    """``make_env`` with the random model parameters drawn under ``model_seed`` (global RNG restored)."""
    from sigma_data.suite import make_env

    return make_env(
        task, cameras=render.cameras, height=render.height, width=render.width, model_seed=model_seed
    )


# Envs built in this process, by (task, render settings, model seed).
_ENVS: dict[tuple[str, RenderConfig, int], Any] = {}


def cached_env(task_name: str, render: RenderConfig, model_seed: int) -> Any:
    """This process's env for ``task_name`` (built on first use; :func:`close_envs` closes them all)."""
    from sigma_data.suite import get_task

    key = (task_name, render, model_seed)
    if key not in _ENVS:
        if not _ENVS:
            atexit.register(close_envs)  # spawned workers exit through sys.exit: close GL contexts first
        _ENVS[key] = build_env(get_task(task_name), render, model_seed)
    return _ENVS[key]


_REPLAYS: dict[tuple[int, int], ReplayRenderer] = {}


def cached_replay(rig: CameraRig, threads: int) -> ReplayRenderer:
    """This process's render threads for ``rig``'s env (closed by :func:`close_envs`, before the envs)."""
    key = (id(rig.env), threads)
    if key not in _REPLAYS:
        _REPLAYS[key] = ReplayRenderer(rig, threads)
    return _REPLAYS[key]


def close_envs() -> None:
    """Close and forget every env :func:`cached_env` built in this process (and their render threads)."""
    from sigma_data.suite import close_env

    while _REPLAYS:
        _, replay = _REPLAYS.popitem()
        with contextlib.suppress(Exception):
            replay.close()
    while _ENVS:
        _, env = _ENVS.popitem()
        with contextlib.suppress(Exception):
            close_env(env)


def check_cameras_exist(cfg: CollectConfig, task_names: list[str], reuse: bool) -> None:
    """Raise ``ValueError`` naming the first task whose scene lacks a requested camera, before any shard runs
    (or, for worker processes, while they start). With ``reuse`` the envs the shards of this process will use
    are built now (nothing extra); otherwise a throwaway env without a renderer is built per task."""
    from sigma_data.suite import close_env, get_task

    for task_name in task_names:
        if reuse:
            env = cached_env(task_name, cfg.render.config(), cfg.model_seed)
            known = set(env.sim.model.camera_names)
        else:
            env = build_env(get_task(task_name), RenderConfig(cameras=()), cfg.model_seed)  # no renderer
            try:
                known = set(env.sim.model.camera_names)
            finally:
                close_env(env)
        unknown = [c for c in cfg.render.config().cameras if c not in known]
        if unknown:
            raise ValueError(
                f"unknown camera(s) {unknown} for task '{task_name}'; known: {', '.join(sorted(known))}"
            )
