"""Reading the batch: frames with and without a time axis, instructions, first frames, the depth unit and the
fused camera cloud, each failing with the field's name."""

from __future__ import annotations

import pytest
import torch

from sigma_data.contract import TIMESTAMP
from sigma_policy.configuration_sigma import SigmaConfig
from sigma_policy.observation import (
    batch_tasks,
    camera_cloud,
    check_depth_unit,
    first_frames,
    proprio_input,
    take,
)


def _camera_batch(cfg: SigmaConfig, cam: str, depth_m: float, hw: tuple[int, int] = (4, 5)) -> dict:
    keys = cfg.camera_keys(cam)
    K = torch.tensor([[2.0, 0, 2.5], [0, 2.0, 2.0], [0, 0, 1]])
    return {
        keys["rgb"]: torch.full((2, 3, *hw), 0.5),
        keys["depth"]: torch.full((2, 1, 4, 5), depth_m),
        keys["intrinsics"]: K.expand(2, 3, 3),
        keys["extrinsics"]: torch.eye(4).expand(2, 4, 4),
    }


def _config(**overrides) -> SigmaConfig:
    return SigmaConfig(cameras=["front"], **overrides)  # the one camera of these batches


def test_take_reads_a_frame_of_the_time_axis_and_an_unbatched_frame_0():
    x = torch.arange(2 * 2 * 3).reshape(2, 2, 3)
    assert torch.equal(take({"observation.state": x}, "observation.state", 1, 1), x[:, 1])
    assert torch.equal(take({"observation.state": x[:, 0]}, "observation.state", 0, 1), x[:, 0])
    with pytest.raises(ValueError, match=r"'observation.state'.*observation_delta_indices=\[0, 1\]"):
        take(
            {"observation.state": x[:, 0]}, "observation.state", 1, 1
        )  # the goal frame of an unbatched frame
    with pytest.raises(KeyError, match=r"no 'observation\.images\.top'"):
        take({"observation.state": x}, "observation.images.top", 0, 3)


def test_batch_tasks_and_first_frames_match_the_batch():
    assert batch_tasks({"task": "lift the cube"}, 1) == ["lift the cube"]
    with pytest.raises(ValueError, match="2 task strings for a batch of 3"):
        batch_tasks({"task": ["a", "b"]}, 3)
    first = first_frames({TIMESTAMP: torch.tensor([0.0, 0.5, 0.0])}, 3, torch.device("cpu"), "who")
    assert first.tolist() == [True, False, True]
    with pytest.raises(KeyError, match=f"who needs the batch's '{TIMESTAMP}'"):
        first_frames({}, 3, torch.device("cpu"), "who")


def test_depth_read_in_the_wrong_unit_names_the_feature_and_the_option():
    check_depth_unit(torch.full((2, 4, 4), 1.2), "observation.images.top_depth", "m")
    with pytest.raises(ValueError, match=r"'observation.images.top_depth' has median 1200 m.*depth_unit='m'"):
        check_depth_unit(torch.full((2, 4, 4), 1200.0), "observation.images.top_depth", "m")
    with pytest.raises(ValueError, match="no valid"):
        check_depth_unit(torch.zeros(2, 4, 4), "observation.images.top_depth", "m")


def test_camera_cloud_back_projects_depth_in_millimetres_and_names_a_camera_whose_sizes_differ():
    cfg = _config(depth_unit="mm")
    cloud = camera_cloud(_camera_batch(cfg, "front", 1000.0), cfg, t=0, check_depth=True)
    assert cloud.points.shape == (2, 20, 3) and cloud.colors.shape == (2, 20, 3)
    assert torch.allclose(
        cloud.points[..., 2], torch.ones(2, 20)
    )  # 1000 mm straight ahead of an identity camera
    with pytest.raises(ValueError, match="depth_unit"):
        camera_cloud(
            _camera_batch(cfg, "front", 1.0), cfg, t=0, check_depth=True
        )  # metres read as millimetres
    with pytest.raises(ValueError, match=r"camera 'front': RGB .* and depth .* differ"):
        camera_cloud(_camera_batch(cfg, "front", 1000.0, hw=(8, 8)), cfg, t=0)


def test_proprio_input_is_none_without_the_token_and_the_gripper_state_with_it():
    state = {"observation.state": torch.arange(20.0).reshape(2, 10)}
    bounds = torch.tensor([-1.0, -1.0, -1.0, 1.0, 1.0, 1.0])
    off = SigmaConfig(use_proprio=False)
    assert proprio_input(state, off, bounds, None, torch.device("cpu")) is None
    on = SigmaConfig(use_proprio=True, proprio_position=False, proprio_orientation=False)
    assert torch.equal(
        proprio_input(state, on, bounds, None, torch.device("cpu")), state["observation.state"][:, 7:10]
    )
