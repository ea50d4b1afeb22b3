"""A killed ``sigma-data collect`` leaves nothing running: its spawned helpers (or DataTrove's pool workers) exit
with it, and the shard a helper was writing is not trusted by the next run."""

from __future__ import annotations

import importlib.util
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

from sigma_data.cameras import RenderOptions
from sigma_data.collect import (
    MARKER,
    RECORD,
    CollectConfig,
    CollectOutputConfig,
    ShardSpec,
    check_shard,
    claim_output_dir,
)


def _running(p: psutil.Process) -> bool:
    try:
        return p.status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


@pytest.mark.parametrize(
    "executor",
    [
        "processes",
        pytest.param(
            "datatrove",
            marks=pytest.mark.skipif(
                importlib.util.find_spec("datatrove") is None, reason="optional datatrove"
            ),
        ),
    ],
)
def test_killing_the_parent_ends_its_helpers(tmp_path, executor):
    out = tmp_path / "run"
    script = Path(sys.executable).with_name("sigma-data")
    cmd = [str(script)] if script.exists() else [sys.executable, "-m", "sigma_data.cli"]
    cfg = CollectConfig(
        tasks="lift",
        episodes=4,
        shard_size=1,
        render=RenderOptions(cameras="agentview", height=32, width=32),
        output=CollectOutputConfig(dir=out),
    )
    args = ["collect", "--tasks=lift", "--episodes=4", "--shard_size=1", "--render.cameras=agentview",
            "--render.height=32", "--render.width=32", "--workers=2", f"--output.dir={out}",
            "--progress=false", f"--executor={executor}"]  # fmt: skip
    # The helper takes shards from the front (this process from the back), DataTrove's rank 0 the first shard:
    # once the first shard's directory exists, a child process is writing it.
    helper_shard = out / "shards" / ShardSpec("lift", "lift_cube", (0,)).name
    log = tmp_path / "collect.log"
    with log.open("w") as sink:
        proc = subprocess.Popen(cmd + args, stdout=sink, stderr=subprocess.STDOUT)
    children: list[psutil.Process] = []
    try:
        deadline = time.monotonic() + 300
        while not helper_shard.exists():
            assert proc.poll() is None, f"collect exited ({proc.returncode}): {log.read_text()[-2000:]}"
            assert time.monotonic() < deadline, "the helper never started a shard"
            time.sleep(0.1)
        children = psutil.Process(proc.pid).children(recursive=True)
        assert children, "no helper process"
        proc.send_signal(signal.SIGKILL)  # the parent only
        proc.wait()
        _, alive = psutil.wait_procs(children, timeout=10)
        alive = [p for p in alive if _running(p)]  # a dead child nobody reaped (no init here) is a zombie
        assert not alive, f"processes outlived their parent: {[(p.pid, p.name()) for p in alive]}"
    finally:
        if proc.poll() is None:
            proc.kill()
        for child in children:
            if child.is_running():
                child.kill()
    # The helper died mid-shard: no marker, so the next run redoes that shard rather than trusting it.
    assert not (helper_shard / MARKER).exists()
    result, why = check_shard(helper_shard, cfg)
    assert result is None and "interrupted" in why


# A child that claims ``out`` for ``tiny`` options and is SIGKILLed halfway through writing collect.json (the kill
# lands inside the write: the file open, half its text written).
_KILLED_MID_RECORD = """
import os, signal, sys
from pathlib import Path
import sigma_data.collect.planning as planning
from sigma_data.cameras import RenderOptions
from sigma_data.collect import CollectConfig, CollectOutputConfig

real = Path.write_text
def torn(self, text, *args, **kwargs):
    if "collect.json" in self.name:
        with self.open("w") as f:
            f.write(text[: len(text) // 2])
            f.flush()
            os.kill(os.getpid(), signal.SIGKILL)
    return real(self, text, *args, **kwargs)
Path.write_text = torn
cfg = CollectConfig(tasks="lift", episodes=1, render=RenderOptions(cameras="agentview", height=32, width=32),
                    output=CollectOutputConfig(dir=Path(sys.argv[1])))
planning.claim_output_dir(cfg)
"""


def test_a_kill_while_collect_json_is_written_leaves_a_resumable_dir(tmp_path):
    """collect.json is written before the first shard; a kill in the middle of that write used to leave it torn,
    and every rerun then failed on it (JSONDecodeError) until --output.overwrite=true threw the shards away. It is
    written under a temporary name and renamed, and the rerun ignores the temporary file."""
    out = tmp_path / "run"
    proc = subprocess.run(
        [sys.executable, "-c", _KILLED_MID_RECORD, str(out)], capture_output=True, text=True
    )
    assert proc.returncode == -signal.SIGKILL, proc.stderr[-2000:]
    record = out / RECORD
    assert not record.exists() or json.loads(record.read_text())  # never torn at its final name
    cfg = CollectConfig(
        tasks="lift",
        episodes=1,
        render=RenderOptions(cameras="agentview", height=32, width=32),
        output=CollectOutputConfig(dir=out),
    )
    claim_output_dir(cfg)  # the rerun's claim: accepted, the options recorded
    assert json.loads(record.read_text())["config"] == cfg.data_options()
    assert sorted(p.name for p in out.iterdir()) == [RECORD]
