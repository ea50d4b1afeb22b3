"""The installed stack: plugin discovery by LeRobot, a consistent venv, and headless robosuite rendering."""

from __future__ import annotations

import importlib.metadata
import subprocess
import sys
import textwrap

import numpy as np
import pytest

# Imported before any env exists: importing it (it pulls in robosuite.wrappers) after an offscreen context
# was created leaves that context rendering garbage depth under pytest (seen with robosuite 1.5.1 + EGL).
from robosuite.utils import camera_utils


def run_python(code: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, timeout=300
    )


def test_distribution_name_is_discoverable_by_lerobot():
    name = importlib.metadata.distribution("lerobot_policy_sigma").metadata["Name"]
    # LeRobot imports distributions whose metadata Name starts with this prefix; a hyphen is skipped silently.
    assert name.startswith("lerobot_policy_"), name
    assert importlib.metadata.version("lerobot") == "0.6.1"


def test_lerobot_plugin_discovery_registers_sigma():
    """In a fresh interpreter, LeRobot's own discovery imports the shim and `sigma` becomes a policy type."""
    proc = run_python(
        """
        import sys
        from lerobot.configs.policies import PreTrainedConfig
        assert "sigma" not in PreTrainedConfig.get_known_choices()
        from lerobot.utils.import_utils import register_third_party_plugins
        register_third_party_plugins()
        assert "lerobot_policy_sigma" in sys.modules, "shim not imported by LeRobot"
        assert "sigma_policy" in sys.modules, "shim did not import sigma_policy"
        cls = PreTrainedConfig.get_choice_class("sigma")
        assert cls.__name__ == "SigmaConfig", cls
        print("OK", cls.__module__)
        """
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "OK sigma_policy.configuration_sigma" in proc.stdout


def test_venv_requirements_are_consistent():
    proc = subprocess.run([sys.executable, "-m", "pip", "check"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_pins_that_robosuite_needs():
    import mujoco

    major, minor = (int(p) for p in mujoco.__version__.split(".")[:2])
    assert (3, 3) <= (major, minor) < (3, 10), f"mujoco {mujoco.__version__} breaks robosuite 1.5.1"
    assert importlib.metadata.version("robosuite") == "1.5.1"


@pytest.fixture(scope="module")
def lift_env():
    import robosuite

    from sigma_data.suite import close_env

    env = robosuite.make(
        "Lift",
        robots="Panda",
        has_renderer=False,
        has_offscreen_renderer=True,
        use_camera_obs=False,
        camera_names=["agentview"],
        camera_heights=96,
        camera_widths=96,
        control_freq=20,
        ignore_done=True,
    )
    env.reset()
    yield env
    close_env(env)


def test_robosuite_lift_renders_upright_rgb_and_metric_depth(lift_env):
    """Render agentview offscreen, flip to the top-left origin, convert the z-buffer to metres, and check both
    against the true cube position projected through robosuite's own calibration."""
    env, cam, h, w = lift_env, "agentview", 96, 96
    env.sim.forward()
    rgb, zbuf = env.sim.render(camera_name=cam, height=h, width=w, depth=True)
    rgb, zbuf = rgb[::-1], zbuf[::-1]  # OpenGL rows are bottom-up
    depth = camera_utils.get_real_depth_map(env.sim, zbuf)
    assert rgb.shape == (h, w, 3) and rgb.dtype == np.uint8
    assert depth.shape == (h, w) and np.isfinite(depth).all()

    cube_pos = env.sim.data.body_xpos[env.cube_body_id]
    world_to_pixel = camera_utils.get_camera_transform_matrix(env.sim, cam, h, w)
    u, v, z, _ = world_to_pixel @ np.append(cube_pos, 1.0)
    col, row = int(u / z), int(v / z)
    assert 0 <= row < h and 0 <= col < w

    # Upright: the cube (red) is where calibration says; upside down it would land on the table or the wall.
    r, g, b = rgb[row, col].astype(int)
    assert r > 80 and r > 2 * g and r > 2 * b, f"pixel {(row, col)} is {(r, g, b)}, not the red cube"
    # Metric: depth at the cube centre's pixel is the camera-frame z of the cube's surface, within its size.
    cam_to_world = camera_utils.get_camera_extrinsic_matrix(env.sim, cam)
    z_cam = (np.linalg.inv(cam_to_world) @ np.append(cube_pos, 1.0))[2]
    assert z_cam - 0.04 < depth[row, col] < z_cam + 0.005, (depth[row, col], z_cam)
    # The table behind the cube is farther than the cube, and the scene is within a few metres.
    assert 0.3 < np.median(depth) < 5.0
