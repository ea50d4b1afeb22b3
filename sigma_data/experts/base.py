"""Shared pieces of the scripted waypoint experts.

An expert is a function ``expert(recorder, variation, rng) -> None`` that drives the robot through the
recorder (``sigma_data.record.EpisodeRecorder``: ``env``, ``step(action)``, ``mark_keyframe(...)``) and
marks the end of every waypoint as an expert keyframe with its gripper-open and ignore-collision labels.
It raises :class:`ExpertFailure` when it gives up; the pipeline drops and counts such episodes.

:class:`WaypointArm` wraps the :mod:`sigma_data.control` primitives so an expert reads as its list of
waypoints: ``arm.move(pos, quat, ignore_collision=...)``, ``arm.grip(open=...)``. A waypoint passed with
``approach=True`` (the pose above an object before the grasp) is moved by a random horizontal offset when the
recorder asks for it (``pregrasp_jitter_m``, DART-style data: Laskey et al., "DART: Noise Injection for Robust
Imitation Learning", CoRL 2017, https://arxiv.org/abs/1703.09327); the grasp after it still goes to the object.
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
    # Radius (m) of the approach waypoints' random offset; optional (WaypointArm reads 0 where it is absent).
    pregrasp_jitter_m: float

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
        rng: np.random.Generator | None = None,
    ):
        self.recorder = recorder
        self.rng = rng
        self.jitter_m = float(getattr(recorder, "pregrasp_jitter_m", 0.0))
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
        approach: bool = False,
    ) -> MoveResult:
        """Servo to a waypoint (world grip-site pose) and mark it as a keyframe (unless ``keyframe=False``). An
        ``approach`` waypoint is first moved by :meth:`approach_offset`."""
        if approach:
            pos = np.asarray(pos, dtype=np.float64) + self.approach_offset()
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

    def approach_offset(self) -> np.ndarray:
        """(3,) a horizontal offset uniform over the disc of radius ``pregrasp_jitter_m`` (zeros, and no draw from
        the expert's generator, when it is 0)."""
        if not self.jitter_m:
            return np.zeros(3)
        if self.rng is None:
            raise ValueError("a recorder with pregrasp_jitter_m needs WaypointArm(..., rng=the expert's rng)")
        angle, radius = self.rng.uniform(0, 2 * np.pi), self.jitter_m * np.sqrt(self.rng.uniform())
        return np.array([radius * np.cos(angle), radius * np.sin(angle), 0.0])

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
