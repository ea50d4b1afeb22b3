"""Render recorded sim states in background threads: an episode's frames render in parallel, ahead of the writer.

Recording stores the flattened sim state of every control step (``[time, qpos, qvel]``), so all the frames of an
episode are known before the first is rendered, and any renderer can render any of them. MuJoCo on a CPU (Mesa
llvmpipe) renders a 128x128 robosuite scene on about one core (most of the cost is the ~170k triangles of the
Panda meshes) and releases the GIL while it does, so two threads render two frames at once, and the writer's
work in the calling thread (LeRobot's ``add_frame``, the video encoders' threads) overlaps both.

:class:`ReplayRenderer` keeps ``threads`` threads; each owns a GL context (``mujoco.GLContext``: the ``MUJOCO_GL``
backend), an ``MjData``, a scene and an ``MjrContext`` on the env's model, with the render options of the env's
offscreen context as :class:`~sigma_data.cameras.CameraRig` set them (fast settings or robosuite's): its images
are bit for bit those of ``CameraRig.render_state`` in the test's frames (a rare frame can differ in a few depth
pixels by a unit or two: ``docs/robosuite.md`` §2). The model is shared read-only; mocap poses are
copied with the model when an episode's frames are queued (:meth:`ReplayRenderer.snapshot`), so the env may reset
for the next episode (which moves Door's frame) while they render.

:class:`RenderedFrames` is what writers read an episode's frames from, with or without a :class:`ReplayRenderer`.
"""

from __future__ import annotations

import contextlib
import copy
import queue
import threading
import time
from collections.abc import Iterable
from concurrent.futures import CancelledError, Future
from dataclasses import dataclass
from typing import Any

import numpy as np

from sigma_data.cameras import CameraRig, camera_frame
from sigma_data.episode import CameraViews, Episode


@dataclass(frozen=True)
class SceneSnapshot:
    """What a frame needs besides its state: the env's model and mocap poses when the episode was recorded (a
    copy: ``reset`` may change them, e.g. Door's frame, while this episode's frames still render)."""

    model: Any
    mocap_pos: np.ndarray
    mocap_quat: np.ndarray


class _ThreadRenderer:
    """One thread's GL context, data, scene and MuJoCo render context (created and freed in that thread)."""

    def __init__(self, model: Any, options: Any, scene_flags: list[int], rig: CameraRig):
        import mujoco

        cfg = rig.config
        self.gl = mujoco.GLContext(cfg.width, cfg.height)
        self.gl.make_current()
        self.model = model
        self.data = mujoco.MjData(model)
        self.scene = mujoco.MjvScene(model, maxgeom=10_000)  # as robosuite's context
        for i, flag in enumerate(scene_flags):
            self.scene.flags[i] = flag
        self.options = options
        self.camera = mujoco.MjvCamera()
        self.camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self.perturb = mujoco.MjvPerturb()
        self.context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self.context)
        self.viewport = mujoco.MjrRect(0, 0, cfg.width, cfg.height)
        self.cameras = [(cam, model.camera(cam).id) for cam in cfg.cameras]
        self.size = (cfg.height, cfg.width)
        self.max_depth = cfg.max_depth

    def render(self, snapshot: SceneSnapshot, state: np.ndarray) -> CameraViews:
        import mujoco

        m, d = snapshot.model, self.data
        d.time = state[0]
        d.qpos[:] = state[1 : 1 + m.nq]
        d.qvel[:] = state[1 + m.nq : 1 + m.nq + m.nv]
        d.mocap_pos[:] = snapshot.mocap_pos
        d.mocap_quat[:] = snapshot.mocap_quat
        mujoco.mj_forward(m, d)
        views: CameraViews = {}
        for name, cam_id in self.cameras:
            self.camera.fixedcamid = cam_id
            mujoco.mjv_updateScene(
                m, d, self.options, self.perturb, self.camera, mujoco.mjtCatBit.mjCAT_ALL, self.scene
            )
            mujoco.mjr_render(self.viewport, self.scene, self.context)
            rgb = np.empty((*self.size, 3), dtype=np.uint8)
            zbuf = np.empty(self.size, dtype=np.float32)
            mujoco.mjr_readPixels(rgb, zbuf, self.viewport, self.context)
            views[name] = camera_frame(m, d, cam_id, rgb, zbuf, self.max_depth)
        return views

    def close(self) -> None:
        self.context.free()
        self.gl.free()


class ReplayRenderer:
    """Renders flattened sim states of ``rig``'s env in ``threads`` background threads.

    :meth:`submit` returns a future of ``(views, seconds)``: the frame's camera views and how long its thread
    spent rendering it. Use as a context manager or call :meth:`close` (frees the threads' GL contexts).
    """

    def __init__(self, rig: CameraRig, threads: int = 2):
        if threads < 1:
            raise ValueError(f"threads must be >= 1, got {threads}")
        # The fast settings are on the model before the threads' contexts exist.
        context = rig._ensure_context()
        self.sim = rig.env.sim
        self.model = self.sim.model._model
        self.threads = threads
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        started: queue.SimpleQueue = queue.SimpleQueue()
        # One copy of the options for every thread (mjv_updateScene only reads them).
        settings = (copy.copy(context.vopt), [int(f) for f in context.scn.flags], rig)
        self._workers = [
            threading.Thread(
                target=self._serve, args=(settings, started), name=f"sigma-render-{i}", daemon=True
            )
            for i in range(threads)
        ]
        for worker in self._workers:
            worker.start()
        errors = [e for e in (started.get() for _ in self._workers) if e is not None]
        if errors:
            self.close()
            raise RuntimeError(f"could not create a render thread's GL context: {errors[0]}") from errors[0]

    def _serve(self, settings: tuple[Any, list[int], CameraRig], started: queue.SimpleQueue) -> None:
        options, flags, rig = settings
        try:
            renderer = _ThreadRenderer(self.model, options, flags, rig)
        except BaseException as exc:  # reported by __init__
            started.put(exc)
            return
        started.put(None)
        try:
            while (job := self._queue.get()) is not None:
                future, snapshot, state = job
                if not future.set_running_or_notify_cancel():
                    continue
                try:
                    start = time.perf_counter()
                    views = renderer.render(snapshot, state)
                    future.set_result((views, time.perf_counter() - start))
                except BaseException as exc:
                    future.set_exception(exc)
        finally:
            renderer.close()

    def snapshot(self) -> SceneSnapshot:
        """The env's model and mocap poses now, copied (call it before the env moves on to another episode)."""
        if self.sim.model._model is not self.model:
            raise RuntimeError("the env's model was rebuilt (hard reset): make a new ReplayRenderer")
        data = self.sim.data._data
        return SceneSnapshot(copy.copy(self.model), data.mocap_pos.copy(), data.mocap_quat.copy())

    def submit(self, snapshot: SceneSnapshot, state: np.ndarray) -> Future:
        """Queue one flattened state ``[time, qpos, qvel]`` of ``snapshot``'s model (copied)."""
        m = snapshot.model
        state = np.array(state, dtype=np.float64)
        if state.shape != (1 + m.nq + m.nv,):
            raise ValueError(f"sim state has shape {state.shape}, this model needs ({1 + m.nq + m.nv},)")
        future: Future = Future()
        self._queue.put((future, snapshot, state))
        return future

    def close(self) -> None:
        """Stop the threads after the frames already queued; idempotent."""
        for worker in self._workers:
            if worker.is_alive():
                self._queue.put(None)
        for worker in self._workers:
            worker.join()
        self._workers = []

    def __enter__(self) -> ReplayRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class RenderedFrames:
    """An episode's frames for the writers: ``frames(t)`` is the camera views of frame ``t``, by state replay.

    With a :class:`ReplayRenderer`, the frames of ``order`` (those the writers will ask for, in the order they ask)
    render ahead in its threads, at most ``ahead`` frames past the last one asked for; a frame asked for out of
    that order renders at once. The episode's ``snapshot`` is taken now unless given (a snapshot taken right after
    the episode was recorded lets the env move on). Without a renderer, each frame renders in this thread when asked for. Frames in ``keep``
    stay after their first use (a frame both datasets store renders once). ``seconds`` is the time spent
    rendering (summed over threads), ``waited`` the time this thread waited for frames; call :meth:`close` (or use
    ``with``) before the env changes: it cancels what was not asked for and waits for what is rendering.
    """

    def __init__(
        self,
        episode: Episode,
        rig: CameraRig,
        keep: Iterable[int] = (),
        order: Iterable[int] = (),
        replay: ReplayRenderer | None = None,
        ahead: int | None = None,
        snapshot: SceneSnapshot | None = None,
    ):
        if episode.sim_states is None:
            raise ValueError(f"{episode.name}: no sim states to render")
        self.episode, self.rig, self.replay = episode, rig, replay
        self.snapshot = snapshot or (replay.snapshot() if replay is not None else None)
        self.keep = set(keep)
        self.cache: dict[int, CameraViews] = {}
        self.pending: dict[int, Future] = {}
        self.order = list(dict.fromkeys(order)) if replay is not None else []
        self.ahead = ahead if ahead is not None else 2 * (replay.threads if replay else 1) + 2
        self._next = 0  # position in ``order`` of the next frame to submit
        self.seconds = 0.0
        self.waited = 0.0
        self.count = 0
        self._top_up()

    def _submit(self, t: int) -> Future:
        if not 0 <= t < len(self.episode):
            raise IndexError(f"{self.episode.name}: frame {t} out of range (episode has {len(self.episode)})")
        return self.replay.submit(self.snapshot, self.episode.sim_states[t])

    def _top_up(self) -> None:
        while self._next < len(self.order) and len(self.pending) < self.ahead:
            t = self.order[self._next]
            self._next += 1
            if t not in self.pending and t not in self.cache:
                self.pending[t] = self._submit(t)

    def __call__(self, t: int) -> CameraViews:
        if t in self.cache:
            return self.cache[t]
        start = time.perf_counter()
        if self.replay is None:
            views = self.rig.render_state(self.episode.sim_states[t])
            self.seconds += time.perf_counter() - start
        else:
            future = self.pending.pop(t, None) or self._submit(t)
            try:
                views, seconds = future.result()
            except Exception as exc:
                raise RuntimeError(f"{self.episode.name}: rendering frame {t} failed: {exc}") from exc
            self.seconds += seconds
            self._top_up()
        self.waited += time.perf_counter() - start
        self.count += 1
        if t in self.keep:
            self.cache[t] = views
        return views

    def close(self) -> None:
        """Cancel frames not asked for; wait for those already rendering (the env may change afterwards)."""
        for future in self.pending.values():
            future.cancel()
        for future in self.pending.values():
            with contextlib.suppress(CancelledError):
                future.exception()
        self.pending.clear()
        self._next = len(self.order)

    def __enter__(self) -> RenderedFrames:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
