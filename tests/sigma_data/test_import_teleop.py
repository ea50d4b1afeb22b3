"""Teleoperation driven headless by a scripted device: manual keyframe marks, reset, discard and keep; the kept
episode lands in datasets that pass validation and load in stock LeRobot."""

from pathlib import Path

import numpy as np
import pytest
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from sigma_data.cameras import RenderOptions
from sigma_data.importers.teleop import (
    EventSource,
    ScriptedDevice,
    ScriptStep,
    TeleopConfig,
    TeleopEvent,
    TeleopSource,
    device_action,
    outcome_line,
    record_teleop,
    teleop_keyframes,
)
from sigma_data.output import OutputConfig
from sigma_data.validate import ValidateConfig, validate_dataset

DOWN_OPEN = (0.0, 0.0, -0.3, 0.0, 0.0, 0.0, -1.0)
HOLD_CLOSE = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)
UP_CLOSED = (0.0, 0.0, 0.3, 0.0, 0.0, 0.0, 1.0)


def steps(action, n):
    return [ScriptStep(action)] * n


def script() -> list[ScriptStep]:
    return [
        # episode 1 (seed 0): two steps, then the operator resets -> same seed again
        *steps(DOWN_OPEN, 2),
        ScriptStep(events=(TeleopEvent.RESET,)),
        # episode 2 (seed 0): a mark, then discarded -> next seed
        *steps(DOWN_OPEN, 3),
        ScriptStep(DOWN_OPEN, events=(TeleopEvent.KEYFRAME,)),
        ScriptStep(events=(TeleopEvent.DISCARD,)),
        # episode 3 (seed 1): move down, mark, close the gripper, mark, lift, keep
        *steps(DOWN_OPEN, 4),
        ScriptStep(HOLD_CLOSE, events=(TeleopEvent.KEYFRAME,)),  # marks frame 4, then the first close
        *steps(HOLD_CLOSE, 3),
        ScriptStep(UP_CLOSED, events=(TeleopEvent.KEYFRAME, TeleopEvent.KEYFRAME)),  # marks frame 8 once
        *steps(UP_CLOSED, 2),
        ScriptStep(events=(TeleopEvent.KEEP,)),
        # the script ends: QUIT
    ]


def test_scripted_session_marks_resets_discards_and_keeps(tmp_path):
    device = ScriptedDevice(script())
    assert isinstance(device, TeleopSource) and isinstance(device, EventSource)
    out = tmp_path / "teleop"
    cfg = TeleopConfig(
        task="lift",
        episodes=5,
        viewer=False,
        render=RenderOptions(cameras="agentview,robot0_eye_in_hand", height=32, width=32),
        output=OutputConfig(dir=out, dense_video=False),
    )
    summary, outcomes = record_teleop(cfg, device=device, events=device)
    assert [(o.kind, o.seed, o.steps) for o in outcomes] == [
        ("reset", 0, 2),
        ("discard", 0, 4),
        ("keep", 1, 11),
        ("quit", 2, 0),
    ]
    assert device.started == 4
    assert outcome_line(outcomes) == "teleop: kept 1, discarded 1, reset 1, timed out 0 episodes"
    assert summary.converted == 1 and summary.frames == {"dense": 12, "keyframe": 5}

    kept = outcomes[2].episode
    assert kept.keyframe_indices == [4, 5, 8, 11]
    assert [k.source for k in kept.keyframes] == ["manual", "gripper", "manual", "final"]
    assert [k.gripper_open for k in kept.keyframes] == [True, False, False, False]
    np.testing.assert_allclose(kept.actions[0], DOWN_OPEN, atol=1e-6)
    assert kept.states[2, 2] < kept.states[0, 2] - 0.005  # the scripted motion moved the arm down

    for kind in ("dense", "keyframe"):
        report = validate_dataset(ValidateConfig(root=out / kind, frames_per_episode=3))
        assert report.num_errors == 0, report.table()
    dense = LeRobotDataset("local/teleop", root=out / "dense", depth_output_unit="m", video_backend="pyav")
    flags = np.asarray(dense.hf_dataset.with_format(None)["sigma.is_keyframe"]).reshape(-1)
    assert np.flatnonzero(flags).tolist() == [4, 5, 8, 11]
    assert dense[0]["task"] == "lift the cube"
    keyframe = LeRobotDataset("local/teleop_kf", root=out / "keyframe", video_backend="pyav")
    assert keyframe.meta.total_episodes == 1 and len(keyframe) == 5


def test_keyframe_modes_and_device_actions():
    g = np.array([1, 1, 1, 1, 0, 0, 0, 0], dtype=np.float32)
    still = np.zeros((8, 7))
    manual = teleop_keyframes([2], g, still, "manual")
    assert [k.index for k in manual] == [2, 4, 7]
    union = teleop_keyframes([2], g, still, "union")
    assert {2, 4, 7} <= {k.index for k in union}
    with pytest.raises(ValueError, match="unknown keyframe mode"):
        teleop_keyframes([], g, still, "both")
    # robosuite's input2action() dict -> the 7-D env action (clipped to [-1, 1])
    a = device_action({"right_delta": np.array([2.0, 0, 0, 0, 0, -0.5]), "right_gripper": np.array([1.0])})
    np.testing.assert_allclose(a, [1.0, 0, 0, 0, 0, -0.5, 1.0])
    with pytest.raises(ValueError, match="right_gripper"):
        device_action({"right_delta": np.zeros(6)})


def test_an_output_option_on_the_command_line_keeps_teleops_output_dir():
    """One ``--output.*`` option leaves the others at teleop's defaults (not the importers')."""
    import draccus

    cfg = draccus.parse(TeleopConfig, args=["--output.dense_video=false", "--render.cameras=agentview"])
    assert cfg.output.dir == Path("outputs/sigma_teleop") and not cfg.output.dense_video
    assert cfg.render.config().cameras == ("agentview",) and cfg.render.height == 128
