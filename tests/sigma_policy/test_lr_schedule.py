"""The held-peak cosine schedule: LeRobot's schedule at hold 0, the hold, the sum, registration and config wiring."""

from __future__ import annotations

import itertools

import pytest
import torch
from lerobot.optim.schedulers import CosineDecayWithWarmupSchedulerConfig, LRSchedulerConfig

from sigma_policy.configuration_sigma import SigmaConfig
from sigma_policy.lr_schedule import SCHEDULER_TYPE, HoldCosineSchedulerConfig, summed_multiplier


def stepped_multipliers(config: CosineDecayWithWarmupSchedulerConfig, steps: int) -> list[float]:
    """The rate / peak that a real optimiser sees at each of ``steps`` steps of a built scheduler."""
    opt = torch.optim.SGD([torch.nn.Parameter(torch.zeros(1))], lr=config.peak_lr)
    sched = config.build(opt, num_training_steps=steps)
    out = []
    for _ in range(steps):
        out.append(opt.param_groups[0]["lr"] / config.peak_lr)
        opt.step()
        sched.step()
    return out


def schedule(hold: float, warmup: int = 20, decay: int = 2000) -> HoldCosineSchedulerConfig:
    return HoldCosineSchedulerConfig(
        num_warmup_steps=warmup, num_decay_steps=decay, peak_lr=1e-2, decay_lr=1e-4, hold_fraction=hold
    )


@pytest.mark.parametrize(
    ("steps", "decay"), [(700, 2000), (300, 300), (500, 200)]
)  # shrunk, exact, longer run
def test_without_a_hold_it_is_lerobots_schedule(steps: int, decay: int):
    stock = CosineDecayWithWarmupSchedulerConfig(
        num_warmup_steps=20, num_decay_steps=decay, peak_lr=1e-2, decay_lr=1e-4
    )
    mine = stepped_multipliers(schedule(0.0, decay=decay), steps)
    assert mine == pytest.approx(stepped_multipliers(stock, steps), abs=1e-12)


def test_holds_the_peak_then_decays_to_the_floor():
    # shrunk to the run: warm-up 7 steps, the peak held to step 420, where the cosine starts, decay to step 700
    rates = stepped_multipliers(schedule(0.6), 700)
    assert rates[0] == pytest.approx(1 / 8)
    assert rates[6] < 1.0 and all(r == 1.0 for r in rates[7:421])
    assert rates[421] < 1.0 and all(a >= b for a, b in itertools.pairwise(rates[420:]))
    assert rates[-1] == pytest.approx(0.01, abs=1e-4)
    assert rates[560] == pytest.approx(0.01 + 0.99 * 0.5, abs=1e-9)  # half-way through the decay


def test_summed_rate_grows_with_the_hold():
    stock = CosineDecayWithWarmupSchedulerConfig(
        num_warmup_steps=20, num_decay_steps=2000, peak_lr=1e-2, decay_lr=1e-4
    )
    assert summed_multiplier(stock, 700) == pytest.approx(sum(stepped_multipliers(stock, 700)))
    assert summed_multiplier(stock, 700) == pytest.approx(350.5, abs=0.1)
    assert summed_multiplier(schedule(0.8), 700) == pytest.approx(627.7, abs=0.1)


@pytest.mark.parametrize("hold", [-0.1, 1.0, 1.5])
def test_rejects_a_hold_outside_its_range(hold: float):
    with pytest.raises(ValueError, match="scheduler_hold_fraction"):
        schedule(hold)
    with pytest.raises(ValueError, match="scheduler_hold_fraction"):
        SigmaConfig(preset="small", device="cpu", scheduler_hold_fraction=hold)


def test_the_policy_uses_it_only_with_a_hold():
    assert LRSchedulerConfig.get_choice_class(SCHEDULER_TYPE) is HoldCosineSchedulerConfig
    plain = SigmaConfig(preset="small", device="cpu").get_scheduler_preset()
    assert type(plain) is CosineDecayWithWarmupSchedulerConfig  # runs without a hold save LeRobot's own type
    held = SigmaConfig(preset="small", device="cpu", scheduler_hold_fraction=0.7).get_scheduler_preset()
    assert isinstance(held, HoldCosineSchedulerConfig) and held.hold_fraction == 0.7
    assert (held.peak_lr, held.decay_lr, held.num_warmup_steps, held.num_decay_steps) == (
        plain.peak_lr,
        plain.decay_lr,
        plain.num_warmup_steps,
        plain.num_decay_steps,
    )
