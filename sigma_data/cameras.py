"""Fast, exact RGB-D rendering of robosuite cameras from ``env.sim``, with calibration at the same state.

:class:`CameraRig` renders named cameras of a robosuite env after ``sim.forward()`` with the "fast" settings of
docs/robosuite.md §2: MSAA off (``offsamples = 0``, which also makes depth exact at silhouettes), reflections
and skybox off, offscreen buffer = image size (about 3x faster than robosuite's defaults). Every frame returns,
per camera, a :class:`~sigma_data.episode.CameraFrame`:

* ``rgb`` (H, W, 3) uint8 **upright** (MuJoCo renders bottom-up; rows are flipped);
* ``depth`` (H, W) float32 **metres**, z-depth along the optical axis (the OpenGL z-buffer converted with the
  model's near/far planes), clipped to ``max_depth`` (background pixels hit the far plane, hundreds of metres);
* ``intrinsics`` K (3, 3): ``f = 0.5 H / tan(fovy / 2)``, ``c = (W / 2, H / 2)``; pixel (row v, col u) has its
  centre at ``(u + 0.5, v + 0.5)``;
* ``extrinsics`` (4, 4) camera-to-world in OpenCV axes (x right, y down, z forward).

:func:`backproject` and :func:`fused_cloud` turn them into world-frame points. :class:`RenderOptions` are the
``--render.*`` options of every command that renders (``sigma-data collect``, ``import hdf5``, ``import teleop``);
:func:`parse_cameras` reads a comma-separated camera list and :meth:`RenderOptions.config` gives the renderers'
:class:`RenderConfig`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from sigma_data.episode import CameraFrame, CameraViews

DEFAULT_CAMERAS: tuple[str, ...] = ("agentview", "frontview", "birdview", "robot0_eye_in_hand")
# MuJoCo camera axes (x right, y up, looking along -z) -> OpenCV axes (x right, y down, z forward).
_MUJOCO_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])


@dataclass(frozen=True)
class RenderConfig:
    """Which cameras to render and how. Sizes in pixels, depth in metres."""

    cameras: tuple[str, ...] = DEFAULT_CAMERAS
    height: int = 128
    width: int = 128
    # The fast settings (MSAA, reflections and skybox off; buffer = image size). False keeps robosuite's.
    fast: bool = True
    # Depth beyond this (background, far plane) is clipped to it, metres.
    max_depth: float = 3.0


def parse_cameras(text: str, flag: str = "--render.cameras") -> tuple[str, ...]:
    """``"a,b"`` -> ``("a", "b")``; ``ValueError`` naming ``flag`` if empty or duplicated."""
    cams = tuple(c.strip() for c in text.split(",") if c.strip())
    if not cams:
        raise ValueError(f"no cameras given ({flag})")
    if len(set(cams)) != len(cams):
        raise ValueError(f"duplicate camera names in {flag}={text}")
    return cams


@dataclass
class RenderOptions:
    """Which cameras to render and how (``--render.*`` of ``sigma-data collect`` and the importers that render)."""

    # Cameras, comma-separated.
    cameras: str = ",".join(DEFAULT_CAMERAS)
    # Image height in pixels (every camera).
    height: int = 128
    # Image width in pixels (every camera).
    width: int = 128
    # Render with the fast settings (MSAA/reflections/skybox off: exact depth, ~3x faster).
    fast: bool = True
    # Depth is clipped to this many metres (background pixels hit the far plane, hundreds of metres away).
    max_depth: float = 3.0

    def config(self) -> RenderConfig:
        """The renderers' :class:`RenderConfig` (``ValueError`` if ``cameras`` is empty or repeats a name)."""
        return RenderConfig(parse_cameras(self.cameras), self.height, self.width, self.fast, self.max_depth)


def camera_intrinsics(model: Any, cam_id: int, height: int, width: int) -> np.ndarray:
    """Pinhole K (3, 3) float64 of MuJoCo camera ``cam_id`` for an ``height`` x ``width`` image (robosuite's)."""
    fovy = np.deg2rad(float(model.cam_fovy[cam_id]))
    f = 0.5 * height / np.tan(fovy / 2)
    return np.array([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]])


def camera_extrinsics(data: Any, cam_id: int) -> np.ndarray:
    """Camera-to-world (4, 4) float64 in OpenCV axes at ``data`` (after ``mj_forward``)."""
    pose = np.eye(4)
    pose[:3, :3] = np.asarray(data.cam_xmat[cam_id]).reshape(3, 3)
    pose[:3, 3] = data.cam_xpos[cam_id]
    return pose @ _MUJOCO_TO_OPENCV


def zbuffer_to_metres(model: Any, zbuffer: np.ndarray) -> np.ndarray:
    """OpenGL z-buffer values in [0, 1] -> metric z-depth, metres (robosuite's ``get_real_depth_map``)."""
    extent = model.stat.extent
    near = model.vis.map.znear * extent
    far = model.vis.map.zfar * extent
    return near / (1.0 - zbuffer * (1.0 - near / far))


def camera_frame(
    model: Any, data: Any, cam_id: int, rgb: np.ndarray, zbuffer: np.ndarray, max_depth: float
) -> CameraFrame:
    """A :class:`CameraFrame` from MuJoCo's bottom-up ``rgb`` (H, W, 3) and ``zbuffer`` (H, W) of camera
    ``cam_id``, with calibration at ``data``."""
    h, w = zbuffer.shape
    depth = zbuffer_to_metres(model, zbuffer[::-1].astype(np.float64))
    return CameraFrame(
        rgb=np.ascontiguousarray(rgb[::-1]),
        depth=np.minimum(depth, max_depth).astype(np.float32),
        intrinsics=camera_intrinsics(model, cam_id, h, w).astype(np.float32),
        extrinsics=camera_extrinsics(data, cam_id).astype(np.float32),
    )


def backproject(depth: np.ndarray, intrinsics: np.ndarray, extrinsics: np.ndarray) -> np.ndarray:
    """World points (H, W, 3) float64 of an upright metric depth image (H, W) with K and camera-to-world E.

    Pixel (v, u) is at ``((u + 0.5 - cx) z / fx, (v + 0.5 - cy) z / fy, z)`` in the camera frame.
    """
    depth = np.asarray(depth, dtype=np.float64).reshape(depth.shape[0], depth.shape[1])
    h, w = depth.shape
    v, u = np.meshgrid(np.arange(h) + 0.5, np.arange(w) + 0.5, indexing="ij")
    K = np.asarray(intrinsics, dtype=np.float64)
    x = (u - K[0, 2]) * depth / K[0, 0]
    y = (v - K[1, 2]) * depth / K[1, 1]
    cam = np.stack([x, y, depth], axis=-1)
    E = np.asarray(extrinsics, dtype=np.float64)
    return cam @ E[:3, :3].T + E[:3, 3]


def fused_cloud(views: CameraViews, max_depth: float | None = None) -> np.ndarray:
    """(N, 3) world points of all cameras concatenated; pixels at or beyond ``max_depth`` are dropped."""
    clouds = []
    for frame in views.values():
        pts = backproject(frame.depth, frame.intrinsics, frame.extrinsics).reshape(-1, 3)
        if max_depth is not None:
            pts = pts[frame.depth.reshape(-1) < max_depth]
        clouds.append(pts)
    return np.concatenate(clouds, axis=0)


class CameraRig:
    """Renders ``config.cameras`` of a robosuite env (made with ``has_offscreen_renderer=True``).

    The fast settings are applied to the env's offscreen context once, at construction; they survive
    ``env.reset()`` only with ``hard_reset=False`` (robosuite rebuilds the context otherwise; :meth:`render`
    re-applies them if it notices a new context).
    """

    def __init__(self, env: Any, config: RenderConfig = RenderConfig()):
        if config.height <= 0 or config.width <= 0:
            raise ValueError(f"image size must be positive, got {config.height}x{config.width}")
        if not config.cameras:
            raise ValueError("no cameras to render")
        if len(set(config.cameras)) != len(config.cameras):
            raise ValueError(f"duplicate camera names in {list(config.cameras)}")
        check_cameras(env, config.cameras)
        self.env = env
        self.config = config
        self._context = None
        self._ensure_context()

    @property
    def cameras(self) -> tuple[str, ...]:
        return self.config.cameras

    def _ensure_context(self) -> Any:
        sim = self.env.sim
        ctx = sim._render_context_offscreen
        if ctx is None:
            raise ValueError("the env has no offscreen renderer: create it with has_offscreen_renderer=True")
        if ctx is not self._context:
            if self.config.fast:
                self._apply_fast_settings(ctx)
            self._context = ctx
        return ctx

    def _apply_fast_settings(self, ctx: Any) -> None:
        import mujoco

        model = self.env.sim.model._model
        model.vis.quality.offsamples = 0
        model.vis.global_.offwidth = self.config.width
        model.vis.global_.offheight = self.config.height
        ctx.con.free()
        ctx._set_mujoco_context_and_buffers()
        ctx.scn.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0
        ctx.scn.flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = 0

    def render(self) -> CameraViews:
        """Render every camera at the current ``sim.data`` (``forward()`` is called first)."""
        sim = self.env.sim
        # Current in this thread: robosuite renders into whatever context is current, and closing another env
        # releases it (eglReleaseThread).
        self._ensure_context().gl_ctx.make_current()
        sim.forward()
        h, w = self.config.height, self.config.width
        model, data = sim.model._model, sim.data._data
        views: CameraViews = {}
        for cam in self.config.cameras:
            rgb, zbuf = sim.render(camera_name=cam, width=w, height=h, depth=True)
            cam_id = sim.model.camera_name2id(cam)
            views[cam] = camera_frame(model, data, cam_id, rgb, zbuf, self.config.max_depth)
        return views

    def render_state(self, flat_state: np.ndarray) -> CameraViews:
        """Restore a flattened MuJoCo state ``[time, qpos, qvel]`` and render it."""
        self.env.sim.set_state_from_flattened(np.asarray(flat_state, dtype=np.float64))
        return self.render()

    def static_calibration(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """K and E of the cameras not attached to a moving body (fixed in the world), by camera name."""
        sim = self.env.sim
        out = {}
        for cam in self.config.cameras:
            cam_id = sim.model.camera_name2id(cam)
            if is_static_body(sim.model, sim.model.cam_bodyid[cam_id]):
                out[cam] = (
                    camera_intrinsics(sim.model, cam_id, self.config.height, self.config.width),
                    camera_extrinsics(sim.data, cam_id),
                )
        return out


def is_static_body(model: Any, body_id: int) -> bool:
    """True if no joint moves ``body_id`` (it and all its ancestors have no degrees of freedom)."""
    while body_id > 0:
        if model.body_jntnum[body_id] > 0 or model.body_dofnum[body_id] > 0:
            return False
        body_id = model.body_parentid[body_id]
    return True


def check_cameras(env: Any, cameras: Sequence[str]) -> None:
    """Raise ``ValueError`` naming unknown cameras of ``env``."""
    known = set(env.sim.model.camera_names)
    unknown = [c for c in cameras if c not in known]
    if unknown:
        raise ValueError(f"unknown camera(s) {unknown}; this scene has: {', '.join(sorted(known))}")
