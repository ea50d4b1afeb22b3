"""RESULTS.md: benchmark fragments (command + machine + table) stitched in a fixed order, gaps named."""

from __future__ import annotations

import json

import pytest

from pipelines.reporting import write_report
from pipelines.results import BENCHMARKS, ResultsConfig, selected, stitch


def test_write_report_records_command_machine_and_data(tmp_path):
    md = write_report("loader", "Loader", "| a | b |\n|---|---|\n| 1 | 2 |", {"x": 1.5}, "a note", tmp_path)
    text = md.read_text()
    assert text.startswith("## Loader\n") and "Command: `" in text and "Machine: " in text
    assert "| 1 | 2 |" in text and text.rstrip().endswith("a note")
    payload = json.loads((tmp_path / "loader.json").read_text())
    assert payload["data"] == {"x": 1.5} and payload["command"] and payload["machine"]


def test_stitch_orders_fragments_and_names_missing_ones(tmp_path):
    write_report("loader", "Loader", "| loader table |", {}, results_dir=tmp_path)
    write_report("experts", "Experts", "| experts table |", {}, results_dir=tmp_path)
    text = stitch(tmp_path, failures={"collect": 2})
    assert text.startswith("# sigma results") and "sigma-results --stitch_only true" in text
    # Fixed order: experts before loader, whatever order the files were written in.
    assert text.index("| experts table |") < text.index("| loader table |")
    assert "### Experts" in text and "## Experts" not in text.replace("### Experts", "")
    # A missing fragment says how to produce it; a failed run says so with its command.
    ablation = next(b for b in BENCHMARKS if b.name == "ablation")
    assert f"Not measured yet: run `{ablation.command}`" in text
    assert "**Failed** (exit status 2)" in text


def test_selection_skips_slow_and_gpu_benchmarks_by_default():
    names = [b.name for b in selected(ResultsConfig(), cuda=False)]
    assert "loader" in names and "collect" in names
    assert not {"experts", "ablation", "policy_paper_cuda", "renderer"} & set(names)
    assert [b.name for b in selected(ResultsConfig(only=["ablation"]), cuda=False)] == ["ablation"]
    assert selected(ResultsConfig(stitch_only=True), cuda=True) == []
    everything = {b.name for b in selected(ResultsConfig(include_slow=True), cuda=True)}
    assert everything == {b.name for b in BENCHMARKS}
    with pytest.raises(ValueError, match="unknown benchmark"):
        selected(ResultsConfig(skip=["bogus"]), cuda=False)
