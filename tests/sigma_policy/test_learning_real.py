"""(slow) The small recipe learns real robosuite keyframes: collected by the scripted experts, read by stock LeRobot,
scored by ``sigma-diagnose`` on training and held-out episodes. And rotation is learnable under yaw augmentation."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from pipelines.diagnostics import diagnose_checkpoint
from pipelines.keyframe_sets import KeyframeSet, goal_rows, open_dataset
from sigma_data.suite import scene_bounds
from sigma_policy.observation import batch_tasks
from tests.sigma_policy.test_modeling import build, sample_indices, train, training_batch
from tests.sigma_policy.tiny_dataset import write_tiny_keyframe_dataset

CAMERAS = "agentview,frontview,birdview,robot0_eye_in_hand"


def _collect_lift(out, episodes: int, start_seed: int):
    from sigma_data.cameras import RenderOptions
    from sigma_data.collect import CollectConfig, CollectOutputConfig, collect

    summary = collect(
        CollectConfig(
            tasks="lift",
            episodes=episodes,
            start_seed=start_seed,
            output=CollectOutputConfig(dir=out, repo_id=f"local/{out.name}", dense=False),
            render=RenderOptions(cameras=CAMERAS, height=64, width=64),
            workers=1,
            progress=False,
        )
    )
    return summary.outputs["keyframe"]


@pytest.mark.slow
def test_small_recipe_fits_real_robosuite_keyframes_and_generalises(tmp_path):
    """12 Lift demonstrations, 300 steps at batch 8 (~3 min on 2 cores): training and held-out keyframes within
    about a centimetre, every gripper command right, and the close-then-lift step (which the old recipe got 14 cm
    wrong by repeating the grasp) learned."""
    train_root = _collect_lift(tmp_path / "train", episodes=12, start_seed=0)
    held_root = _collect_lift(tmp_path / "held", episodes=6, start_seed=70_000)
    _, policy, pre, _, ds = build(
        train_root, preset="small", img_size=64, patch_size=8, attn_dim=128, attn_heads=4, **_box()
    )
    train(policy, pre, ds, sample_indices(ds), steps=300)

    sets = []
    for name, root in (("train", train_root), ("heldout", held_root)):
        data = open_dataset(root)
        rows, steps = goal_rows(data)
        sets.append(KeyframeSet(name, data, rows, np.asarray(steps)))
    report = diagnose_checkpoint(policy, pre, sets)
    for name in ("train", "heldout"):
        summary = report[name]["all"]
        assert summary["trans_cm_median"] < 1.5, (name, summary)
        assert summary["gripper_acc"] >= 0.95, (name, summary)
        lift_step = report[name]["per_step"]["3"]  # at the grasp, gripper closed -> the lift pose, 15 cm up
        assert lift_step["trans_cm_median"] < 3.0, (name, lift_step)


# Training steps of the rotation test: at 400, 48% (local features) and 31% (none) of draws were within 10°.
ROTATION_STEPS = 800
# Its bar: at 800 steps the draw without local features scored above 60% on an AVX512 CPU and 59.4% (38 of 64) on an
# AVX2 one, in either convolution layout (docs/learning.md): where a draw lands around 60% is the CPU's float
# kernels. 50% is still more than 5 standard errors above a constant guess's 22%.
ROTATION_BAR = 0.5


def _box() -> dict:
    return {"scene_bounds": list(scene_bounds(["lift"]))}


@pytest.mark.slow
@pytest.mark.parametrize("local_channels", [0, 16])
def test_rotation_is_learnable_under_yaw_augmentation(tmp_path, local_channels):
    """With ±45° yaw augmentation every training sample shows the scene turned about its target and a target yaw
    turned with it; the rotation head must read the turn from the rendered views (no proprio token: the gripper's
    own orientation would give the answer away). After training, on fresh augmentation draws, the predicted yaw bin
    is within 10° of the augmented target far more often than chance (a constant guess is within 10° of a uniform
    ±45° yaw about 22% of the time). The heads' local features (``local_channels``), pooled at the predicted
    position, see the cube's outline and learn it faster; the token features alone (``local_channels=0``) get
    there too within this budget (docs/learning.md)."""
    from sigma_policy.augmentation import se3_augment
    from sigma_policy.rotation import gimbal_fixed_euler

    root = write_tiny_keyframe_dataset(tmp_path / "tiny", episodes=4, size=64)
    _, policy, pre, _, ds = build(
        root,
        preset="small",
        img_size=64,
        attn_dim=128,
        attn_heads=4,
        image_noise=0.0,
        aug_translation_range=0.0,
        aug_yaw_range_deg=45.0,
        use_contrastive=False,
        use_proprio=False,
        local_channels=local_channels,
    )
    idx = sample_indices(ds)
    train(policy, pre, ds, idx, steps=ROTATION_STEPS)

    gen = torch.Generator().manual_seed(123)
    hits, total = 0, 0
    with torch.no_grad():
        for _ in range(8):
            batch = pre(training_batch(ds, idx))
            cloud = policy._cloud(batch, t=0)
            action = batch["action"].float()
            points, _, quat, _ = se3_augment(
                cloud.points, action[:, :3], action[:, 3:7], policy.scene_bounds, 0.0, 45.0, generator=gen
            )
            views = policy._render(points, cloud.colors, policy.scene_bounds)
            out = policy._run_network(
                views, batch_tasks(batch, len(idx)), batch, policy.scene_bounds.expand(len(idx), 6)
            )
            res = 360 / policy.config.num_rotation_bins
            pred_yaw = out.rot_logits[:, 2].argmax(-1).double() * res - 180
            true_yaw = gimbal_fixed_euler(quat)[:, 2]
            diff = (pred_yaw - true_yaw + 180) % 360 - 180
            hits += int((diff.abs() <= 10).sum())
            total += len(idx)
    rate = hits / total
    assert rate > ROTATION_BAR, rate
    assert not math.isnan(rate)
