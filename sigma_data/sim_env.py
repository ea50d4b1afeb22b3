"""A gymnasium environment that takes one 9-D keyframe action per step, for closed-loop evaluation.

``SigmaRobosuiteEnv`` wraps one registered task (``sigma_data.tasks``). Each ``step(action)`` hands the keyframe
``[x, y, z, qx, qy, qz, qw, gripper_open, ignore_collision]`` (world frame, grip site) to the
:class:`~sigma_data.control.KeyframeExecutor`, which drives the arm there and then actuates the gripper, and
returns the observation the policy needs, rendered from ``env.sim`` after ``forward()`` exactly like the training
data (:class:`~sigma_data.cameras.CameraRig`):

* ``pixels``: ``{camera: (H, W, 3) uint8}`` upright RGB (LeRobot maps it to ``observation.images.<cam>``);
* ``images.<cam>_depth``: ``(1, H, W)`` float32 depth in ``depth_unit`` (-> ``observation.images.<cam>_depth``):
  millimetres by default, the unit stock ``LeRobotDataset`` returns by default (``depth_output_unit="mm"``), so a
  policy trained by plain ``lerobot-train`` sees the same numbers in evaluation; ``"m"`` for metres;
* ``camera.<cam>.intrinsics`` (3, 3) and ``camera.<cam>.extrinsics`` (4, 4, camera-to-world, OpenCV axes);
* ``agent_pos``: the 10-D ``observation.state`` of the data contract.

``task_description`` is the variation's instruction; ``info["is_success"]`` is the task's own success check (the
instruction decides what success means), and the episode terminates on success. Which variation an episode
uses: the one named at construction, else ``variations[seed % n]`` (deterministic round-robin over seeds).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np

from sigma_data.cameras import DEFAULT_CAMERAS, CameraRig, RenderConfig
from sigma_data.control import EnvDriver, ExecutorConfig, KeyframeExecutor
from sigma_data.record import robot_state
from sigma_data.tasks.registry import TaskSpec, get_task, get_variation, make_env, reset_env

GYM_ID = "sigma/Robosuite-v0"
DEPTH_SCALE = {"m": 1.0, "mm": 1000.0}  # rendered metres -> the unit handed to the policy
ACTION_NAMES = ("x", "y", "z", "qx", "qy", "qz", "qw", "gripper_open", "ignore_collision")


def parse_task(spec: str) -> tuple[TaskSpec, str | None]:
    """``"stack"`` (all variations) or ``"stack:green_on_red"`` -> (task, variation name or None)."""
    name, _, variation = spec.partition(":")
    task = get_task(name)
    if variation:
        get_variation(task, variation)  # raises with the known names
    return task, variation or None


class SigmaRobosuiteEnv(gym.Env):
    """One keyframe per ``step``; see the module docstring for the observation and episode conventions."""

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
    ):
        super().__init__()
        if depth_unit not in DEPTH_SCALE:
            raise ValueError(f"depth_unit must be one of {sorted(DEPTH_SCALE)}, got {depth_unit!r}")
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
        self._last_rgb: np.ndarray | None = None

        h = w = image_size
        box = gym.spaces.Box
        spaces: dict[str, gym.Space] = {
            "pixels": gym.spaces.Dict({c: box(0, 255, (h, w, 3), np.uint8) for c in self.cameras}),
            "agent_pos": box(-np.inf, np.inf, (10,), np.float32),
        }
        for cam in self.cameras:
            spaces[f"images.{cam}_depth"] = box(0.0, np.inf, (1, h, w), np.float32)
            spaces[f"camera.{cam}.intrinsics"] = box(-np.inf, np.inf, (3, 3), np.float32)
            spaces[f"camera.{cam}.extrinsics"] = box(-np.inf, np.inf, (4, 4), np.float32)
        self.observation_space = gym.spaces.Dict(spaces)
        self.action_space = box(-np.inf, np.inf, (len(ACTION_NAMES),), np.float32)

    @property
    def task_description(self) -> str:
        return self.variation.instruction

    def _observation(self) -> dict[str, Any]:
        views = self.rig.render()
        obs: dict[str, Any] = {
            "pixels": {cam: v.rgb for cam, v in views.items()},
            "agent_pos": robot_state(self.env, self._executor.gripper_open if self._executor else True),
        }
        for cam, v in views.items():
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
        self._executor = KeyframeExecutor(EnvDriver(self.env), self.executor_config, gripper_open=True)
        info = {"task": self.task.name, "variation": name, "seed": seed, "is_success": False}
        return self._observation(), info

    def step(self, action: np.ndarray):
        if self._executor is None:
            raise RuntimeError("call reset() before step()")
        action = np.asarray(action, dtype=np.float64).reshape(-1)
        if action.shape != (len(ACTION_NAMES),) or not np.isfinite(action).all():
            raise ValueError(f"action must be 9 finite values {ACTION_NAMES}, got {action!r}")
        result = self._executor.execute(action)
        success = bool(self.task.success(self.env, self.variation))
        info = {
            "is_success": success,
            "control_steps": result.steps,
            "arm_status": result.arm.status.value,
            "variation": self.variation.name,
        }
        return self._observation(), float(success), success, False, info

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        return self._last_rgb

    def close(self) -> None:
        self.env.close()


def register_gym_env() -> None:
    """Register :data:`GYM_ID` with gymnasium (idempotent)."""
    if GYM_ID not in gym.registry:
        gym.register(id=GYM_ID, entry_point=f"{__name__}:SigmaRobosuiteEnv", max_episode_steps=10)


register_gym_env()
