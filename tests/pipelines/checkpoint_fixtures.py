"""A tiny untrained sigma checkpoint on a tiny keyframe dataset, for the pipelines that read checkpoints."""

from __future__ import annotations

import json

import torch
from lerobot.policies.factory import make_policy, make_pre_post_processors

from pipelines.keyframe_sets import open_dataset
from sigma_policy.configuration_sigma import SigmaConfig
from tests.sigma_policy.tiny_dataset import BOUNDS


def save_tiny_checkpoint(root, out, train_episodes, seed):
    """An untrained small sigma policy for the tiny dataset at ``root``, saved to ``out`` as a ``pretrained_model``
    with a ``train_config.json`` naming ``root`` and the ``train_episodes``."""
    torch.manual_seed(seed)
    cfg = SigmaConfig(
        device="cpu",
        scene_bounds=list(BOUNDS),
        preset="small",
        img_size=32,
        patch_size=8,
        attn_dim=64,
        attn_heads=2,
    )
    ds = open_dataset(root)
    policy = make_policy(cfg, ds_meta=ds.meta)
    pre, post = make_pre_post_processors(cfg, dataset_stats=ds.meta.stats)
    out.mkdir(parents=True)
    for obj in (policy, pre, post):
        obj.save_pretrained(out)
    (out / "train_config.json").write_text(
        json.dumps({"dataset": {"root": str(root), "episodes": train_episodes}})
    )
    return policy
