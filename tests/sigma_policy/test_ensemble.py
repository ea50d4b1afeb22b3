"""Several policies acting as one (sigma_policy/ensemble.py): the mean of the members' probabilities, one policy
with itself acting as alone, two policies' heatmaps averaged, and members that render another scene refused."""

from __future__ import annotations

import pytest
import torch

from sigma_policy.configuration_sigma import SigmaConfig
from sigma_policy.ensemble import check_members, mean_probability_logits
from tests.sigma_policy.test_modeling import build, single_observation
from tests.sigma_policy.tiny_dataset import write_tiny_keyframe_dataset


@pytest.fixture(scope="module")
def tiny_root(tmp_path_factory):
    return write_tiny_keyframe_dataset(tmp_path_factory.mktemp("sigma") / "tiny", episodes=2, size=48)


def test_mean_probability_logits_give_the_mean_of_the_members_distributions_per_view():
    torch.manual_seed(0)
    a, b = torch.randn(2, 5, 4, 4), torch.randn(2, 5, 4, 4)
    mean = mean_probability_logits([a, b], event_dims=2)
    assert mean.shape == a.shape

    def per_view(x):
        return torch.softmax(x.flatten(2), -1)

    torch.testing.assert_close(per_view(mean), (per_view(a) + per_view(b)) / 2)
    rot = mean_probability_logits([a[:, :3, 0], b[:, :3, 0]])  # (B, 3, bins): over the last dimension
    torch.testing.assert_close(rot.softmax(-1), (a[:, :3, 0].softmax(-1) + b[:, :3, 0].softmax(-1)) / 2)


def test_a_policy_with_itself_acts_as_alone_and_two_policies_average_their_heatmaps(tiny_root):
    _, policy, pre, _, _ = build(tiny_root)
    torch.manual_seed(1)
    _, other, *_ = build(tiny_root)
    policy.eval(), other.eval()
    obs = pre(single_observation(tiny_root, 1))
    alone = policy.predict(obs)
    second = other.predict(obs)
    assert not torch.allclose(alone.heatmaps, second.heatmaps)  # two different networks

    policy.add_ensemble_members([policy], ["itself"])
    twice = policy.predict(obs)
    torch.testing.assert_close(twice.heatmaps, alone.heatmaps)
    torch.testing.assert_close(twice.action, alone.action, atol=1e-5, rtol=0)
    torch.testing.assert_close(twice.rotation_probs, alone.rotation_probs, atol=1e-5, rtol=0)

    policy.add_ensemble_members([other], ["other"])
    both = policy.predict(obs)
    torch.testing.assert_close(both.heatmaps, (alone.heatmaps + second.heatmaps) / 2)
    torch.testing.assert_close(both.views, alone.views)  # one rendering for every member


def test_members_that_render_another_scene_are_refused_naming_the_member_and_the_field():
    lead = SigmaConfig(preset="small", img_size=32, cameras=["front"])
    check_members(lead, [SigmaConfig(preset="small", img_size=32, cameras=["front"], attn_dim=64)], ["wider"])
    with pytest.raises(ValueError, match="member b: img_size is 64, the first policy's is 32"):
        check_members(lead, [SigmaConfig(preset="small", img_size=64, cameras=["front"])], ["b"])
    with pytest.raises(ValueError, match=r"member c: cameras \['side'\]"):
        check_members(lead, [SigmaConfig(preset="small", img_size=32, cameras=["side"])], ["c"])
