"""Warm-up, a hold at the peak, then cosine decay: the learning rate of a short run (``--policy.scheduler_hold_fraction``).

LeRobot's ``cosine_decay_with_warmup`` (``lerobot/optim/schedulers.py``) warms up linearly, then follows a cosine
from the peak down to ``decay_lr`` over ``num_decay_steps``; when the run is shorter than that it shrinks warm-up and
decay to the run. A LAMB step moves each tensor by about ``lr`` times its norm (``sigma_policy/lamb.py``), so what a
run can learn grows with the learning rate it sums, and a cosine spends half its steps below half the peak: 700 steps
sum about 350 peak-steps. On the demo's Stack the instruction's order was learned abruptly once the sum passed about
600-700 peak-steps (docs/learning.md "Padding states and Stack's order").

This schedule keeps the rate at its peak until a fraction ``h`` of the decay span, then decays with the same
cosine over the rest (the warm-up/stable/decay shape of Hu et al. 2024, https://arxiv.org/abs/2404.06395):

    W, D = warm-up and decay steps (both shrunk as LeRobot does when the run is shorter than D)
    H    = round(h * D)
    step < W:              LeRobot's linear warm-up
    W <= step < H:         1
    step >= max(W, H):     alpha + (1 - alpha) * (1 + cos(pi * min(step - H, D - H) / (D - H))) / 2
                           with alpha = decay_lr / peak_lr

At ``h = 0`` this is LeRobot's schedule step for step (its cosine also counts from step 0); the config then returns
LeRobot's own scheduler, so runs without a hold train and save exactly as before. 700 steps with ``h = 0.6`` sum
about 560 peak-steps against 350.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

from lerobot.optim.schedulers import CosineDecayWithWarmupSchedulerConfig, LRSchedulerConfig
from torch.optim import Optimizer
from torch.optim.lr_scheduler import LambdaLR

SCHEDULER_TYPE = "sigma_hold_cosine"


def check_hold_fraction(fraction: float) -> float:
    """``fraction`` if it is a valid hold (0 = LeRobot's cosine), else ValueError naming the option."""
    if not 0.0 <= fraction < 1.0:
        raise ValueError(
            f"policy.scheduler_hold_fraction must be in [0, 1) (0 = no hold; e.g. 0.6), got {fraction}"
        )
    return float(fraction)


def scaled_spans(num_warmup_steps: int, num_decay_steps: int, num_training_steps: int) -> tuple[int, int]:
    """Warm-up and decay steps as LeRobot's cosine scheduler uses them: shrunk to the run when it is shorter."""
    if num_training_steps < num_decay_steps:
        return int(num_warmup_steps * num_training_steps / num_decay_steps), num_training_steps
    return num_warmup_steps, num_decay_steps


@LRSchedulerConfig.register_subclass(SCHEDULER_TYPE)
@dataclass
class HoldCosineSchedulerConfig(CosineDecayWithWarmupSchedulerConfig):
    """LeRobot's warm-up + cosine decay with the rate held at its peak for ``hold_fraction`` of the decay span."""

    hold_fraction: float = 0.0

    def __post_init__(self):
        check_hold_fraction(self.hold_fraction)

    def multiplier(self, step: int, num_training_steps: int) -> float:
        """The factor on the peak rate at optimiser step ``step`` of a run of ``num_training_steps``."""
        warmup, decay = scaled_spans(self.num_warmup_steps, self.num_decay_steps, num_training_steps)
        if step < warmup:  # LeRobot's linear warm-up, from 1 / (W + 1) at step 0 to 1 at step W
            start = 1 / (warmup + 1)
            return start if step <= 0 else start + (1 - start) * step / warmup
        hold_end = round(self.hold_fraction * decay)
        if step < hold_end:
            return 1.0
        span = max(decay - hold_end, 1)
        alpha = self.decay_lr / self.peak_lr
        return alpha + (1 - alpha) * 0.5 * (1 + math.cos(math.pi * min(step - hold_end, span) / span))

    def build(self, optimizer: Optimizer, num_training_steps: int) -> LambdaLR:
        warmup, decay = scaled_spans(self.num_warmup_steps, self.num_decay_steps, num_training_steps)
        logging.info(
            f"sigma lr schedule: warm-up {warmup} steps, peak held to step "
            f"{round(self.hold_fraction * decay)}, cosine decay to step {decay}"
        )
        return LambdaLR(optimizer, lambda step: self.multiplier(step, num_training_steps), -1)


def summed_multiplier(config: CosineDecayWithWarmupSchedulerConfig, num_training_steps: int) -> float:
    """The run's summed learning rate in peak-steps (sum over steps of lr / peak_lr), for either scheduler."""
    if isinstance(config, HoldCosineSchedulerConfig):
        return sum(config.multiplier(s, num_training_steps) for s in range(num_training_steps))
    as_hold = HoldCosineSchedulerConfig(
        num_warmup_steps=config.num_warmup_steps,
        num_decay_steps=config.num_decay_steps,
        peak_lr=config.peak_lr,
        decay_lr=config.decay_lr,
    )
    return summed_multiplier(as_hold, num_training_steps)
