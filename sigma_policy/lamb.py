"""LAMB as used by Σ-agent / RVT (docs/method.md §10), and its LeRobot ``OptimizerConfig`` (``--optimizer.type=lamb``).

Per parameter p with gradient g (no bias correction):

    m <- beta1 m + (1 - beta1) g
    v <- beta2 v + (1 - beta2) g^2
    r  = m / (sqrt(v) + eps) + weight_decay * p
    trust = clamp(||p||, 0, 10) / ||r||     (1 if either norm is 0)
    p <- p - lr * trust * r

A parameter group with ``trust_ratio=False`` skips the trust ratio (``trust = 1``: a plain Adam step of size lr
without bias correction). sigma puts biases, norm gains/offsets, the logit scale and the zero-initialised query
tokens in such a group (``SigmaConfig.optimizer_exempt_small``): a trust ratio scales a tensor's step by its own
norm, so a tensor that starts at zero (or near it) can hardly leave it in a short run; exempting them is common LAMB
practice (You et al., 2019, exclude biases and LayerNorm from weight decay and adaptation). The group's
``weight_decay`` applies as given (sigma sets it to 0 there). All state values are tensors (``step`` included) so
that LeRobot's safetensors checkpointing can save them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
from lerobot.optim.optimizers import OptimizerConfig, OptimizerParams

TRUST_CLAMP = 10.0


class Lamb(torch.optim.Optimizer):
    """Layer-wise adaptive moments (You et al., 2019) without bias correction, trust-ratio clamp 10."""

    def __init__(
        self,
        params: OptimizerParams,
        lr: float = 1e-3,
        betas: tuple[float, float] = (0.9, 0.999),
        eps: float = 1e-6,
        weight_decay: float = 0.0,
        foreach: bool = True,
    ):
        if lr < 0.0:
            raise ValueError(f"Lamb: invalid learning rate {lr}")
        if not (0.0 <= betas[0] < 1.0 and 0.0 <= betas[1] < 1.0):
            raise ValueError(f"Lamb: invalid betas {betas}")
        if eps <= 0.0 or weight_decay < 0.0:
            raise ValueError(f"Lamb: invalid eps {eps} or weight_decay {weight_decay}")
        defaults = {
            "lr": lr,
            "betas": tuple(betas),
            "eps": eps,
            "weight_decay": weight_decay,
            "trust_ratio": True,
        }
        super().__init__(params, defaults)
        self.foreach = foreach

    @torch.no_grad()
    def step(self, closure: Callable[[], float] | None = None) -> float | None:
        loss = None
        if closure is not None:
            with torch.enable_grad():
                loss = closure()
        for group in self.param_groups:
            params = [p for p in group["params"] if p.grad is not None]
            for p in params:
                if p.grad.is_sparse:
                    raise RuntimeError("Lamb does not support sparse gradients")
                state = self.state[p]
                if not state:
                    state["step"] = torch.zeros((), dtype=torch.float32)
                    state["exp_avg"] = torch.zeros_like(p, memory_format=torch.preserve_format)
                    state["exp_avg_sq"] = torch.zeros_like(p, memory_format=torch.preserve_format)
                state["step"] += 1
            if not params:
                continue
            if self.foreach:
                # One kernel per operation for all parameters of a device and dtype, instead of ~14 per parameter:
                # the step of the 38 M-parameter paper network is launch-bound otherwise.
                groups: dict[tuple[torch.device, torch.dtype], list[torch.Tensor]] = {}
                for p in params:
                    groups.setdefault((p.device, p.dtype), []).append(p)
                for same in groups.values():
                    self._update_foreach(same, group)
            else:
                for p in params:
                    self._update_foreach([p], group)
        return loss

    def _update_foreach(self, params: list[torch.Tensor], group: dict) -> None:
        beta1, beta2 = group["betas"]
        grads = [p.grad for p in params]
        exp_avg = [self.state[p]["exp_avg"] for p in params]
        exp_avg_sq = [self.state[p]["exp_avg_sq"] for p in params]
        torch._foreach_mul_(exp_avg, beta1)
        torch._foreach_add_(exp_avg, grads, alpha=1 - beta1)
        torch._foreach_mul_(exp_avg_sq, beta2)
        torch._foreach_addcmul_(exp_avg_sq, grads, grads, value=1 - beta2)

        denom = torch._foreach_sqrt(exp_avg_sq)
        torch._foreach_add_(denom, group["eps"])
        update = torch._foreach_div(exp_avg, denom)
        if group["weight_decay"] != 0:
            torch._foreach_add_(update, params, alpha=group["weight_decay"])

        if group.get("trust_ratio", True):  # absent in groups saved before the flag existed
            weight_norm = torch.stack(torch._foreach_norm(params)).clamp(0, TRUST_CLAMP)
            update_norm = torch.stack(torch._foreach_norm(update))
            trust = torch.where(
                (weight_norm > 0) & (update_norm > 0), weight_norm / update_norm, torch.ones_like(weight_norm)
            )
        else:
            trust = torch.ones(len(params), device=params[0].device, dtype=params[0].dtype)
        for p, u, scale in zip(params, update, (trust * -group["lr"]).unbind(), strict=True):
            p.addcmul_(u, scale.to(p.dtype))  # one launch per parameter, no host sync


@OptimizerConfig.register_subclass("lamb")
@dataclass
class LambConfig(OptimizerConfig):
    """``--optimizer.type=lamb``; defaults are Σ-agent's (betas 0.9/0.999, eps 1e-6, weight decay 1e-6)."""

    lr: float = 9.6e-4
    betas: tuple[float, float] = (0.9, 0.999)
    eps: float = 1e-6
    weight_decay: float = 1e-6
    grad_clip_norm: float = 0.0

    def build(self, params: OptimizerParams) -> Lamb:
        return Lamb(params, lr=self.lr, betas=self.betas, eps=self.eps, weight_decay=self.weight_decay)
