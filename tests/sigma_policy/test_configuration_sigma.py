"""The policy config: its presets, how they fill and validate fields, and the presets table of docs/method.md §12,
which prints ``PRESETS`` (sigma_policy/configuration_sigma.py) field by field and must not drift from it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from sigma_policy.configuration_sigma import PRESETS, SigmaConfig

METHOD_MD = Path(__file__).resolve().parents[2] / "docs" / "method.md"


def _cell(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    return f"{value:g}" if isinstance(value, float) else str(value)


def presets_table() -> str:
    """``PRESETS`` as the markdown table of docs/method.md §12: a row per field, a column per preset."""
    names = list(PRESETS)
    fields = list(dict.fromkeys(key for preset in PRESETS.values() for key in preset))
    rows = ["| field | " + " | ".join(f"`{n}`" for n in names) + " |", "|---" * (len(names) + 1) + "|"]
    rows += [f"| `{f}` | " + " | ".join(_cell(PRESETS[n][f]) for n in names) + " |" for f in fields]
    return "\n".join(rows)


def test_method_md_prints_the_presets_as_they_are():
    table = presets_table()
    assert table in METHOD_MD.read_text(), (
        f"docs/method.md §12 no longer matches PRESETS; its table is now:\n{table}"
    )


def test_every_preset_sets_the_same_fields_and_each_is_a_config_field():
    fields = {f for preset in PRESETS.values() for f in preset}
    for name, preset in PRESETS.items():
        assert set(preset) == fields, f"preset {name!r} leaves {sorted(fields - set(preset))} to chance"
    assert fields <= set(SigmaConfig.__dataclass_fields__)


def test_config_presets_and_overrides():
    small = SigmaConfig(preset="small", device="cpu")
    assert (small.img_size, small.attn_dim, small.decoder_kernel) == (64, 128, 3)
    paper = SigmaConfig(device="cpu")
    assert (paper.img_size, paper.patch_size, paper.attn_dim, paper.num_fusion_layers) == (220, 11, 512, 4)
    assert SigmaConfig(preset="small", img_size=48, device="cpu").img_size == 48
    assert paper.push_to_hub is False and paper.drop_n_last_frames == 1
    assert paper.observation_delta_indices == [0, 1]
    assert SigmaConfig(use_contrastive=False, device="cpu").observation_delta_indices == [0]
    with pytest.raises(ValueError, match="preset"):
        SigmaConfig(preset="huge", device="cpu")
    with pytest.raises(ValueError, match="scene_bounds"):
        SigmaConfig(scene_bounds=[0, 0, 0, 1, -1, 1], device="cpu")
    with pytest.raises(ValueError, match="multiple of patch_size"):
        SigmaConfig(preset="small", img_size=60, device="cpu")
    # The CPU recipe (RESULTS.md "Learning") vs the paper's; explicit fields still win over the preset.
    recipe = ("optimizer_lr", "optimizer_exempt_small", "aug_translation_range", "aug_yaw_range_deg")
    assert tuple(getattr(small, f) for f in recipe) == (1e-2, True, 0.0, 45.0)
    assert tuple(getattr(paper, f) for f in recipe) == (9.6e-4, False, 0.125, 45.0)
    assert SigmaConfig(preset="small", aug_yaw_range_deg=15, device="cpu").aug_yaw_range_deg == 15
    # The suite preset: small's network with per-task boxes, the yaw scan and the gentler schedule.
    suite = SigmaConfig(preset="suite", device="cpu")
    multi = (
        "per_task_bounds",
        "yaw_scan_px",
        "optimizer_lr",
        "scheduler_decay_steps",
        "img_size",
        "attn_dim",
    )
    assert tuple(getattr(suite, f) for f in multi) == (True, 24, 3e-3, 7500, 64, 128)
    # The gpu preset: the suite recipe with a wider network over a 3000-step decay (7.6 M parameters, 4.7x).
    gpu = SigmaConfig(preset="gpu", device="cpu")
    assert tuple(getattr(gpu, f) for f in multi) == (True, 24, 3e-3, 3000, 64, 256)
    assert (gpu.im_channels, gpu.final_dim, gpu.attn_heads, gpu.attn_dim_head, gpu.num_fusion_layers) == (
        32,
        32,
        8,
        32,
        4,
    )
    assert (
        tuple(getattr(small, f) for f in multi[:2])
        == (False, 0)
        == tuple(getattr(paper, f) for f in multi[:2])
    )
    assert (small.network_config().head_activation, paper.network_config().head_activation) == (
        "leaky_relu",
        "relu",
    )
    assert (small.lang_film, small.heatmap_refine_px, paper.lang_film, paper.heatmap_refine_px) == (
        True,
        2,
        False,
        0,
    )
    assert small.network_config().lang_film and not paper.network_config().lang_film
    assert small.network_config().proprio_film and not paper.network_config().proprio_film
    suite = SigmaConfig(preset="suite", device="cpu")
    assert not suite.network_config().proprio_film  # measured with `small` only


def test_a_saved_checkpoint_acts_with_its_own_heatmap_fusion_or_else_its_presets(tmp_path):
    """Configs saved before ``heatmap_fusion`` existed take their preset's (docs/method.md §14.6); saved ones keep
    theirs, so an evaluation log or a diagnosis of them is not mistaken for the other fusion's."""
    assert (
        SigmaConfig(device="cpu").heatmap_fusion,
        SigmaConfig(preset="suite", device="cpu").heatmap_fusion,
    ) == (
        "sum",
        "product",
    )
    for saved, acting in (
        ({"preset": "suite"}, "product"),
        ({"preset": "paper"}, "sum"),
        ({"preset": "small", "heatmap_fusion": "sum"}, "sum"),
        ({"preset": "paper", "heatmap_fusion": "product"}, "product"),
    ):
        (tmp_path / "config.json").write_text(json.dumps({"type": "sigma", "device": "cpu", **saved}))
        assert SigmaConfig.from_pretrained(tmp_path).heatmap_fusion == acting, saved
    (tmp_path / "config.json").write_text(json.dumps({"type": "sigma", "device": "cpu", "preset": "huge"}))
    with pytest.raises(ValueError, match=r"config\.json: policy\.preset must be one of .* got 'huge'"):
        SigmaConfig.from_pretrained(tmp_path)


def test_the_instruction_contrast_is_small_s_and_a_config_saved_before_it_reads_it_off(tmp_path):
    """``lang_task_contrast`` is on in ``small`` only (measured on the demo's two tasks); a config saved before the
    option existed was trained without it and adds no weights to tell so, so it reads off, not as its preset."""
    on = {
        p: SigmaConfig(preset=p, device="cpu").lang_task_contrast for p in ("paper", "small", "suite", "gpu")
    }
    assert on == {"paper": False, "small": True, "suite": False, "gpu": False}
    for saved, acting in (
        ({"preset": "small"}, False),
        ({"preset": "small", "lang_task_contrast": True}, True),
        ({"preset": "suite", "lang_task_contrast": True}, True),
    ):
        (tmp_path / "config.json").write_text(json.dumps({"type": "sigma", "device": "cpu", **saved}))
        assert SigmaConfig.from_pretrained(tmp_path).lang_task_contrast is acting, saved


@pytest.mark.parametrize(
    ("views", "message"),
    [
        (["top", "front"], "policy.virtual_views: .* needs 'left' or 'right'"),
        (["front", "left", "right"], "policy.virtual_views: .* lacks 'top'"),
        (["top", "front", "lft"], "policy.virtual_views: unknown view"),
    ],
)
def test_virtual_views_are_checked(views, message):
    with pytest.raises(ValueError, match=message):
        SigmaConfig(device="cpu", virtual_views=views)
    assert SigmaConfig(device="cpu", virtual_views=["top", "right", "back"]).network_config().views == (
        0,
        2,
        4,
    )
    assert SigmaConfig(device="cpu").network_config().num_views == 5
