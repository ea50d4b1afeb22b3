"""The instruction-geometry benchmark: its rescalings, distances and readout, and one run on the real encoder."""

from __future__ import annotations

import torch

from benchmarks.bench_instructions import (
    InstructionsConfig,
    geometry,
    main,
    readout_misses,
    standardised,
    whitened,
)
from sigma_data.suite import TASKS


def test_standardised_centres_and_scales_each_dimension_and_leaves_a_constant_one_alone():
    x = torch.randn(4, 3, 5) * torch.tensor([1.0, 2.0, 3.0, 4.0, 0.0]) + 7.0
    rows = standardised(x).reshape(-1, 5)
    assert torch.allclose(rows[:, :4].mean(0), torch.zeros(4), atol=1e-5)
    assert torch.allclose(rows[:, :4].std(0), torch.ones(4), atol=1e-5)
    assert torch.equal(rows[:, 4], torch.zeros(12))  # centred, not divided by a zero deviation


def test_whitening_puts_the_instructions_at_the_corners_of_a_regular_simplex():
    x = torch.randn(6, 2, 9) * torch.linspace(0.1, 5.0, 9)
    d = torch.cdist(whitened(x), whitened(x))
    off = d[~torch.eye(6, dtype=torch.bool)]
    assert torch.allclose(off, off[0].expand_as(off), rtol=1e-4)


def test_geometry_averages_distances_by_kind_of_pair():
    # task a: variations v (rows 0, 1) and w (row 2); task b: row 3. Points on a line, so distances are differences.
    x = torch.tensor([[0.0], [2.0], [5.0], [10.0]])
    labels = [("a", "v"), ("a", "v"), ("a", "w"), ("b", "u")]
    g = geometry(x, labels, {"a": (0, 2)})
    assert g["within"] == 2.0 and g["between"] == 4.0  # |0-5|, |2-5|
    assert g["tasks"] == (10 + 8 + 5) / 3
    assert g["a"] == {"between_over_within": 2.0, "canonical_over_within": 2.5}


def test_readout_reads_separable_variations_and_misses_indistinguishable_ones():
    labels = [("t", "a")] * 3 + [("t", "b")] * 3
    centres = torch.tensor([[1.0, 0.0, 0.0]] * 3 + [[0.0, 1.0, 0.0]] * 3)
    noise = torch.tensor([[0, 0, 0.1], [0, 0, -0.1], [0, 0, 0.0]] * 2)
    assert readout_misses(centres + noise, labels) == []
    same = torch.tensor([[1.0, 0.0, 0.0]] * 6) + noise  # the two variations only differ by noise
    assert len(readout_misses(same, labels)) >= 2


def test_the_suites_instructions_under_the_offline_encoder(tmp_path):
    report = main(InstructionsConfig(output=tmp_path / "instructions.json"))
    raw, white = report["geometry"]["raw"], report["geometry"]["whitened"]
    registered = sum(len(v.instructions) for task in TASKS.values() for v in task.variations)
    assert report["instructions"] == registered and set(report["sentence_cosine_canonical"]) == {
        "stack",
        "pick_place",
        "nut_assembly",
    }
    assert raw["readout"] > white["readout"]  # whitening forgets which paraphrases are alike
    assert abs(white["stack"]["between_over_within"] - 1.0) < 1e-3
    assert (tmp_path / "instructions.json").exists()
