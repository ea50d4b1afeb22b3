"""Instruction-contrastive decoding: which instructions are contrasted, and what the contrast does to a heatmap."""

from __future__ import annotations

import math

import pytest
import torch

from sigma_policy.instruction_contrast import check_contrast_weight, contrasted_logits, task_alternatives

TASKS = {
    "put the milk in its bin": "pick_place",
    "put the can in its bin": "pick_place",
    "put the bread in its bin": "pick_place",
    "lift the cube": "lift",
}


def test_alternatives_are_the_other_instructions_of_the_same_task():
    got = task_alternatives(["put the can in its bin", "lift the cube", "a sentence never seen"], TASKS)
    assert got == [["put the bread in its bin", "put the milk in its bin"], [], []]


def _logits(*probs: float) -> torch.Tensor:
    """(1, 1, 1, N) logits whose softmax is ``probs``."""
    return torch.tensor(probs).log().view(1, 1, 1, -1)


def test_a_place_every_instruction_wants_loses_to_the_place_only_this_one_wants():
    """The own heatmap peaks on a salient object that the other instruction wants too (pixel 0) and puts less on
    its own object (pixel 1); the contrast moves the argmax to pixel 1, and leaves the background below both."""
    own = _logits(0.55, 0.35, 0.05, 0.05)
    other = _logits(0.80, 0.02, 0.09, 0.09)
    assert own.flatten().argmax() == 0
    scores = contrasted_logits(own, other[None], torch.tensor([[True]]), weight=0.5).flatten()
    assert scores.argmax() == 1
    assert scores[2] < scores[0] and scores[3] < scores[0]


def test_where_every_instruction_agrees_the_argmax_is_the_policys_own():
    own = torch.randn(2, 5, 8, 8)
    for weight in (0.0, 0.3, 0.9):
        scores = contrasted_logits(
            own, own[None].repeat(3, 1, 1, 1, 1), torch.ones(3, 2, dtype=torch.bool), weight
        )
        expected = (1 - weight) * torch.log_softmax(own.flatten(2), -1)
        torch.testing.assert_close(scores.flatten(2), expected)


def test_padding_is_left_out_of_the_mean():
    """A sample with fewer alternatives than the batch's widest is padded; the padding does not count."""
    own, real, pad = torch.randn(1, 5, 4, 4), torch.randn(1, 5, 4, 4), torch.randn(1, 5, 4, 4)
    alone = contrasted_logits(own, real[None], torch.tensor([[True]]), 0.5)
    padded = contrasted_logits(own, torch.stack([real, pad]), torch.tensor([[True], [False]]), 0.5)
    torch.testing.assert_close(padded, alone)
    # the mean is over own and the real alternative: log p_own - w log((p_own + p_real) / 2)
    log_own, log_real = (torch.log_softmax(x.flatten(2), -1) for x in (own, real))
    log_mean = torch.logaddexp(log_own, log_real) - math.log(2)
    torch.testing.assert_close(alone.flatten(2), log_own - 0.5 * log_mean)


def test_shapes_that_do_not_match_and_weights_outside_0_1_are_refused():
    with pytest.raises(ValueError, match="do not match"):
        contrasted_logits(
            torch.zeros(1, 5, 4, 4), torch.zeros(2, 1, 5, 4, 3), torch.ones(2, 1, dtype=torch.bool), 0.5
        )
    for weight in (-0.1, 1.0, 2.0):
        with pytest.raises(ValueError, match=r"\[0, 1\)"):
            check_contrast_weight(weight)
    assert check_contrast_weight(0) == 0.0


def test_swap_negative_costs_the_mass_the_other_instruction_puts_at_the_own_target():
    """-log(1 - q) per view, averaged: nothing at the target costs 0, half of the mass costs log 2, and a view the
    target is outside of (an all-zero window) costs nothing."""
    from sigma_policy.instruction_contrast import swap_negative_loss

    window = torch.tensor([1.0, 0.5, 0.0, 0.0]).view(1, 1, 1, 4)
    away = swap_negative_loss(_logits(1e-9, 1e-9, 0.5, 0.5), window)
    assert away.item() == pytest.approx(0.0, abs=1e-6)
    half = swap_negative_loss(_logits(0.5, 1e-9, 0.5 - 1e-9, 1e-9), window)
    assert half.item() == pytest.approx(math.log(2), rel=1e-4)
    two_views = torch.cat([_logits(0.5, 1e-9, 0.5 - 1e-9, 1e-9)] * 2, dim=1)
    outside = torch.cat([window, torch.zeros_like(window)], dim=1)
    assert swap_negative_loss(two_views, outside).item() == pytest.approx(math.log(2) / 2, rel=1e-4)
    all_in = swap_negative_loss(_logits(1.0 - 3e-9, 1e-9, 1e-9, 1e-9), window)
    assert all_in.item() > 10 and torch.isfinite(all_in)


def test_swap_negative_gradient_moves_mass_off_the_target():
    from sigma_policy.instruction_contrast import swap_negative_loss

    logits = torch.zeros(1, 1, 1, 4, requires_grad=True)
    swap_negative_loss(logits, torch.tensor([1.0, 0.0, 0.0, 0.0]).view(1, 1, 1, 4)).backward()
    assert logits.grad[0, 0, 0, 0] > 0 and (logits.grad[0, 0, 0, 1:] < 0).all()
    with pytest.raises(ValueError, match="differ"):
        swap_negative_loss(logits, torch.ones(1, 1, 2, 2))
