"""Places a keyframe must not go (sigma_policy/exclusion.py): the heatmaps' best voxel outside vertical cylinders,
on flat and tilted views, and ``SigmaPolicy.avoid`` moving a real policy's translation out of one until reset."""

from __future__ import annotations

import pytest
import torch

from sigma_policy.exclusion import Exclusion
from sigma_policy.heatmap import gaussian_heatmaps, heatmap_to_cube_point
from sigma_policy.renderer import VirtualViewRenderer
from tests.sigma_policy.test_modeling import build, single_observation
from tests.sigma_policy.tiny_dataset import write_tiny_keyframe_dataset

BOX = torch.tensor([[-0.5, -0.5, 0.5, 0.5, 0.5, 1.5]])  # 1 m: a cube unit is 0.5 m


def two_peaks(S: int, tilt: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Heatmap logits (1, V, S, S) of a strong peak at ``best`` and a weaker one at ``second`` (cube points)."""
    renderer = VirtualViewRenderer(img_size=S, side_tilt_deg=tilt)
    best, second = torch.tensor([[0.3, 0.1, -0.2]]), torch.tensor([[-0.4, 0.5, 0.2]])
    prob = 0.7 * gaussian_heatmaps(renderer.project(best[:, None])[:, 0], S)
    prob = prob + 0.3 * gaussian_heatmaps(renderer.project(second[:, None])[:, 0], S)
    return torch.log(prob + 1e-12), best, second


@pytest.mark.parametrize(("S", "tilt"), [(64, 0.0), (32, 30.0)])
def test_the_best_voxel_outside_the_cylinders_is_the_point(S: int, tilt: float):
    logits, best, second = two_peaks(S, tilt)
    voxel = 2 / S

    def point(exclude=None):
        return heatmap_to_cube_point(logits, S, side_tilt_deg=tilt, exclude=exclude)[0]

    assert (point() - best[0]).norm() < voxel
    # 15 cm about the best peak's world point (beyond its Gaussian's 3 sigma), at another height: a cylinder covers
    # every height
    above = (best * 0.5 + torch.tensor([0.0, 0.0, 1.0]))[None] + torch.tensor([0.0, 0.0, 0.3])
    assert (point(Exclusion.around(above, 0.15, BOX)) - second[0]).norm() < voxel
    # a smaller one leaves the peak's flank outside it, and that voxel is not refined back under the cylinder
    flank = heatmap_to_cube_point(
        logits, S, refine_px=2, side_tilt_deg=tilt, exclude=Exclusion.around(above, 0.03, BOX)
    )[0]
    assert (flank[:2] - best[0, :2]).norm() >= 0.06  # 3 cm is 0.06 cube units in the 1 m box
    # a cylinder 25 cm beside it changes nothing; one over both peaks leaves the best of what it covers
    beside = above + torch.tensor([0.25, 0.0, 0.0])
    assert (point(Exclusion.around(beside, 0.15, BOX)) - best[0]).norm() < voxel
    assert (point(Exclusion.around(above, 5.0, BOX)) - best[0]).norm() < voxel


def test_an_exclusion_is_a_vertical_cylinder_in_each_samples_box():
    boxes = torch.tensor([[-0.5, -0.5, 0.5, 0.5, 0.5, 1.5], [-0.2, -0.2, 0.5, 0.2, 0.2, 0.9]])
    points = torch.tensor([[[0.1, 0.0, 1.0]], [[0.1, 0.0, 0.7]]])
    ex = Exclusion.around(points, 0.04, boxes)
    torch.testing.assert_close(ex.radii, torch.tensor([0.08, 0.2]))  # 4 cm of a 1 m and of a 0.4 m box
    # cube x of world x 0.10 and 0.13 in the 1 m box, 0.10 and 0.15 in the 0.4 m one
    x = torch.tensor([0.2, 0.26, 0.5, 0.75])[None]
    covered = torch.tensor([[1, 1, 0, 0], [0, 0, 1, 0]]).bool()
    torch.testing.assert_close(ex.covers(x, torch.zeros(1, 4)), covered)
    with pytest.raises(ValueError, match="radius_m must be > 0"):
        Exclusion.around(points, 0.0, boxes)
    with pytest.raises(ValueError, match=r"points must be \(B, K, 3\)"):
        Exclusion.around(points[:, 0], 0.04, boxes)


def test_a_policy_asked_to_avoid_its_keyframe_goes_elsewhere_until_reset(tmp_path):
    root = write_tiny_keyframe_dataset(tmp_path / "tiny", episodes=2, size=48)
    _, policy, pre, _, _ = build(root)
    policy.eval()
    obs = pre(single_observation(root, 1))
    first = policy.predict(obs).point_world[0]
    policy.avoid(first.tolist(), 0.03)
    moved = policy.predict(obs)
    assert (moved.point_world[0, :2] - first[:2]).norm() >= 0.03
    assert torch.isfinite(moved.action).all()
    # and the second place, named 20 cm above it: the cylinder has no top
    policy.avoid((moved.point_world[0] + torch.tensor([0.0, 0.0, 0.2])).tolist(), 0.03)
    third = policy.predict(obs).point_world[0]
    assert min((third[:2] - p[:2]).norm() for p in (first, moved.point_world[0])) >= 0.03
    policy.reset()
    torch.testing.assert_close(policy.predict(obs).point_world[0], first)
    with pytest.raises(ValueError, match="3 finite world coordinates"):
        policy.avoid([0.0, float("nan"), 1.0], 0.03)
