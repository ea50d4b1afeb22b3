"""A gymnasium environment over one sigma task, in keyframe or dense control, for closed-loop evaluation.

``SigmaRobosuiteEnv`` wraps one registered task (``sigma_data.suite``) in one of two control modes:

* ``control="keyframe"`` (sigma's policy): each ``step(action)`` hands the 9-D keyframe ``[x, y, z, qx, qy, qz,
  qw, gripper_open, ignore_collision]`` (world frame, grip site, the keyframe dataset's action) to the
  :class:`~sigma_data.keyframe_executor.KeyframeExecutor`, which drives the arm there and then actuates the gripper;
* ``control="dense"`` (stock LeRobot policies trained on the dense dataset): each ``step(action)`` is one
  robosuite control step (20 Hz) of the dense dataset's 7-D OSC_POSE delta ``[dx, dy, dz, rx, ry, rz, grip]``
  (grip +1 closes), exactly what the scripted experts executed when the data was recorded.

Either way it returns the observation named and shaped like the datasets, rendered from ``env.sim`` after
``forward()`` exactly like the training data (:class:`~sigma_data.cameras.CameraRig`):

* ``pixels``: ``{camera: (H, W, 3) uint8}`` upright RGB (LeRobot maps it to ``observation.images.<cam>``);
* ``images.<cam>_depth`` (unless ``depth=False``): ``(1, H, W)`` float32 depth in ``depth_unit``
  (-> ``observation.images.<cam>_depth``): millimetres by default, the unit stock ``LeRobotDataset`` returns by
  default (``depth_output_unit="mm"``), so a policy trained by plain ``lerobot-train`` sees the same numbers in
  evaluation; ``"m"`` for metres;
* ``camera.<cam>.intrinsics`` (3, 3) and ``camera.<cam>.extrinsics`` (4, 4, camera-to-world, OpenCV axes);
* ``agent_pos``: the 10-D ``observation.state`` of the data contract (its quaternion continuous over the
  episode like the datasets', ``sigma_data.episode.continuous_quats``).

``task_description`` is the variation's instruction; ``info["is_success"]`` is the task's own success check (the
instruction decides what success means), and the episode terminates on success. Which variation an episode
uses: the one named at construction, else ``variations[seed % n]`` (deterministic round-robin over seeds).
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np

from sigma_data.cameras import DEFAULT_CAMERAS, CameraRig, RenderConfig
from sigma_data.contract import ACTION_NAMES
from sigma_data.control import EnvDriver
from sigma_data.keyframe_executor import ExecutorConfig, KeyframeExecutor
from sigma_data.record import robot_state
from sigma_data.suite import TaskSpec, close_env, get_task, get_variation, make_env, reset_env

GYM_ID = "sigma/Robosuite-v0"
DEPTH_SCALE = {"m": 1.0, "mm": 1000.0}  # rendered metres -> the unit handed to the policy


def parse_task(spec: str) -> tuple[TaskSpec, str | None]:
    """``"stack"`` (all variations) or ``"stack:green_on_red"`` -> (task, variation name or None)."""
    name, _, variation = spec.partition(":")
    task = get_task(name)
    if variation:
        get_variation(task, variation)  # raises with the known names
    return task, variation or None


class SigmaRobosuiteEnv(gym.Env):
    """One keyframe (or one control step) per ``step``; see the module docstring for the conventions."""

    metadata: ClassVar[dict] = {"render_modes": ["rgb_array"], "render_fps": 2}

    def __init__(
        self,
        task: str = "lift",
        cameras: Sequence[str] = DEFAULT_CAMERAS,
        image_size: int = 128,
        executor: ExecutorConfig | None = None,
        render_mode: str | None = "rgb_array",
        render_camera: str | None = None,
        depth_unit: str = "mm",
        control: str = "keyframe",
        depth: bool = True,
    ):
        super().__init__()
        if depth_unit not in DEPTH_SCALE:
            raise ValueError(f"depth_unit must be one of {sorted(DEPTH_SCALE)}, got {depth_unit!r}")
        if control not in ACTION_NAMES:
            raise ValueError(f"control must be one of {sorted(ACTION_NAMES)}, got {control!r}")
        self.control = control
        self.action_names = ACTION_NAMES[control]
        self.depth = bool(depth)
        self.depth_scale = DEPTH_SCALE[depth_unit]
        self.task, self.fixed_variation = parse_task(task)
        self.cameras = tuple(cameras)
        self.render_mode = render_mode
        self.render_camera = render_camera or self.cameras[0]
        if self.render_camera not in self.cameras:
            raise ValueError(f"render_camera '{self.render_camera}' is not among the cameras {self.cameras}")
        self.env = make_env(self.task, cameras=self.cameras, height=image_size, width=image_size)
        self.rig = CameraRig(
            self.env, RenderConfig(cameras=self.cameras, height=image_size, width=image_size)
        )
        self.executor_config = executor or ExecutorConfig()
        self.variation = get_variation(self.task, self.fixed_variation or self.task.variation_names[0])
        self._executor: KeyframeExecutor | None = None
        self._gripper_open = True  # dense control: the last grip command (+1 closes), as the recorder's state
        self._last_quat: np.ndarray | None = None
        self._last_rgb: np.ndarray | None = None

        h = w = image_size
        box = gym.spaces.Box
        spaces: dict[str, gym.Space] = {
            "pixels": gym.spaces.Dict({c: box(0, 255, (h, w, 3), np.uint8) for c in self.cameras}),
            "agent_pos": box(-np.inf, np.inf, (10,), np.float32),
        }
        for cam in self.cameras:
            if self.depth:
                spaces[f"images.{cam}_depth"] = box(0.0, np.inf, (1, h, w), np.float32)
            spaces[f"camera.{cam}.intrinsics"] = box(-np.inf, np.inf, (3, 3), np.float32)
            spaces[f"camera.{cam}.extrinsics"] = box(-np.inf, np.inf, (4, 4), np.float32)
        self.observation_space = gym.spaces.Dict(spaces)
        low = -1.0 if control == "dense" else -np.inf  # OSC_POSE deltas are clipped to [-1, 1] by robosuite
        self.action_space = box(low, -low, (len(self.action_names),), np.float32)

    @property
    def task_description(self) -> str:
        return self.variation.instruction

    def _observation(self) -> dict[str, Any]:
        views = self.rig.render()
        gripper_open = self._executor.gripper_open if self._executor else self._gripper_open
        state = robot_state(self.env, gripper_open)
        if self._last_quat is not None and np.dot(state[3:7], self._last_quat) < 0:
            state[3:7] *= -1  # keep the previous step's hemisphere, like the datasets (continuous_quats)
        self._last_quat = state[3:7].astype(np.float64)
        obs: dict[str, Any] = {"pixels": {cam: v.rgb for cam, v in views.items()}, "agent_pos": state}
        for cam, v in views.items():
            if self.depth:
                obs[f"images.{cam}_depth"] = v.depth[None] * np.float32(self.depth_scale)
            obs[f"camera.{cam}.intrinsics"] = v.intrinsics
            obs[f"camera.{cam}.extrinsics"] = v.extrinsics
        self._last_rgb = views[self.render_camera].rgb
        return obs

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is None:
            seed = int(self.np_random.integers(0, 2**31 - 1))
        name = self.fixed_variation or self.task.variation_names[seed % len(self.task.variations)]
        self.variation = get_variation(self.task, name)
        reset_env(self.env, self.task, self.variation, seed)
        self._gripper_open, self._last_quat = True, None
        self._executor = (
            KeyframeExecutor(EnvDriver(self.env), self.executor_config, gripper_open=True)
            if self.control == "keyframe"
            else None
        )
        info = {"task": self.task.name, "variation": name, "seed": seed, "is_success": False}
        return self._observation(), info

    def step(self, action: np.ndarray):
        if self._last_quat is None:
            raise RuntimeError("call reset() before step()")
        action = np.asarray(action, dtype=np.float64).reshape(-1)
        if action.shape != (len(self.action_names),) or not np.isfinite(action).all():
            raise ValueError(
                f"{self.control} control: action must be {len(self.action_names)} finite values "
                f"{self.action_names}, got {action!r}"
            )
        info: dict[str, Any] = {"variation": self.variation.name}
        if self._executor is not None:
            result = self._executor.execute(action)
            info |= {"control_steps": result.steps, "arm_status": result.arm.status.value}
        else:
            self.env.step(action)
            self._gripper_open = bool(action[-1] < 0)
            info["control_steps"] = 1
        success = bool(self.task.success(self.env, self.variation))
        info["is_success"] = success
        return self._observation(), float(success), success, False, info

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        return self._last_rgb

    def close(self) -> None:
        if self.env is not None:
            close_env(self.env)
            self.env = None

    def __del__(self) -> None:
        # Dropped without close(): robosuite would free the render context in another env's GL context.
        with contextlib.suppress(Exception):
            self.close()


def register_gym_env() -> None:
    """Register :data:`GYM_ID` with gymnasium (idempotent)."""
    if GYM_ID not in gym.registry:
        gym.register(id=GYM_ID, entry_point=f"{__name__}:SigmaRobosuiteEnv", max_episode_steps=10)


register_gym_env()
