"""Contrastive IL losses: CLIP-style symmetric InfoNCE, instruction masking, learnability, and the cross-process
all-gather (two CPU processes on gloo)."""

from __future__ import annotations

import math

import torch
import torch.distributed as dist
import torch.multiprocessing as mp
import torch.nn.functional as F

from sigma_policy.contrastive import centred, contrastive_losses, instruction_ids, symmetric_info_nce


def clip_loss(a: torch.Tensor, b: torch.Tensor, scale: float) -> torch.Tensor:
    logits = scale * a @ b.t()
    labels = torch.arange(a.shape[0])
    return 0.5 * (F.cross_entropy(logits, labels) + F.cross_entropy(logits.t(), labels))


def test_single_process_equals_the_clip_loss():
    g = torch.Generator().manual_seed(0)
    a = F.normalize(torch.randn(6, 8, generator=g), dim=-1)
    b = F.normalize(torch.randn(6, 8, generator=g), dim=-1)
    got = symmetric_info_nce(a, b, torch.tensor(14.3))
    torch.testing.assert_close(got, clip_loss(a, b, 14.3))


def test_same_instruction_negatives_are_masked():
    g = torch.Generator().manual_seed(1)
    a = F.normalize(torch.randn(4, 8, generator=g), dim=-1)
    b = F.normalize(torch.randn(4, 8, generator=g), dim=-1)
    same = instruction_ids(["push the red cube"] * 4)
    # Every other row shares the instruction, so only the positive is left: the loss is exactly 0.
    assert symmetric_info_nce(a, b, torch.tensor(10.0), same).item() == 0.0
    # Two groups of two: each row competes against the two rows of the other group only.
    groups = instruction_ids(["a", "a", "b", "b"])
    masked = symmetric_info_nce(a, b, torch.tensor(10.0), groups)
    manual = []
    for i, keep in enumerate([[0, 2, 3], [1, 2, 3], [2, 0, 1], [3, 0, 1]]):
        manual.append(F.cross_entropy(10.0 * a[i : i + 1] @ b[keep].t(), torch.tensor([0])))
        manual.append(F.cross_entropy(10.0 * b[i : i + 1] @ a[keep].t(), torch.tensor([0])))
    torch.testing.assert_close(masked, torch.stack(manual).mean())


def test_loss_falls_well_below_chance_on_learnable_pairs():
    torch.manual_seed(0)
    batch, dim = 16, 32
    latent = torch.randn(256, 8)
    state_x, lang_x = latent @ torch.randn(8, dim), latent @ torch.randn(8, dim)  # paired views of one latent
    fused_x, goal_x = latent @ torch.randn(8, dim), latent @ torch.randn(8, dim)
    encoders = torch.nn.ModuleList(torch.nn.Linear(dim, 16) for _ in range(4))
    log_scale = torch.nn.Parameter(torch.tensor(math.log(1 / 0.07)))
    opt = torch.optim.Adam([*encoders.parameters(), log_scale], lr=1e-2)
    for step in range(150):
        idx = torch.randint(0, 256, (batch,))
        feats = [enc(x[idx]) for enc, x in zip(encoders, (state_x, lang_x, fused_x, goal_x), strict=True)]
        losses = contrastive_losses(*feats, logit_scale=log_scale.exp())
        if step == 0:
            assert losses.state_language.item() > 0.8 * math.log(batch)  # at or above chance at the start
        opt.zero_grad()
        losses.total.backward()
        opt.step()
    assert losses.state_language.item() < 0.25 * math.log(batch)
    assert losses.goal.item() < 0.25 * math.log(batch)


def test_centring_ignores_what_every_sample_shares():
    """With ``center`` a direction shared by the whole batch (the table every scene shows) drops out of the goal
    term: adding it changes nothing; without centring it swamps the per-sample signal and pins the loss at
    log(batch). The state-language term is never centred."""
    g = torch.Generator().manual_seed(2)
    feats = [torch.randn(8, 16, generator=g, dtype=torch.float64) for _ in range(4)]
    shared = [100.0 * torch.randn(1, 16, generator=g, dtype=torch.float64) for _ in range(4)]
    moved_feats = [f + c for f, c in zip(feats, shared, strict=True)]
    scale = torch.tensor(14.3, dtype=torch.float64)
    plain = contrastive_losses(*feats, logit_scale=scale, center=True)
    moved = contrastive_losses(*moved_feats, logit_scale=scale, center=True)
    torch.testing.assert_close(moved.goal, plain.goal)
    swamped = contrastive_losses(*moved_feats, logit_scale=scale)
    assert abs(swamped.goal.item() - math.log(8)) < 0.05
    assert abs(plain.goal.item() - math.log(8)) > 0.05
    torch.testing.assert_close(
        plain.state_language, contrastive_losses(*feats, logit_scale=scale).state_language
    )


# ---------------------------------------------------------------------------------- two processes on gloo
def _features(n: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(123)
    a = F.normalize(torch.randn(n, 8, generator=g, dtype=torch.float64), dim=-1)
    b = F.normalize(torch.randn(n, 8, generator=g, dtype=torch.float64), dim=-1)
    ids = torch.tensor([0, 1, 0, 2, 1, 3, 3])[:n]
    return a, b, ids


SIZES = (3, 4)  # unequal per-process batches


def _worker(rank: int, init_file: str, out_dir: str) -> None:
    dist.init_process_group("gloo", init_method=f"file://{init_file}", rank=rank, world_size=2)
    try:
        a, b, ids = _features(sum(SIZES))
        lo = sum(SIZES[:rank])
        sl = slice(lo, lo + SIZES[rank])
        a_loc = a[sl].clone().requires_grad_(True)
        b_loc = b[sl].clone().requires_grad_(True)
        loss = symmetric_info_nce(a_loc, b_loc, torch.tensor(5.0, dtype=torch.float64), ids[sl])
        loss.backward()
        torch.save(
            {"loss": loss.detach(), "ga": a_loc.grad, "gb": b_loc.grad, "centred": centred(a[sl]).detach()},
            f"{out_dir}/rank{rank}.pt",
        )
    finally:
        dist.destroy_process_group()


def test_all_gather_across_two_gloo_processes(tmp_path):
    mp.spawn(_worker, args=(str(tmp_path / "store"), str(tmp_path)), nprocs=2, join=True)
    a, b, ids = _features(sum(SIZES))
    for rank in range(2):
        got = torch.load(tmp_path / f"rank{rank}.pt")
        lo = sum(SIZES[:rank])
        sl = slice(lo, lo + SIZES[rank])
        # Reference in one process: full-batch negatives, gradient only through this rank's own rows.
        a_ref = a.clone()
        b_ref = b.clone()
        a_loc = a[sl].clone().requires_grad_(True)
        b_loc = b[sl].clone().requires_grad_(True)
        a_all = torch.cat([a_ref[:lo], a_loc, a_ref[lo + SIZES[rank] :]])
        b_all = torch.cat([b_ref[:lo], b_loc, b_ref[lo + SIZES[rank] :]])
        labels = torch.arange(SIZES[rank]) + lo
        mask = ids[sl][:, None] == ids[None, :]
        mask[torch.arange(SIZES[rank]), labels] = False
        l1 = F.cross_entropy((5.0 * a_loc @ b_all.t()).masked_fill(mask, -torch.inf), labels)
        l2 = F.cross_entropy((5.0 * b_loc @ a_all.t()).masked_fill(mask, -torch.inf), labels)
        ref = 0.5 * (l1 + l2)
        ref.backward()
        torch.testing.assert_close(got["loss"], ref.detach())
        torch.testing.assert_close(got["ga"], a_loc.grad)
        torch.testing.assert_close(got["gb"], b_loc.grad)
        torch.testing.assert_close(got["centred"], a[sl] - a.mean(dim=0))  # one mean: the whole batch's
