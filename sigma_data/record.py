"""Record an episode from the simulator state every control step, without rendering.

:class:`EpisodeRecorder` is what scripted experts (and teleoperation, replay) drive: ``step(action)`` executes
one ``env.step`` and stores, for the frame *before* the action, the flattened MuJoCo state, the 10-D
``observation.state`` vector and the arm joint velocities, plus the executed action. ``mark_keyframe`` labels
the state reached by the most recent step as an expert keyframe. :meth:`EpisodeRecorder.to_episode` closes the
episode with the final state (a hold action) and returns an :class:`~sigma_data.episode.Episode` whose pixels
are rendered later by state replay, only for the frames that are stored.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sigma_data.contract import DENSE_ACTION_DIM
from sigma_data.episode import (
    STATE_DIM,
    Episode,
    Keyframe,
    hold_action,
    with_final_keyframe,
)
from sigma_data.poses import grip_site_pose

ACTION_DIM = DENSE_ACTION_DIM  # robosuite OSC_POSE delta + gripper


def robot_state(env: Any, gripper_open: bool) -> np.ndarray:
    """The contract's ``observation.state`` (10,) float32 at the current ``sim.data`` (call ``forward()`` first).

    ``[eef_x, eef_y, eef_z, eef_qx, eef_qy, eef_qz, eef_qw, gripper_open, finger_q1, finger_q2]``: grip-site
    pose in the world (not ``robot0_eef_quat``, the hand body), ``gripper_open`` from the last command,
    finger joint positions in metres (Panda: q1 in [0, 0.04], q2 in [-0.04, 0]).
    """
    pos, quat = grip_site_pose(env)
    robot = env.robots[0]
    fingers = env.sim.data.qpos[robot._ref_gripper_joint_pos_indexes["right"]]
    return np.concatenate([pos, quat, [float(gripper_open)], fingers]).astype(np.float32)


def arm_joint_velocities(env: Any) -> np.ndarray:
    """Arm joint velocities (n_arm,) rad/s."""
    return np.array(env.sim.data.qvel[env.robots[0]._ref_joint_vel_indexes], dtype=np.float64)


# The largest approach offset an expert's plan is made for: beyond it the approach may leave the object's bin.
MAX_PREGRASP_JITTER_M = 0.1


def check_pregrasp_jitter(radius_m: float) -> float:
    """``radius_m`` as a float when it is a radius in [0, :data:`MAX_PREGRASP_JITTER_M`) metres, else ValueError."""
    if not (np.isfinite(radius_m) and 0 <= radius_m < MAX_PREGRASP_JITTER_M):
        raise ValueError(f"pregrasp_jitter_m must be in [0, {MAX_PREGRASP_JITTER_M}) m, got {radius_m}")
    return float(radius_m)


class EpisodeRecorder:
    """Steps a robosuite env and records states, actions and keyframe marks (the ``tasks_api`` protocol).

    Create it right after ``reset_env`` (frame 0 is the state at construction, gripper assumed open as
    ``reset_env`` leaves it). The env should have ``use_camera_obs=False`` so that stepping never renders.
    ``pregrasp_jitter_m`` is read by the experts' :class:`~sigma_data.experts.base.WaypointArm`: the radius of the
    random x-y offset it gives each approach waypoint (0: the expert's own waypoints).
    """

    def __init__(self, env: Any, initial_gripper_open: bool = True, pregrasp_jitter_m: float = 0.0):
        self.env = env
        self.pregrasp_jitter_m = check_pregrasp_jitter(pregrasp_jitter_m)
        self._gripper_open = bool(initial_gripper_open)
        self._sim_states: list[np.ndarray] = []
        self._states: list[np.ndarray] = []
        self._joint_vel: list[np.ndarray] = []
        self._actions: list[np.ndarray] = []
        self._keyframes: list[Keyframe] = []
        self._capture()

    def _capture(self) -> None:
        sim = self.env.sim
        sim.forward()  # after env.step, site/camera poses lag qpos by one substep
        self._sim_states.append(np.array(sim.get_state().flatten(), dtype=np.float64))
        self._states.append(robot_state(self.env, self._gripper_open))
        self._joint_vel.append(arm_joint_velocities(self.env))

    @property
    def num_steps(self) -> int:
        """Control steps executed so far."""
        return len(self._actions)

    def step(self, action: np.ndarray) -> None:
        """Execute one control step with a 7-D OSC_POSE delta ``[dx, dy, dz, rx, ry, rz, grip]`` and record it."""
        action = np.asarray(action, dtype=np.float64)
        if action.shape != (ACTION_DIM,) or not np.isfinite(action).all():
            raise ValueError(f"action must be {ACTION_DIM} finite values, got {action!r}")
        self.env.step(action)
        self._actions.append(action)
        self._gripper_open = bool(action[-1] < 0)
        self._capture()

    def mark_keyframe(self, gripper_open: bool, ignore_collision: bool) -> None:
        """Label the state reached by the most recent step as an expert keyframe."""
        if not self._actions:
            raise RuntimeError("mark_keyframe() called before any step(): frame 0 cannot be a keyframe")
        index = len(self._actions)  # frame index of the state after the last step
        if self._keyframes and self._keyframes[-1].index == index:
            raise RuntimeError(
                f"frame {index} is already a keyframe: mark_keyframe() called twice without a step"
            )
        self._keyframes.append(Keyframe(index, bool(gripper_open), bool(ignore_collision), source="expert"))

    def to_episode(
        self,
        task: str,
        variation: str,
        instruction: str,
        seed: int | None = None,
        provenance: dict[str, Any] | None = None,
    ) -> Episode:
        """The recorded episode: ``num_steps + 1`` frames (the final state gets a hold action), keyframes
        ending at the final frame."""
        if not self._actions:
            raise RuntimeError(f"{task}/{variation} seed {seed}: nothing recorded (no step() was called)")
        length = len(self._states)
        actions = np.stack([*self._actions, hold_action(self._actions[-1])]).astype(np.float32)
        keyframes = with_final_keyframe(self._keyframes, length, self._gripper_open)
        states = np.stack(self._states)
        assert states.shape == (length, STATE_DIM)
        return Episode(
            task=task,
            variation=variation,
            instruction=instruction,
            states=states,
            actions=actions,
            keyframes=keyframes,
            joint_velocities=np.stack(self._joint_vel),
            sim_states=np.stack(self._sim_states),
            seed=seed,
            provenance=dict(provenance or {}),
        )
