"""`make demo --quick`: every stage of the main job runs for real (collect, validate, lerobot-train, eval, viz)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from lerobot.datasets.lerobot_dataset import LeRobotDataset

from pipelines.demo import BF16_STEPS, FLOAT32_STEPS, DemoConfig, run_demo
from pipelines.viz.cli import PolicyViewConfig, run_policy_view
from sigma_policy.renderer import VIEW_NAMES
from tests.pipelines.viz_fixtures import read_rrd


def test_quick_demo_runs_every_stage(tmp_path):
    out = tmp_path / "demo"
    report = run_demo(DemoConfig(output_dir=out, quick=True))

    # Stage outputs exist and are what they claim to be.
    for kind in ("dense", "keyframe"):
        ds = LeRobotDataset(f"local/{kind}", root=report["datasets"][kind], video_backend="pyav")
        assert ds.num_episodes >= 1
    ckpt = out / "train" / "checkpoints" / "last" / "pretrained_model"
    assert json.loads((ckpt / "config.json").read_text())["type"] == "sigma"
    results = json.loads((out / "eval" / "results.json").read_text())
    assert results["variations"] and all(v["episodes"] >= 1 for v in results["variations"])
    # Rollouts ran to the end (with Rerun logging on): a policy failure is fine, a crash is not.
    assert [e["error"] for e in results["episodes"]] == [None] * len(results["episodes"])
    assert set(report["recordings"]) >= {"episode"}
    assert any(k.startswith("rollout_") for k in report["recordings"])
    for path in report["recordings"].values():
        assert (out / "viz").exists() and path.endswith(".rrd")
    assert json.loads((out / "demo.json").read_text())["stage_seconds"]

    # The policy viewer on the trained checkpoint and a real keyframe-dataset frame (sigma-viz policy).
    rrd = tmp_path / "policy.rrd"
    line = run_policy_view(
        PolicyViewConfig(checkpoint=ckpt, root=report["datasets"]["keyframe"], frame_index=1, save=rrd)
    )
    assert "5 views" in line and "translation error" in line
    contents = read_rrd(rrd)
    for name in VIEW_NAMES:
        assert contents.rows[f"/policy/views/{name}/heatmap"]["Tensor:data"] == 1
        assert contents.rows[f"/policy/views/{name}/markers/gt"]["Points2D:positions"] == 1
    assert len(contents.values["/policy/world/point_cloud"]["Points3D:positions"][0]) > 100
    assert contents.rows["/policy/probs/gripper"]["BarChart:values"] == 1

    # The stock evaluator on the same checkpoint through sigma's env plugin (discovered via the shim).
    eval_dir = tmp_path / "lerobot_eval"
    cams = "[" + ",".join(DemoConfig(quick=True).cameras) + "]"
    proc = subprocess.run(
        [
            str(Path(sys.executable).with_name("lerobot-eval")),
            f"--policy.path={ckpt}",
            "--env.type=sigma_robosuite",
            "--env.task=lift",
            f"--env.cameras={cams}",
            f"--env.image_size={DemoConfig(quick=True).image_size}",
            "--env.episode_length=2",
            "--eval.n_episodes=1",
            "--eval.batch_size=1",
            "--policy.device=cpu",
            "--seed=100000",
            f"--output_dir={eval_dir}",
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-4000:]
    info = json.loads((eval_dir / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 1
    assert list((eval_dir / "videos").rglob("*.mp4"))


def test_demo_steps_follow_the_training_precision(monkeypatch):
    """Unset ``steps`` is the bf16 recipe's ``BF16_STEPS`` on a CPU with native bf16 and ``FLOAT32_STEPS`` in float32
    (``--bf16 false`` or a CPU without it), so the demo keeps to about 20 minutes; ``--steps`` wins either way, and
    ``--quick`` keeps 4."""
    import sigma_policy.modeling_sigma as modeling

    for native, bf16, want in (
        (True, True, BF16_STEPS),
        (False, True, FLOAT32_STEPS),
        (True, False, FLOAT32_STEPS),
    ):
        monkeypatch.setattr(modeling, "cpu_has_native_bf16", lambda native=native: native)
        cfg = DemoConfig(bf16=bf16)
        why = cfg.resolve_steps()
        assert cfg.steps == want and str(want) in why
        assert ("float32" in why) == (want == FLOAT32_STEPS)
    cfg = DemoConfig(steps=1200)
    assert "1200" in cfg.resolve_steps() and cfg.steps == 1200
    quick = DemoConfig(quick=True)
    assert "--quick" in quick.resolve_steps() and quick.steps == 4
