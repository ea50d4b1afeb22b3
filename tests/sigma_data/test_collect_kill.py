"""A killed ``sigma-data collect`` leaves nothing running: its spawned helpers (or DataTrove's pool workers) exit
with it, and the shard a helper was writing is not trusted by the next run."""

from __future__ import annotations

import importlib.util
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

from sigma_data.cameras import RenderOptions
from sigma_data.collect import MARKER, CollectConfig, CollectOutputConfig, ShardSpec, check_shard


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
