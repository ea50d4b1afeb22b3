"""CameraRig: upright RGB, metric depth and calibration agree with the true scene geometry."""

import numpy as np
import pytest

from sigma_data.cameras import (
    DEFAULT_CAMERAS,
    CameraRig,
    RenderConfig,
    RenderOptions,
    backproject,
    fused_cloud,
    parse_cameras,
)
from sigma_data.record import EpisodeRecorder
from sigma_data.suite import close_env, get_task, make_env, reset_env

SIZE = 96


@pytest.fixture(scope="module")
def scene():
    task = get_task("lift")
    env = make_env(task, cameras=DEFAULT_CAMERAS, height=SIZE, width=SIZE)
    reset_env(env, task, task.variations[0], seed=2)
    rig = CameraRig(env, RenderConfig(DEFAULT_CAMERAS, SIZE, SIZE))
    yield env, rig
    close_env(env)


def cube_points_error(env, cloud: np.ndarray) -> tuple[np.ndarray, int]:
    """|signed distance| (m) to the true cube box of the cloud points near the cube and above the table."""
    body = env.sim.model.body_name2id(env.cube.root_body)
    centre = env.sim.data.body_xpos[body]
    rot = env.sim.data.body_xmat[body].reshape(3, 3)
    half = np.asarray(env.cube.size)
    local = (cloud - centre) @ rot
    table_z = env.model.mujoco_arena.table_offset[2]
    near = np.all(np.abs(local) < half + 0.01, axis=1) & (cloud[:, 2] > table_z + 0.002)
    q = np.abs(local[near]) - half
    signed = np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)
    return np.abs(signed), int(near.sum())


def test_fused_cloud_matches_the_cube_within_5mm(scene):
    env, rig = scene
    views = rig.render()
    assert set(views) == set(DEFAULT_CAMERAS)
    for v in views.values():
        assert v.rgb.shape == (SIZE, SIZE, 3) and v.rgb.dtype == np.uint8
        assert v.depth.shape == (SIZE, SIZE) and v.depth.dtype == np.float32
        assert v.intrinsics.shape == (3, 3) and v.extrinsics.shape == (4, 4)
    err, n = cube_points_error(env, fused_cloud(views, max_depth=rig.config.max_depth))
    assert n > 100
    assert err.max() < 0.005, f"max cube error {err.max() * 1000:.2f} mm"
    # Each fixed camera alone also sees the cube correctly (calibration of every camera, not just on average).
    for cam in ("agentview", "frontview"):
        err_cam, n_cam = cube_points_error(
            env, backproject(views[cam].depth, views[cam].intrinsics, views[cam].extrinsics).reshape(-1, 3)
        )
        assert n_cam > 10 and err_cam.max() < 0.005, cam


def test_images_are_upright(scene):
    env, rig = scene
    views = rig.render()
    # agentview looks at the table from the front and above: the table (near) is at the bottom of an upright
    # image, the far background at the top, so depth grows from the bottom rows to the top rows.
    depth = views["agentview"].depth
    assert np.median(depth[-8:]) < np.median(depth[:8])
    # The cube centre projects onto pixels whose depth is about the camera distance to the cube.
    K, E = views["agentview"].intrinsics.astype(np.float64), views["agentview"].extrinsics.astype(np.float64)
    body = env.sim.model.body_name2id(env.cube.root_body)
    p_cam = np.linalg.inv(E) @ np.append(env.sim.data.body_xpos[body], 1.0)
    u, v, _ = K @ p_cam[:3] / p_cam[2]
    assert 0 < p_cam[2] - depth[int(v), int(u)] < 0.04  # the visible surface, in front of the centre


def test_wrist_camera_moves_with_the_state_and_static_ones_do_not(scene):
    env, rig = scene
    task = get_task("lift")
    reset_env(env, task, task.variations[0], seed=2)
    rec = EpisodeRecorder(env)
    for _ in range(6):
        rec.step(np.array([0.6, 0, 0.4, 0, 0, 0, -1.0]))
    ep = rec.to_episode("lift", "lift_cube", "lift the cube")
    first, last = rig.render_state(ep.sim_states[0]), rig.render_state(ep.sim_states[-1])
    wrist = "robot0_eye_in_hand"
    moved = np.linalg.norm(last[wrist].extrinsics[:3, 3] - first[wrist].extrinsics[:3, 3])
    assert moved > 0.02
    np.testing.assert_array_equal(first["agentview"].extrinsics, last["agentview"].extrinsics)
    # The static calibration lists exactly the fixed cameras, equal to the per-frame values.
    static = rig.static_calibration()
    assert set(static) == {"agentview", "frontview", "birdview"}
    np.testing.assert_allclose(static["agentview"][1], first["agentview"].extrinsics, atol=1e-6)


def test_fast_settings_and_bad_cameras(scene):
    env, _rig = scene
    assert env.sim.model._model.vis.quality.offsamples == 0
    with pytest.raises(ValueError, match="unknown camera"):
        CameraRig(env, RenderConfig(("agentview", "nope"), SIZE, SIZE))
    with pytest.raises(ValueError, match="image size"):
        CameraRig(env, RenderConfig(("agentview",), 0, SIZE))


def test_render_options_give_the_render_config_and_bad_camera_lists_are_named():
    """``--render.*`` of every rendering command: defaults equal the renderers' and the one camera-list parser
    names the flag it read."""
    assert RenderOptions().config() == RenderConfig()
    options = RenderOptions(cameras=" agentview, robot0_eye_in_hand ,", height=64, fast=False, max_depth=2.0)
    assert options.config() == RenderConfig(("agentview", "robot0_eye_in_hand"), 64, 128, False, 2.0)
    with pytest.raises(ValueError, match=r"no cameras given \(--render\.cameras\)"):
        RenderOptions(cameras=" , ").config()
    with pytest.raises(ValueError, match=r"duplicate camera names in --render\.cameras=agentview,agentview"):
        parse_cameras("agentview,agentview")
    with pytest.raises(ValueError, match=r"no cameras given \(--cameras\)"):
        parse_cameras("", "--cameras")
