"""``scripts/fault_injection.py`` (issue #19): a collection killed at a random point, rerun, equals a clean run.

The default suite runs the script end to end on the smallest collection (one Lift episode, one worker, keyframe
dataset only, one kill point), then checks that a rerun of the script reuses what it recorded and that its
comparison is not blind (a changed value, a truncated file, a leftover temporary file and a damaged shard are all
caught). The slow test runs two kill points with a helper process, killing the whole group and then only the
parent.
"""

from __future__ import annotations

import json
import os
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import draccus
import pyarrow.parquet as pq
import pytest

from tests.scripts.script_module import load_script

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "scripts" / "fault_injection.py"
SMALLEST = ["--episodes=1", "--workers=1", "--dense=false", "--size=32", "--cameras=agentview"]


fi = load_script("fault_injection")


def _run(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "HF_HUB_OFFLINE": "1"}
    return subprocess.run(
        [sys.executable, str(SCRIPT), *args], capture_output=True, text=True, cwd=ROOT, env=env, timeout=600
    )


@pytest.fixture(scope="module")
def one_kill(tmp_path_factory):
    out = tmp_path_factory.mktemp("fault_injection")
    args = ["--kills=1", "--seed=1", f"--output_dir={out}", "--keep=true", *SMALLEST]
    return out, args, _run(*args)


def test_one_kill_point_reruns_equal_to_the_clean_run(one_kill):
    out, _, proc = one_kill
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    lines = proc.stdout.splitlines()
    assert any(line.startswith("kill  1/1 at ") and "equal to the clean run" in line for line in lines)
    assert lines[-1].startswith("1/1 kill points: rerun equal to the clean run")
    results = json.loads((out / "results.json").read_text())
    (point,) = results["points"]
    assert point["problems"] == [] and point["target"] == "group"
    assert point["comparison"]["identical"] > 0
    assert not list(out.rglob(".*.tmp"))  # nothing left half-written


def test_a_rerun_of_the_script_reuses_what_it_recorded(one_kill):
    out, args, first = one_kill
    assert first.returncode == 0
    proc = _run(*args)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "clean run: recorded" in proc.stdout and "[recorded]" in proc.stdout
    # Other collection options: the recorded clean run is not theirs, so it is not reused.
    cfg = draccus.parse(config_class=fi.FaultInjectionConfig, args=[*args, "--episodes=2"])
    assert cfg.collection() != json.loads((out / "clean.json").read_text())["collection"]


def _first_data_parquet(root: Path) -> Path:
    return sorted((root / "keyframe" / "data").rglob("*.parquet"))[0]


def test_the_comparison_catches_damage(one_kill, tmp_path):
    out, args, first = one_kill
    assert first.returncode == 0
    clean, run = out / "clean", out / "kill-00" / "run"
    assert fi.compare_trees(clean, run).problems == []
    cfg = draccus.parse(config_class=fi.FaultInjectionConfig, args=args)

    # A changed value in the merged keyframe data (written back with the same schema and metadata).
    changed = tmp_path / "changed"
    shutil.copytree(run, changed)
    path = _first_data_parquet(changed)
    table = pq.read_table(path)
    column = table.column("frame_index").to_pylist()
    column[-1] += 1
    pq.write_table(
        table.set_column(table.schema.get_field_index("frame_index"), "frame_index", [column]), path
    )
    assert any("differs from the clean run" in p for p in fi.compare_trees(clean, changed).problems)

    # A truncated file, a leftover temporary record, a missing file.
    damaged = tmp_path / "damaged"
    shutil.copytree(run, damaged)
    path = _first_data_parquet(damaged)
    path.write_bytes(path.read_bytes()[:-100])
    (damaged / ".collect.json.tmp").write_text("{")
    (damaged / "keyframe" / "meta" / "info.json").unlink()
    problems = " | ".join(fi.compare_trees(clean, damaged).problems)
    assert "differs from the clean run" in problems
    assert "not in the clean run: .collect.json.tmp" in problems
    assert "missing from" in problems and "keyframe/meta/info.json" in problems

    # A shard whose parquet was cut short does not verify: a rerun must redo it, and the script says why.
    shard = sorted((damaged / "shards").iterdir())[0]
    path = _first_data_parquet(shard)
    path.write_bytes(path.read_bytes()[:-100])
    states = fi.shard_states(cfg, damaged)
    assert states[shard.name] and "bytes" in states[shard.name]


def test_the_readme_command_parses():
    """The README prints the script's command; it parses with the script's own config (tests/test_readme_commands.py
    parses only the installed commands)."""
    readme = (ROOT / "README.md").read_text()
    commands = [
        line.strip().split("scripts/fault_injection.py", 1)[1]
        for line in readme.replace("`", "\n").splitlines()
        if "scripts/fault_injection.py" in line and "python" in line
    ]
    assert commands, "README.md prints no scripts/fault_injection.py command"
    for rest in commands:
        cfg = draccus.parse(config_class=fi.FaultInjectionConfig, args=shlex.split(rest))
        assert cfg.kills >= 20


@pytest.mark.slow
def test_a_helper_ends_with_its_killed_parent(tmp_path):
    """Two kill points with a helper process: the whole group killed, then only the parent (its helper must end
    by itself, within 15 s); both reruns equal the clean run."""
    args = [
        "--kills=2",
        "--seed=2",
        "--target=alternate",
        f"--output_dir={tmp_path}",
        "--episodes=2",
        "--workers=2",
    ]
    proc = _run(*args, "--dense=false")
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    points = json.loads((tmp_path / "results.json").read_text())["points"]
    assert [p["target"] for p in points] == ["group", "parent"]
    assert all(p["problems"] == [] for p in points)
