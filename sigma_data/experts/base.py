"""Shared pieces of the scripted waypoint experts.

An expert is a function ``expert(recorder, variation, rng) -> None`` that drives the robot through the
recorder (``sigma_data.record.EpisodeRecorder``: ``env``, ``step(action)``, ``mark_keyframe(...)``) and
marks the end of every waypoint as an expert keyframe with its gripper-open and ignore-collision labels.
It raises :class:`ExpertFailure` when it gives up; the pipeline drops and counts such episodes.

:class:`WaypointArm` wraps the :mod:`sigma_data.control` primitives so an expert reads as its list of
waypoints: ``arm.move(pos, quat, ignore_collision=...)``, ``arm.grip(open=...)``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from sigma_data.control import (
    GRIP_CLOSE,
    GRIP_OPEN,
    MoveResult,
    MoveStatus,
    ServoConfig,
    actuate_gripper,
    hold,
    move_to,
)

if TYPE_CHECKING:
    from sigma_data.tasks.spec import Variation


class ExpertFailure(RuntimeError):  # noqa: N818  (name fixed by the tasks_api contract)
    """A scripted expert gave up on an episode (the reason says where and why)."""


class EpisodeRecorder(Protocol):
    """The recorder interface experts drive (implemented by ``sigma_data.record``)."""

    env: Any

    def step(self, action: np.ndarray) -> None: ...

    def mark_keyframe(self, gripper_open: bool, ignore_collision: bool) -> None: ...

    @property
    def num_steps(self) -> int: ...


ExpertFn = Callable[[EpisodeRecorder, "Variation", np.random.Generator], None]


class WaypointArm:
    """Waypoint-level control for an expert: every finished waypoint becomes an expert keyframe.

    Tracks the commanded gripper state (the episode starts fully open, see ``reset_env``). A move that
    ends farther than ``fail_pos_tol`` (m) / ``fail_rot_tol`` (rad) from its waypoint raises
    :class:`ExpertFailure` naming the waypoint, unless the caller accepts contact (``allow_stall``).
    """

    def __init__(
        self,
        recorder: EpisodeRecorder,
        servo: ServoConfig = ServoConfig(),
        fail_pos_tol: float = 0.015,
        fail_rot_tol: float = 0.15,
    ):
        self.recorder = recorder
        self.env = recorder.env
        self.servo = servo
        self.fail_pos_tol = fail_pos_tol
        self.fail_rot_tol = fail_rot_tol
        self.gripper_open = True

    @property
    def grip_command(self) -> float:
        return GRIP_OPEN if self.gripper_open else GRIP_CLOSE

    def move(
        self,
        name: str,
        pos: Sequence[float],
        quat_xyzw: Sequence[float],
        ignore_collision: bool,
        *,
        max_steps: int | None = None,
        keyframe: bool = True,
        allow_stall: bool = False,
        pos_tol: float | None = None,
    ) -> MoveResult:
        """Servo to a waypoint (world grip-site pose) and mark it as a keyframe (unless ``keyframe=False``)."""
        result = move_to(self.recorder, pos, quat_xyzw, self.grip_command, self.servo, max_steps=max_steps)
        fail_pos = self.fail_pos_tol if pos_tol is None else pos_tol
        off_target = result.pos_error > fail_pos or result.rot_error > self.fail_rot_tol
        if off_target and not (allow_stall and result.status == MoveStatus.STALLED):
            raise ExpertFailure(
                f"waypoint '{name}' not reached ({result.status.value} after {result.steps} steps): "
                f"position error {1000 * result.pos_error:.1f} mm, rotation error {result.rot_error:.3f} rad"
            )
        if keyframe:
            self.recorder.mark_keyframe(self.gripper_open, ignore_collision)
        return result

    def grip(self, open: bool, ignore_collision: bool = True) -> int:
        """Open or close the gripper in place and mark the end as a keyframe. Returns steps taken."""
        steps = actuate_gripper(self.recorder, open=open)
        self.gripper_open = open
        self.recorder.mark_keyframe(self.gripper_open, ignore_collision)
        return steps

    def hold(self, steps: int) -> None:
        """Hold the current pose for ``steps`` control steps (no keyframe)."""
        hold(self.recorder, steps, self.grip_command)


def check_grasp(env: Any, obj: Any, what: str) -> None:
    """Raise :class:`ExpertFailure` unless both fingers touch ``obj`` (a robosuite ``MujocoObject``)."""
    if not env._check_grasp(gripper=env.robots[0].gripper, object_geoms=obj):
        raise ExpertFailure(f"grasp of the {what} failed: fingers not in contact after closing")
