"""A checkpoint's processor JSON cannot run code in a process that loaded sigma's plugin (issue #19 item 3, the env
plugin path): LeRobot's loader refuses a step named by the import path of an unregistered class before importing
it, and still opens registered steps however they are named."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from lerobot.processor import DataProcessorPipeline, DeviceProcessorStep

from lerobot_policy_sigma import processor_guard

ROOT = Path(__file__).resolve().parents[2]
POPEN = "subprocess.Popen"


def _saved(tmp_path: Path, extra_step: dict | None = None, by_path: bool = False) -> Path:
    """A saved one-step pipeline (the device step), optionally named by import path, plus ``extra_step``."""
    out = tmp_path / "processor"
    DataProcessorPipeline(
        steps=[DeviceProcessorStep(device="cpu")], name="policy_preprocessor"
    ).save_pretrained(out)
    path = out / "policy_preprocessor.json"
    spec = json.loads(path.read_text())
    if by_path:
        del spec["steps"][0]["registry_name"]
        spec["steps"][0]["class"] = f"{DeviceProcessorStep.__module__}.{DeviceProcessorStep.__qualname__}"
    if extra_step is not None:
        spec["steps"].append(extra_step)
    path.write_text(json.dumps(spec))
    return path


@pytest.fixture
def guard():
    if os.environ.get("SIGMA_NO_LEROBOT_PATCHES"):
        pytest.skip("SIGMA_NO_LEROBOT_PATCHES leaves LeRobot untouched")
    assert processor_guard.install()


def test_an_unregistered_class_is_refused_before_it_is_imported(guard, tmp_path):
    marker = tmp_path / "executed"
    path = _saved(tmp_path, {"class": POPEN, "config": {"args": ["touch", str(marker)]}})
    with pytest.raises(ImportError, match=r"refusing processor step class 'subprocess\.Popen'"):
        DataProcessorPipeline.from_pretrained(path.parent, config_filename=path.name)
    assert not marker.exists()
    module = "sigma_guard_probe_never_imported"
    path = _saved(tmp_path, {"class": f"{module}.Step", "config": {}})
    with pytest.raises(ImportError, match="refusing"):
        DataProcessorPipeline.from_pretrained(path.parent, config_filename=path.name)
    assert module not in sys.modules


@pytest.mark.parametrize("by_path", [False, True])
def test_registered_steps_still_open(guard, tmp_path, by_path):
    path = _saved(tmp_path, by_path=by_path)
    pipeline = DataProcessorPipeline.from_pretrained(path.parent, config_filename=path.name)
    assert isinstance(pipeline.steps[0], DeviceProcessorStep)


def test_the_plugin_installs_the_guard():
    """LeRobot's CLIs import the plugin shim at start-up; that import is what guards their loader."""
    probe = (
        "import lerobot_policy_sigma\n"
        "from lerobot.processor import DataProcessorPipeline as P\n"
        "print(P.__dict__['_resolve_step_class'].__func__.__module__)\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "SIGMA_NO_LEROBOT_PATCHES"} | {"HF_HUB_OFFLINE": "1"}
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, env=env, check=True)
    assert out.stdout.split()[-1] == "lerobot_policy_sigma.processor_guard"


@pytest.mark.slow
def test_stock_lerobot_eval_on_the_sigma_env_refuses_a_tampered_checkpoint(tmp_path):
    """The issue's reproduction through the stock CLI: ``lerobot-eval --env.type=sigma_robosuite`` on a sigma
    checkpoint whose pre-processor gained ``{"class": "subprocess.Popen", ...}`` ran ``touch`` before the guard; it
    now exits with the refusal and nothing runs."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from lerobot.policies.factory import make_policy, make_pre_post_processors

    from sigma_policy.configuration_sigma import SigmaConfig
    from tests.sigma_policy.tiny_dataset import BOUNDS, write_tiny_keyframe_dataset

    root = write_tiny_keyframe_dataset(tmp_path / "tiny", episodes=2, size=32)
    cfg = SigmaConfig(
        preset="small",
        img_size=32,
        patch_size=8,
        attn_dim=32,
        attn_heads=2,
        device="cpu",
        scene_bounds=list(BOUNDS),
    )
    meta = LeRobotDataset("local/tiny", root=root).meta
    ckpt = tmp_path / "pretrained_model"
    for thing in (make_policy(cfg, ds_meta=meta), *make_pre_post_processors(cfg, dataset_stats=meta.stats)):
        thing.save_pretrained(ckpt)
    marker = tmp_path / "executed"
    path = ckpt / "policy_preprocessor.json"
    spec = json.loads(path.read_text())
    spec["steps"].append({"class": POPEN, "config": {"args": ["touch", str(marker)]}})
    path.write_text(json.dumps(spec))
    # The tiny checkpoint's cameras are "front" and "side": two robosuite cameras are renamed onto them.
    rename = {
        f"observation.images.{cam}{depth}": f"observation.images.{name}{depth}"
        for cam, name in (("agentview", "front"), ("robot0_eye_in_hand", "side"))
        for depth in ("", "_depth")
    }
    script = Path(sys.executable).with_name("lerobot-eval")
    args = [
        f"--policy.path={ckpt}",
        "--env.type=sigma_robosuite",
        "--env.task=lift",
        "--env.image_size=32",
        "--env.cameras=[agentview,robot0_eye_in_hand]",
        f"--rename_map={json.dumps(rename)}",
        "--eval.n_episodes=1",
        "--eval.batch_size=1",
        "--policy.device=cpu",
        f"--output_dir={tmp_path / 'eval'}",
    ]
    env = {k: v for k, v in os.environ.items() if k != "SIGMA_NO_LEROBOT_PATCHES"} | {"HF_HUB_OFFLINE": "1"}
    proc = subprocess.run(
        [str(script), *args], capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300
    )
    assert proc.returncode != 0
    assert "refusing processor step class 'subprocess.Popen'" in proc.stdout + proc.stderr
    assert not marker.exists()
