"""``sigma_policy.compat``: options sigma removed are dropped from a saved config that left them off and refused,
naming the file, the field and the docs section, where it did not. (Checkpoints saved before a module existed:
tests/sigma_policy/test_modeling.py, the ``saved_before``/``saved_without`` tests.)"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import pytest

from sigma_policy.compat import RETIRED, RetiredOptionError, drop_retired
from sigma_policy.configuration_sigma import SigmaConfig

ROOT = Path(__file__).resolve().parents[2]


def test_no_retired_option_is_still_an_option():
    assert not set(RETIRED) & {f.name for f in dataclasses.fields(SigmaConfig)}


def test_every_retired_option_names_a_section_of_the_learning_docs():
    headings = re.findall(
        r"^#+ (.+?)(?: \(\d{4}-\d\d-\d\d.*\))?$", (ROOT / "docs/learning.md").read_text(), re.M
    )
    for name, option in RETIRED.items():
        assert option.section in headings, (name, option.section)


def test_off_values_are_dropped_and_anything_else_is_refused_by_name():
    saved = {
        "preset": "suite",
        "stem_layers": 0,
        "hand_mask_box": None,
        "hand_mask_views": "all",
        "hand_marker": False,
        "hand_site_noise_m": 0.0,
        "zoom_box_m": 0,
        "zoom_share": 0.5,
        "zoom_jitter_m": 0.05,
        "zoom_at_inference": True,
        "lang_zero_padding": False,
        "decoder_lang_film": False,
    }
    assert drop_retired(saved, "ckpt/config.json") == {"preset": "suite"}
    for name, value in (
        ("zoom_box_m", 0.5),
        ("hand_marker", True),
        ("stem_layers", 2),
        ("hand_mask_box", [0] * 6),
    ):
        with pytest.raises(
            RetiredOptionError, match=rf"ckpt/config\.json: policy\.{name}=.*docs/learning\.md"
        ) as e:
            drop_retired(saved | {name: value}, "ckpt/config.json")
        assert RETIRED[name].section in str(e.value)
        assert str(e.value).endswith("sigma at commit 6ce2291 can")
    # an option removed later names the last commit that has it
    with pytest.raises(RetiredOptionError, match=r"decoder_lang_film=True .* sigma at commit 1c398d5 can$"):
        drop_retired(saved | {"decoder_lang_film": True}, "ckpt/config.json")
    # an option that acted only through another retired one is dropped at any value
    assert drop_retired({"zoom_share": 0.9, "hand_mask_views": "top"}, "x") == {}
