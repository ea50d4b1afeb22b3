"""``pipelines/regrasp.py``: when a close held nothing, and where the hand retreats to; and ``sigma-eval``'s
``--regrasps`` in a real robosuite rollout (``pipelines/rollout.py``), with keyframes scripted in place of a policy
so that the first grasp misses by construction."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipelines.evaluate import EvalConfig
from pipelines.failures import failure_reason
from pipelines.regrasp import FALLBACK_RISE_M, grasp_is_empty, retreat_keyframe
from pipelines.rollout import Job, RolloutWorker

QUAT = (1.0, 0.0, 0.0, 0.0)


def _step(xyz, grip=1.0, closed=False, gap=0.08):
    return {
        "action": [*xyz, *QUAT, grip, 0.0],
        "closed_now": closed,
        "opened_now": False,
        "finger_gap_m": gap,
    }


def test_an_empty_grasp_is_a_closed_command_with_the_fingers_together():
    assert grasp_is_empty(_step((0, 0, 0.82), grip=0.0, closed=True, gap=0.002))
    assert not grasp_is_empty(_step((0, 0, 0.82), grip=0.0, closed=True, gap=0.04))  # holds a 4 cm cube
    # a close stalled on the object, fingers still apart: empty only once they meet (the next keyframe)
    assert not grasp_is_empty(_step((0, 0, 0.82), grip=0.0, closed=True, gap=0.064))
    assert not grasp_is_empty(_step((0, 0, 0.82), grip=1.0, gap=0.002))  # open command: nothing to undo


def test_the_hand_retreats_to_the_approach_it_came_down_from():
    trace = [
        _step((0.1, 0.0, 0.95)),  # approach, 13 cm above the close
        _step((0.1, 0.0, 0.83)),  # down, still open: not an approach (1 cm above)
        _step((0.1, 0.0, 0.82), grip=0.0, closed=True, gap=0.001),
    ]
    np.testing.assert_allclose(retreat_keyframe(trace), [0.1, 0.0, 0.95, *QUAT, 1.0, 1.0])
    # the policy closed where it first arrived: straight up from the close instead
    alone = [_step((0.2, 0.1, 0.82), grip=0.0, closed=True, gap=0.001)]
    np.testing.assert_allclose(retreat_keyframe(alone), [0.2, 0.1, 0.82 + FALLBACK_RISE_M, *QUAT, 1.0, 1.0])
    # a close that stalled and met on the next keyframe (the lift): the close, not the lift, is undone
    stalled = [*trace[:2], _step((0.1, 0.0, 0.82), 0.0, True, 0.06), _step((0.1, 0.0, 0.97), 0.0, gap=0.001)]
    np.testing.assert_allclose(retreat_keyframe(stalled)[:3], [0.1, 0.0, 0.95])


class ScriptedWorker(RolloutWorker):
    """The evaluation worker's episode loop with the policy replaced by keyframes computed from the cube's pose:
    the first grasp 5 cm beside the cube (it closes on nothing), every later one at the cube."""

    def __init__(self, cfg: EvalConfig):
        from types import SimpleNamespace

        self.cfg, self.cameras, self.image_size, self.envs = cfg, ("agentview",), 32, {}
        self.policy = SimpleNamespace(reset=lambda: None, config=SimpleNamespace(depth_unit="mm"))
        self.asked: list[str] = []

    def act(self, obs: dict, instruction: str) -> np.ndarray:
        from sigma_data.experts.lift import cube_grasp_quat
        from sigma_data.poses import body_pose, grip_site_frame

        env = self.envs["lift:lift_cube"].env
        cube, rot = body_pose(env, env.cube.root_body)
        quat = cube_grasp_quat(env, rot)
        beside = np.array([0.0, 0.05, 0.0]) if "close" not in self.asked else np.zeros(3)
        hand_z = grip_site_frame(env)[0][2]
        gripper_open = obs["agent_pos"][7] > 0.5
        if gripper_open and hand_z > cube[2] + 0.05:
            step, target, grip = "approach", cube + beside + [0, 0, 0.08], 1.0
            if self.asked and self.asked[-1] == "approach":
                step, target = "down", cube + beside + [0, 0, -0.003]
        elif gripper_open:
            step, target, grip = "close", cube + beside + [0, 0, -0.003], 0.0
        else:
            step, target, grip = "lift", cube + [0, 0, 0.15], 0.0
        self.asked.append(step)
        return np.array([*target, *quat, grip, 1.0])


@pytest.mark.parametrize("regrasps", [0, 1])
def test_a_missed_grasp_is_undone_and_tried_again_in_real_robosuite(tmp_path: Path, regrasps: int):
    worker = ScriptedWorker(EvalConfig(max_keyframes=10, regrasps=regrasps, output_dir=tmp_path))
    try:
        result = worker.run(Job("lift", "lift_cube", 100_000))
    finally:
        worker.close()
    closes = [step for step in result.trace if step["closed_now"]]
    assert closes[0]["finger_gap_m"] < 0.01  # the first close, beside the cube, held nothing
    if regrasps == 0:
        assert not result.success
        assert result.failure.startswith("grasp missed at keyframe 3")
        assert not any(step.get("regrasp") for step in result.trace)
    else:
        retreat = next(step for step in result.trace if step.get("regrasp"))
        assert retreat["keyframe"] == 4 and retreat["finger_gap_m"] > 0.07  # opened, at the approach
        assert result.success and result.failure is None
        assert worker.asked == ["approach", "down", "close", "approach", "down", "close", "lift"]
    assert failure_reason(result, 10) == result.failure
