"""The zoomed second stage's boxes (sigma_policy/zoom.py): where training and inference put the cube."""

from __future__ import annotations

import pytest
import torch

from sigma_policy.configuration_sigma import SigmaConfig
from sigma_policy.zoom import box_code, box_side, check_zoom, cube_around, training_boxes


def test_cube_around_is_centred_on_the_point_with_the_given_side():
    centre = torch.tensor([[0.1, -0.2, 0.9], [0.0, 0.0, 1.0]])
    box = cube_around(centre, 0.3)
    torch.testing.assert_close((box[:, :3] + box[:, 3:]) / 2, centre)
    torch.testing.assert_close(box[:, 3:] - box[:, :3], torch.full((2, 3), 0.3))
    torch.testing.assert_close(box_side(box), torch.full((2, 1), 0.3))
    # never coarser than the first stage: a box narrower than the zoom gives its own side
    task = torch.tensor([[-0.18, -0.18, 0.75, 0.18, 0.18, 1.11], [-0.4, -0.5, 0.75, 0.6, 0.5, 1.75]])
    torch.testing.assert_close(box_side(cube_around(centre, 0.5, task))[:, 0], torch.tensor([0.36, 0.5]))


def test_training_boxes_zoom_the_share_asked_for_around_the_jittered_target():
    gen = torch.Generator().manual_seed(0)
    B, side, jitter = 4000, 0.3, 0.05
    task_box = torch.tensor([-0.4, -0.5, 0.75, 0.6, 0.5, 1.75])
    target = torch.rand(B, 3, generator=gen) * 0.4 + torch.tensor([-0.2, -0.2, 0.8])
    boxes, zoomed = training_boxes(task_box.expand(B, 6), target, side, 0.25, jitter, generator=gen)
    assert abs(zoomed.float().mean().item() - 0.25) < 0.03
    torch.testing.assert_close(boxes[~zoomed], task_box.expand(int((~zoomed).sum()), 6))
    offset = (boxes[zoomed, :3] + boxes[zoomed, 3:]) / 2 - target[zoomed]
    assert offset.abs().max() <= jitter + 1e-6
    assert offset.abs().max() > 0.9 * jitter  # the whole jitter range is drawn, not only the centre
    torch.testing.assert_close(
        boxes[zoomed, 3:] - boxes[zoomed, :3], torch.full((int(zoomed.sum()), 3), side)
    )
    # the target stays inside its zoomed box, at least side / 2 - jitter from every face
    inside = torch.minimum(target[zoomed] - boxes[zoomed, :3], boxes[zoomed, 3:] - target[zoomed])
    assert inside.min() >= side / 2 - jitter - 1e-6


@pytest.mark.parametrize(
    ("side", "share", "jitter", "match"),
    [(-0.1, 0.5, 0.0, "zoom_box_m"), (0.3, 1.0, 0.0, "zoom_share"), (0.3, 0.5, 0.15, "zoom_jitter_m")],
)
def test_check_zoom_names_the_bad_option(side, share, jitter, match):
    with pytest.raises(ValueError, match=match):
        check_zoom(side, share, jitter)


def test_zoom_is_off_by_default_and_needs_the_proprio_position():
    check_zoom(0.0, 2.0, 9.0)  # off: the other two are not read
    assert SigmaConfig(preset="suite").zoom_box_m == 0.0
    with pytest.raises(ValueError, match="proprio_position"):
        SigmaConfig(preset="paper", zoom_box_m=0.3)
    on = SigmaConfig(preset="small", zoom_box_m=0.3)
    assert on.network_config().proprio_dim == SigmaConfig(preset="small").network_config().proprio_dim + 4


def test_box_code_is_the_side_and_the_centre_in_the_task_box():
    task = torch.tensor([[-0.4, -0.5, 0.75, 0.6, 0.5, 1.75]])
    torch.testing.assert_close(box_code(task, task), torch.tensor([[1.0, 0.0, 0.0, 0.0]]))
    # a 0.5 m cube a quarter of the way in from the task box's far x and y faces, a quarter up from its floor
    zoomed = cube_around(torch.tensor([[0.35, 0.25, 1.0]]), 0.5)
    torch.testing.assert_close(box_code(zoomed, task), torch.tensor([[0.5, 0.5, 0.5, -0.5]]))
