"""The keyframe executor: drives the robot to 9-D keyframes with RLBench ``MoveArmThenGripper`` semantics.

A keyframe is ``[x, y, z, qx, qy, qz, qw, gripper_open, ignore_collision]``: the grip site's world pose (metres,
xyzw quaternion; ``sigma_data/poses.py``) and two flags. The executor is what keyframe replay, closed-loop
evaluation (``sigma-eval``, ``lerobot-eval``'s ``sigma_robosuite`` env) and the tolerance benchmark run; it is
built from the motion primitives of ``sigma_data/control.py`` (docs/robosuite.md §4.3).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from sigma_data.control import (
    GRIP_CLOSE,
    GRIP_OPEN,
    Driver,
    GripperConfig,
    MoveResult,
    ServoConfig,
    actuate_gripper,
    move_to,
)
from sigma_data.episode import canonical_quat
from sigma_data.poses import grip_site_frame, mat_to_quat

__all__ = ["ExecutorConfig", "KeyframeExecutor", "KeyframeResult"]


@dataclass(frozen=True)
class ExecutorConfig:
    """:class:`KeyframeExecutor` parameters (docs/robosuite.md §4.3)."""

    servo: ServoConfig = field(default_factory=lambda: ServoConfig(pos_tol=0.005, rot_tol=0.05))
    gripper: GripperConfig = field(default_factory=GripperConfig)
    arm_budget: int = 60  # control steps per keyframe for the arm motion (3 s at 20 Hz)
    use_via_point: bool = False  # when ignore_collision == 0, go via a safe height first
    via_height: float = 0.05  # metres above the higher of start and target
    via_min_height_change: float = 0.03  # only use a via point if the height changes by more than this


@dataclass(frozen=True)
class KeyframeResult:
    """What one :meth:`KeyframeExecutor.execute` call did."""

    arm: MoveResult
    gripper_steps: int
    steps: int


class KeyframeExecutor:
    """Drive the robot to 9-D keyframes ``[x, y, z, qx, qy, qz, qw, gripper_open, ignore_collision]``.

    RLBench ``MoveArmThenGripper`` semantics: the arm moves to the pose with the current gripper command
    held (:func:`move_to`, budget ``arm_budget`` steps), then, if ``gripper_open`` differs from the current
    gripper state, the gripper actuates (:func:`actuate_gripper`). With ``use_via_point`` and
    ``ignore_collision == 0``, a height change goes via a point ``via_height`` above the higher end (a crude
    stand-in for a collision-free planner).

    The executor tracks the gripper state it commanded; it starts open (``reset_env`` opens it fully).
    """

    def __init__(self, driver: Driver, config: ExecutorConfig = ExecutorConfig(), gripper_open: bool = True):
        self.driver = driver
        self.config = config
        self.gripper_open = gripper_open

    def execute(self, keyframe: Sequence[float]) -> KeyframeResult:
        kf = np.asarray(keyframe, dtype=np.float64)
        if kf.shape != (9,) or not np.all(np.isfinite(kf)):
            raise ValueError(f"keyframe must be 9 finite values [xyz, qxyzw, open, ignore_coll], got {kf!r}")
        pos, quat = kf[:3], canonical_quat(kf[3:7])
        want_open = bool(kf[7] > 0.5)
        ignore_collision = bool(kf[8] > 0.5)
        grip = GRIP_OPEN if self.gripper_open else GRIP_CLOSE

        steps = 0
        cfg = self.config
        if cfg.use_via_point and not ignore_collision:
            cur_pos, cur_rot = grip_site_frame(self.driver.env)
            if abs(pos[2] - cur_pos[2]) > cfg.via_min_height_change:
                via_z = max(pos[2], cur_pos[2]) + cfg.via_height
                up = move_to(
                    self.driver,
                    [*cur_pos[:2], via_z],
                    mat_to_quat(cur_rot),
                    grip,
                    cfg.servo,
                    max_steps=cfg.arm_budget // 2,
                )
                over = move_to(
                    self.driver, [*pos[:2], via_z], quat, grip, cfg.servo, max_steps=cfg.arm_budget // 2
                )
                steps += up.steps + over.steps
        arm = move_to(self.driver, pos, quat, grip, cfg.servo, max_steps=cfg.arm_budget)
        steps += arm.steps

        gripper_steps = 0
        if want_open != self.gripper_open:
            gripper_steps = actuate_gripper(self.driver, open=want_open, config=cfg.gripper)
            self.gripper_open = want_open
        return KeyframeResult(arm=arm, gripper_steps=gripper_steps, steps=steps + gripper_steps)

    def execute_all(self, keyframes: Sequence[Sequence[float]] | np.ndarray) -> list[KeyframeResult]:
        """Execute keyframes in order (shape (K, 9))."""
        return [self.execute(kf) for kf in keyframes]
