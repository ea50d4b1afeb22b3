"""RESULTS.md: benchmark fragments (command + machine + table) stitched in a fixed order, gaps and failures named."""

from __future__ import annotations

import json
import sys

import pytest

from pipelines.reporting import RESULTS_DIR, write_report
from pipelines.results import BENCHMARKS, NAMES, ResultsConfig, command_for, main, selected, stitch


def test_write_report_writes_markdown_and_json_with_command_and_machine(tmp_path):
    md = write_report("loader", "Loader", "| a | b |\n|---|---|\n| 1 | 2 |", {"x": 1.5}, "a note", tmp_path)
    assert md == tmp_path / "loader.md"
    text = md.read_text()
    lines = text.splitlines()
    assert lines[0] == "## Loader"
    assert any(line.startswith("Command: `") and line.endswith("`") for line in lines)
    machine = next(line for line in lines if line.startswith("Machine: "))
    assert " cores" in machine and "Python " in machine and "measured " in machine
    assert text.index("Command: ") < text.index("| 1 | 2 |") < text.index("a note")
    payload = json.loads((tmp_path / "loader.json").read_text())
    assert payload["name"] == "loader" and payload["data"] == {"x": 1.5}
    assert payload["command"] and payload["machine"] in machine


def test_a_rerun_keeps_the_hand_written_notes_below_the_new_table(tmp_path):
    write_report("demos", "Demos", "| old table |", {}, "generated note", tmp_path)
    md = tmp_path / "demos.md"
    md.write_text(
        md.read_text() + "\nNotes (added by hand, 2026-11-27). A **finding**.\n\nIts second paragraph.\n"
    )
    text = write_report("demos", "Demos", "| new table |", {}, "new generated note", tmp_path).read_text()
    assert "old table" not in text and "generated note" not in text.replace("new generated note", "")
    assert text.index("| new table |") < text.index("new generated note") < text.index("Notes (added by hand")
    assert text.endswith("A **finding**.\n\nIts second paragraph.\n")
    assert (
        write_report("demos", "Demos", "| t |", {}, "", tmp_path).read_text().count("Notes (added by hand")
        == 1
    )


def test_stitch_orders_sections_names_missing_and_failed_ones(tmp_path):
    # Written out of order: the report order is fixed (NAMES, below).
    write_report("policy", "Policy speed", "| policy table |", {}, results_dir=tmp_path)
    write_report("loader", "Loader", "| loader table |", {}, results_dir=tmp_path)
    write_report("experts", "Experts", "| experts table |", {}, results_dir=tmp_path)
    text = stitch(tmp_path, failures={"collect": (2, "python -m benchmarks.bench_collect --episodes 20")})

    assert text.startswith("# sigma results\n")
    header = text[: text.index("### ")]
    assert "`sigma-results`" in header and "sigma-results --stitch_only true" in header
    assert "Stitched on: " in header and " cores" in header
    assert NAMES == (
        "experts",
        "tolerance",
        "ablation",
        "compare",
        "learning",
        "demos",
        "suite",
        "collect",
        "loader",
        "renderer",
        "policy",
    )
    titles = [line for line in text.splitlines() if line.startswith("#")]
    assert titles[0] == "# sigma results" and len(titles) == 1 + len(BENCHMARKS)
    assert all(t.startswith("### ") for t in titles[1:])  # fragment '## ' titles demoted under the header
    order = [
        text.index(s) for s in ("| experts table |", "### Contrastive", "### Collection", "| loader table |")
    ]
    assert order == sorted(order) and text.index("| loader table |") < text.index("| policy table |")
    for name in ("ablation", "renderer"):  # no fragment: the section says how to produce it
        bench = next(b for b in BENCHMARKS if b.name == name)
        assert f"Not measured yet: run `{bench.command}`." in text
    collect = text[text.index("### Collection") : text.index("### Loader")]
    assert "**Failed** in the last `sigma-results` run (exit status 2)" in collect
    assert "`python -m benchmarks.bench_collect --episodes 20`" in collect and "Not measured yet" in collect


def test_selection_defaults_only_skip_and_errors(tmp_path):
    assert [b.name for b in selected(ResultsConfig())] == ["collect", "loader", "renderer", "policy"]
    assert [b.name for b in selected(ResultsConfig(include_slow=True))] == list(NAMES)
    assert [b.name for b in selected(ResultsConfig(only="policy, ablation"))] == ["ablation", "policy"]
    assert [b.name for b in selected(ResultsConfig(only="[loader]"))] == ["loader"]
    assert [b.name for b in selected(ResultsConfig(skip="collect,renderer"))] == ["loader", "policy"]
    assert selected(ResultsConfig(stitch_only=True, include_slow=True)) == []
    with pytest.raises(ValueError, match="--skip: unknown benchmark"):
        selected(ResultsConfig(skip="bogus"))
    with pytest.raises(ValueError, match="--extra_args: unknown benchmark"):
        selected(ResultsConfig(extra_args={"bogus": "--x 1"}))
    # The expert benchmark always writes to benchmarks/results: refuse to stitch from elsewhere after it.
    with pytest.raises(ValueError, match="always write to"):
        selected(ResultsConfig(only="experts", results_dir=tmp_path))


def test_command_uses_this_interpreter_extra_flags_and_results_dir(tmp_path):
    loader = next(b for b in BENCHMARKS if b.name == "loader")
    argv = command_for(loader, ResultsConfig(extra_args={"loader": "--samples 3"}, results_dir=tmp_path))
    assert argv[0] == sys.executable and argv[1:3] == ["-m", "benchmarks.bench_loader"]
    assert argv[-4:] == ["--samples", "3", "--results_dir", str(tmp_path.resolve())]
    assert "--results_dir" not in command_for(loader, ResultsConfig(results_dir=RESULTS_DIR))
    ablation = next(b for b in BENCHMARKS if b.name == "ablation")
    assert command_for(ablation, ResultsConfig())[0].endswith("sigma-ablate")


def test_sigma_results_runs_the_loader_benchmark_and_reports_a_failure(tmp_path):
    out = tmp_path / "RESULTS.md"
    common = ["--only", "loader", "--results_dir", str(tmp_path), "--output", str(out)]
    # A real (tiny) run: the benchmark writes its fragment into tmp_path and RESULTS.md includes it.
    assert main([*common, "--extra_args", '{"loader": "--samples 2"}']) == 0
    fragment = (tmp_path / "loader.md").read_text()
    assert (
        "--samples 2" in fragment and "| + current row read without the queried columns (sigma) |" in fragment
    )
    data = json.loads((tmp_path / "loader.json").read_text())["data"]
    assert data["lerobot_ms"] > 0 and data["sigma_ms"] > 0
    text = out.read_text()
    assert "| + current row read without the queried columns (sigma) |" in text and "Not measured yet" in text
    # A benchmark that exits non-zero: sigma-results returns 1 and RESULTS.md names the failure and command,
    # keeping the earlier fragment below it.
    assert main([*common, "--extra_args", '{"loader": "--no_such_flag 1"}']) == 1
    text = out.read_text()
    assert "**Failed** in the last `sigma-results` run (exit status 2)" in text and "--no_such_flag" in text
    assert "The numbers below are from an earlier run." in text and "| + grouped query" in text
