"""LAMB: the exact Σ-agent update rule, tensor-only state that LeRobot can checkpoint, config registration."""

from __future__ import annotations

import math

import pytest
import torch
from lerobot.optim.optimizers import OptimizerConfig, load_optimizer_state, save_optimizer_state

from sigma_policy.configuration_sigma import SigmaConfig
from sigma_policy.lamb import Lamb, LambConfig


def reference_lamb(w, grads, lr, b1, b2, eps, wd):
    """Scalar-loop restatement of docs/method.md §10 in float64 (no bias correction, trust clamp 10)."""
    w = [float(x) for x in w]
    m = [0.0] * len(w)
    v = [0.0] * len(w)
    for g in grads:
        r = []
        for i, gi in enumerate(g):
            m[i] = b1 * m[i] + (1 - b1) * gi
            v[i] = b2 * v[i] + (1 - b2) * gi * gi
            r.append(m[i] / (math.sqrt(v[i]) + eps) + wd * w[i])
        wn = min(math.sqrt(sum(x * x for x in w)), 10.0)
        rn = math.sqrt(sum(x * x for x in r))
        trust = wn / rn if wn > 0 and rn > 0 else 1.0
        w = [wi - lr * trust * ri for wi, ri in zip(w, r, strict=True)]
    return w


@pytest.mark.parametrize("scale", [0.0, 1.0, 50.0])  # zero weights (trust 1), normal, clamped norm (> 10)
def test_matches_the_reference_update(scale: float):
    torch.manual_seed(0)
    w0 = torch.randn(7, dtype=torch.float64) * scale
    grads = [torch.randn(7, dtype=torch.float64) for _ in range(4)]
    p = torch.nn.Parameter(w0.clone())
    opt = Lamb([p], lr=0.05, betas=(0.9, 0.999), eps=1e-6, weight_decay=0.01)
    for g in grads:
        p.grad = g.clone()
        opt.step()
    expected = reference_lamb(w0.tolist(), [g.tolist() for g in grads], 0.05, 0.9, 0.999, 1e-6, 0.01)
    torch.testing.assert_close(
        p.detach(), torch.tensor(expected, dtype=torch.float64), rtol=1e-10, atol=1e-12
    )


def test_step_size_is_layerwise_trust_ratio():
    # With weight norm 2 and any gradient, the first update has norm lr * ||w|| (trust ratio definition).
    p = torch.nn.Parameter(torch.tensor([2.0, 0.0, 0.0]))
    opt = Lamb([p], lr=0.1, weight_decay=0.0)
    p.grad = torch.tensor([1.0, -3.0, 0.5])
    opt.step()
    assert (p.detach() - torch.tensor([2.0, 0.0, 0.0])).norm().item() == pytest.approx(0.2, rel=1e-5)


def test_state_is_tensor_only_and_checkpoints_with_lerobot(tmp_path):
    model = torch.nn.Sequential(torch.nn.Linear(3, 4), torch.nn.LayerNorm(4), torch.nn.Linear(4, 2))
    opt = LambConfig(lr=1e-2).build(model.parameters())
    for _ in range(2):
        model(torch.randn(5, 3)).pow(2).sum().backward()
        opt.step()
        opt.zero_grad()
    for state in opt.state.values():
        assert all(isinstance(v, torch.Tensor) for v in state.values()), state
    save_optimizer_state(opt, tmp_path)
    fresh = LambConfig(lr=1e-2).build(model.parameters())
    fresh = load_optimizer_state(fresh, tmp_path)
    for a, b in zip(opt.state.values(), fresh.state.values(), strict=True):
        for key in a:
            torch.testing.assert_close(a[key], b[key])
    assert fresh.state[next(iter(model.parameters()))]["step"].item() == 2


def test_registered_and_used_by_the_policy_preset():
    assert OptimizerConfig.get_choice_class("lamb") is LambConfig
    cfg = SigmaConfig(preset="small", device="cpu")
    opt_cfg = cfg.get_optimizer_preset()
    assert isinstance(opt_cfg, LambConfig) and opt_cfg.lr == cfg.optimizer_lr and opt_cfg.eps == 1e-6
    sched_cfg = cfg.get_scheduler_preset()
    opt = opt_cfg.build([torch.nn.Parameter(torch.ones(2))])
    sched = sched_cfg.build(opt, num_training_steps=cfg.scheduler_decay_steps)
    lrs = []
    for _ in range(cfg.scheduler_decay_steps):
        lrs.append(opt.param_groups[0]["lr"])
        opt.step()
        sched.step()
    peak = max(lrs)
    assert lrs[0] < 0.1 * peak  # warm-up
    assert peak == pytest.approx(cfg.optimizer_lr, rel=0.01)
    assert lrs[-1] == pytest.approx(cfg.optimizer_lr / 100, rel=0.05)  # cosine decay to lr / 100


def test_rejects_bad_hyperparameters():
    with pytest.raises(ValueError, match="learning rate"):
        Lamb([torch.nn.Parameter(torch.ones(1))], lr=-1.0)


def test_foreach_update_equals_the_per_parameter_update():
    torch.manual_seed(0)
    model = torch.nn.Sequential(torch.nn.Linear(3, 4), torch.nn.LayerNorm(4), torch.nn.Linear(4, 2))
    model[2].bias.data.zero_()  # a zero-norm parameter takes trust 1 in both paths
    twin = torch.nn.Sequential(torch.nn.Linear(3, 4), torch.nn.LayerNorm(4), torch.nn.Linear(4, 2))
    twin.load_state_dict(model.state_dict())
    fast = Lamb(model.parameters(), lr=0.05, weight_decay=0.01, foreach=True)
    slow = Lamb(twin.parameters(), lr=0.05, weight_decay=0.01, foreach=False)
    for _ in range(3):
        x = torch.randn(5, 3)
        for net, opt in ((model, fast), (twin, slow)):
            net(x).pow(2).sum().backward()
            opt.step()
            opt.zero_grad()
    for a, b in zip(model.parameters(), twin.parameters(), strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)


def test_a_group_without_trust_ratio_takes_plain_steps():
    """Tensors near zero barely move under a trust ratio; the exempt group moves by ~lr per element."""
    torch.manual_seed(0)
    small = torch.nn.Parameter(torch.full((8,), 1e-4))
    exempt = torch.nn.Parameter(torch.full((8,), 1e-4))
    opt = Lamb(
        [{"params": [small]}, {"params": [exempt], "trust_ratio": False, "weight_decay": 0.0}], lr=1e-2
    )
    for _ in range(10):
        opt.zero_grad()
        (small.sum() + exempt.sum()).backward()
        opt.step()
    assert (small - 1e-4).abs().max() < 1e-4  # moved by ~lr * ||p|| per step: almost nothing
    assert (exempt - 1e-4).abs().min() > 0.05  # ten steps of ~lr each (more early: no bias correction)


def test_small_preset_exempts_biases_norms_and_query_tokens(tmp_path):
    from tests.sigma_policy.test_modeling import build
    from tests.sigma_policy.tiny_dataset import write_tiny_keyframe_dataset

    root = write_tiny_keyframe_dataset(tmp_path / "tiny", episodes=1, size=32)
    _, policy, *_ = build(root)
    groups = policy.get_optim_params()
    assert len(groups) == 2 and groups[1]["trust_ratio"] is False and groups[1]["weight_decay"] == 0.0
    assert all(p.ndim >= 2 for p in groups[0]["params"])
    shapes = {tuple(p.shape) for p in groups[1]["params"]}
    assert any(len(s) == 3 for s in shapes)  # the (1, num_queries, c) query tokens

    _, paper, *_ = build(root, preset="paper", img_size=32, patch_size=8, attn_dim=64, attn_heads=2)
    assert list(paper.get_optim_params()) == list(paper.parameters())  # the paper's LAMB: no exemption
