"""An exponential moving average of the network's weights (Polyak averaging), the weights a policy acts with.

After every optimiser step the average moves ``1 - decay`` of the way towards the trained weights
(``torch.optim.swa_utils.AveragedModel`` with ``get_ema_multi_avg_fn``); the first step copies them. An average over
the last ~``1 / (1 - decay)`` steps smooths the step-to-step noise of small-batch training, which a decaying learning
rate only shrinks (Polyak & Juditsky 1992, https://doi.org/10.1137/0330046; Izmailov et al. 2018,
https://arxiv.org/abs/1803.05407). ``SigmaPolicy`` (``--policy.ema_decay``, docs/method.md §10.1) updates it from
LeRobot's per-step ``policy.update()`` hook, saves it with the weights (so a resumed run continues it), and acts with
it outside training unless ``act_with_ema`` is off.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.optim.swa_utils import AveragedModel, get_ema_multi_avg_fn


def check_ema_decay(decay: float) -> float:
    """``decay`` if it is a valid moving-average decay (0 = off), else ValueError naming the option."""
    if not 0.0 <= decay < 1.0:
        raise ValueError(f"policy.ema_decay must be in [0, 1) (0 = off; e.g. 0.998), got {decay}")
    return float(decay)


class WeightAverage(nn.Module):
    """The moving average of ``network``'s parameters, in a copy of ``network`` that is never trained.

    Its state (``average.module.*`` and the step count ``average.n_averaged``) is part of the owner's
    ``state_dict``; the copy's parameters do not require gradients, so no optimiser may train them.
    """

    def __init__(self, network: nn.Module, decay: float):
        super().__init__()
        # The network's buffers (its upsampling matrices) are constants of the architecture: copied, not averaged.
        self.average = AveragedModel(
            network, multi_avg_fn=get_ema_multi_avg_fn(check_ema_decay(decay)), use_buffers=False
        )
        self.average.requires_grad_(False)

    @property
    def network(self) -> nn.Module:
        """The averaged copy, to run like the trained network."""
        return self.average.module

    @property
    def steps(self) -> int:
        """Optimiser steps averaged so far."""
        return int(self.average.n_averaged)

    @torch.no_grad()
    def update(self, network: nn.Module) -> None:
        """Move the average towards ``network``'s current weights (the first call copies them)."""
        self.average.update_parameters(network)
