"""Point clouds from depth (robosuite pixel-centre convention), cropping, the canonical cube, and a real
robosuite Lift frame rendered by the virtual-view renderer with the cube where it is."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from sigma_policy.pointcloud import (
    PANDA_HAND_BOX,
    bounds_mask,
    cloud_box,
    crop_to_cube,
    cube_to_world,
    depth_to_camera_points,
    depth_to_world_points,
    drop_points,
    fuse_cameras,
    hand_points,
    in_frame_box,
    world_to_cube,
)
from sigma_policy.renderer import VIEW_NAMES, VirtualViewRenderer

BOUNDS = torch.tensor([-0.4, -0.5, 0.75, 0.4, 0.5, 1.35])


def _look_at_extrinsics(eye: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Camera-to-world, OpenCV axes (z forward, y down), looking from eye at target with world z up."""
    z = (target - eye) / (target - eye).norm()
    x = torch.linalg.cross(z, torch.tensor([0.0, 0.0, 1.0], dtype=eye.dtype))
    x = x / x.norm()
    E = torch.eye(4, dtype=eye.dtype)
    E[:3, :3] = torch.stack([x, torch.linalg.cross(z, x), z], 1)
    E[:3, 3] = eye
    return E


def test_cloud_round_trips_through_pixels() -> None:
    """Project world points with K, E (pixel centre at +0.5) into a depth map, back-project: same points."""
    H, W, f = 48, 64, 50.0
    K = torch.tensor([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1]], dtype=torch.float64)
    E = _look_at_extrinsics(
        torch.tensor([1.0, 0.5, 1.5], dtype=torch.float64), torch.zeros(3, dtype=torch.float64)
    )
    depth = 1.0 + torch.rand(H, W, dtype=torch.float64)
    depth[0, 0] = 0.0
    depth[1, 1] = float("nan")
    world = depth_to_world_points(depth, K, E)
    assert torch.isnan(world[0, 0]).all() and torch.isnan(world[1, 1]).all()
    cam = (torch.cat([world, torch.ones_like(world[..., :1])], -1) @ torch.linalg.inv(E).T)[..., :3]
    pix = cam @ K.T
    uv = pix[..., :2] / pix[..., 2:]
    cols, rows = torch.meshgrid(torch.arange(W) + 0.5, torch.arange(H) + 0.5, indexing="xy")
    ok = torch.isfinite(uv[..., 0])
    torch.testing.assert_close(uv[..., 0][ok], cols[ok].double())
    torch.testing.assert_close(uv[..., 1][ok], rows[ok].double())
    torch.testing.assert_close(cam[..., 2][ok], depth[ok])
    # Batched call == per-item calls.
    cams = depth_to_camera_points(torch.stack([depth, depth * 2]), torch.stack([K, K]))
    torch.testing.assert_close(cams[1][ok], 2 * depth_to_camera_points(depth, K)[ok])


def test_fuse_crop_and_cube_mapping() -> None:
    torch.manual_seed(0)  # unseeded, some draws left no point inside the box
    pts = torch.rand(2, 3, 4, 5, 3) * 2 - 1
    rgb = torch.rand(2, 3, 3, 4, 5)
    p, c = fuse_cameras(pts, rgb)
    assert p.shape == c.shape == (2, 60, 3)
    torch.testing.assert_close(p[1, 2 * 20 + 3 * 5 + 4], pts[1, 2, 3, 4])
    torch.testing.assert_close(c[1, 2 * 20 + 3 * 5 + 4], rgb[1, 2, :, 3, 4])
    p[0, 0] = float("nan")
    m = bounds_mask(p, BOUNDS)
    assert not m[0, 0]
    assert torch.equal(m[0, 1:], ((p[0, 1:] >= BOUNDS[:3]) & (p[0, 1:] <= BOUNDS[3:])).all(-1))
    cube = world_to_cube(p, BOUNDS)
    inside = cube[m]
    assert inside.abs().max() <= 1 + 1e-6
    torch.testing.assert_close(cube_to_world(cube, BOUNDS)[m], p[m])
    corner = world_to_cube(BOUNDS[None, 3:], BOUNDS)[0]
    torch.testing.assert_close(corner, torch.tensor([0.8 / 1.0, 1.0, 0.6 / 1.0]))  # scale = 2 / 1.0 m
    per_sample = torch.stack([BOUNDS, BOUNDS + 0.1])
    torch.testing.assert_close(world_to_cube(p, per_sample)[1], world_to_cube(p[1], BOUNDS + 0.1))


@pytest.fixture(scope="module")
def lift_frame() -> dict:
    import mujoco
    import robosuite
    from robosuite.utils import camera_utils as cu

    from sigma_data.poses import grip_site_pose
    from sigma_data.suite import close_env

    np.random.seed(0)  # robosuite draws the cube placement from the global numpy RNG
    env = robosuite.make(
        "Lift", robots="Panda", has_renderer=False, has_offscreen_renderer=True, use_camera_obs=False,
        horizon=50, hard_reset=False,
    )  # fmt: skip
    env.reset()
    sim = env.sim
    sim.model._model.vis.quality.offsamples = 0  # MSAA off: exact depth at silhouettes (docs/robosuite.md §2)
    ctx = sim._render_context_offscreen
    ctx.con.free()
    ctx._set_mujoco_context_and_buffers()
    sim.forward()
    H = W = 96
    frame = {"depth": [], "rgb": [], "K": [], "E": []}
    cams = ("agentview", "frontview", "birdview", "sideview")
    for cam in cams:
        rgb, depth = sim.render(camera_name=cam, height=H, width=W, depth=True)
        frame["rgb"].append(torch.from_numpy(rgb[::-1].copy()).permute(2, 0, 1).float() / 255)
        frame["depth"].append(torch.from_numpy(cu.get_real_depth_map(sim, depth[::-1].copy())).float())
        frame["K"].append(torch.from_numpy(cu.get_camera_intrinsic_matrix(sim, cam, H, W)).float())
        frame["E"].append(torch.from_numpy(cu.get_camera_extrinsic_matrix(sim, cam)).float())
    # MuJoCo's segmentation (object type, id) per pixel, in the same rows as the RGB-D images
    seg = [sim.render(camera_name=c, height=H, width=W, segmentation=True)[::-1] for c in cams]
    geom_body = sim.model._model.geom_bodyid
    frame["body"] = torch.from_numpy(
        np.stack([np.where(s[..., 0] == mujoco.mjtObj.mjOBJ_GEOM, geom_body[s[..., 1]], -1) for s in seg])
    )
    frame["body_names"] = [sim.model.body_id2name(i) for i in range(sim.model.nbody)]
    pos, quat = grip_site_pose(env)
    frame["site_pos"], frame["site_quat"] = torch.from_numpy(pos).float(), torch.from_numpy(quat).float()
    frame["cube_pos"] = torch.from_numpy(np.array(sim.data.body_xpos[env.cube_body_id])).float()
    frame["cube_rot"] = torch.from_numpy(np.array(sim.data.body_xmat[env.cube_body_id]).reshape(3, 3)).float()
    frame["cube_half"] = torch.tensor(np.asarray(env.cube.size, dtype=np.float32))
    close_env(env)
    return {k: torch.stack(v) if k in ("rgb", "depth", "K", "E") else v for k, v in frame.items()}


def test_real_lift_cloud_renders_cube_where_it_is(lift_frame: dict) -> None:
    depth, K, E = lift_frame["depth"], lift_frame["K"], lift_frame["E"]
    world = depth_to_world_points(depth, K, E)  # (C, H, W, 3)
    pts, rgb = fuse_cameras(world[None], lift_frame["rgb"][None])
    mask = bounds_mask(pts, BOUNDS)
    cube = torch.where(mask[..., None], world_to_cube(pts, BOUNDS), 0)
    renderer = VirtualViewRenderer(img_size=220)
    img = renderer(cube, rgb, mask)[0]  # (V, 10, H, W)
    target = world_to_cube(lift_frame["cube_pos"][None, None], BOUNDS)
    uv = renderer.project(target)[0, 0]  # (V, 2)
    for v, name in enumerate(VIEW_NAMES):
        col, row = int(uv[v, 0]), int(uv[v, 1])
        patch = img[v, :, row - 2 : row + 3, col - 2 : col + 3].flatten(1)  # 5x5 around the cube centre
        filled = patch[6] != -1
        red = (patch[3] > 0.2) & (
            patch[3] > 1.8 * patch[4:6].amax(0)
        )  # lit (.73, .24, .29), shaded (.42, .14, .16)
        # Every virtual camera sees a face of the cube around its centre: those pixels show red points whose xyz
        # channel lies on the true (randomly sized and yawed) cube's surface within 3 mm.
        assert (filled & red).float().mean() > 0.5, (name, patch[3:6].T[:3].tolist())
        xyz_world = cube_to_world(patch[:3, filled & red].T, BOUNDS)
        local = (xyz_world - lift_frame["cube_pos"]) @ lift_frame["cube_rot"]  # in the (yawed) cube's frame
        surface_dist = (local.abs() - lift_frame["cube_half"]).amax(-1)  # 0 on the box surface
        assert surface_dist.abs().max() < 0.003, (name, float(surface_dist.abs().max()))


def test_in_frame_box_uses_the_frame_axes() -> None:
    """A box in a frame turned 90° about z and moved: points inside it (in that frame) become NaN, others stay."""
    axes = torch.tensor([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # frame x = world y
    origin = torch.tensor([1.0, 2.0, 3.0])
    pts = origin + torch.tensor(
        [[0.0, 0.5, 0.0], [0.5, 0.0, 0.0], [0.0, 0.0, 0.0]]
    )  # frame x +0.5, frame y -0.5
    inside = in_frame_box(pts[None], origin[None], axes[None], [0.4, -0.1, -0.1, 0.6, 0.1, 0.1])
    out = drop_points(pts[None], inside)[0]
    assert torch.isnan(out[0]).all() and torch.equal(out[1:], pts[1:])
    with pytest.raises(ValueError, match="x_lo"):
        in_frame_box(pts[None], origin[None], axes[None], [0.0, 1.0])


def test_panda_hand_box_drops_the_real_hand_and_nothing_else(lift_frame: dict) -> None:
    """On a real robosuite Lift frame, ``PANDA_HAND_BOX`` in the grip site's frame holds the Panda hand and link
    7 (by MuJoCo's segmentation of the four cameras) and none of the cube's or the table's points."""
    world = depth_to_world_points(lift_frame["depth"], lift_frame["K"], lift_frame["E"]).reshape(1, -1, 3)
    state = torch.cat([lift_frame["site_pos"], lift_frame["site_quat"], torch.tensor([1.0, 0.04, -0.04])])[
        None
    ]
    dropped = hand_points(world, state, PANDA_HAND_BOX)[0] & torch.isfinite(world[0]).all(-1)
    names = lift_frame["body_names"]
    body = lift_frame["body"].reshape(-1)

    def share(*parts: str) -> tuple[float, int]:
        ids = [i for i, n in enumerate(names) if n and any(n.endswith(p) for p in parts)]
        of = torch.isin(body, torch.tensor(ids))
        return float(dropped[of].float().mean()), int(of.sum())

    hand, n_hand = share("right_gripper", "link7")
    assert n_hand > 50 and hand > 0.9, (hand, n_hand)
    for part in ("cube_main", "table"):
        frac, n = share(part)
        assert n > 20 and frac == 0.0, (part, frac, n)


def test_crop_keeps_the_in_box_points_first_padded_to_the_fullest_sample() -> None:
    bounds = torch.tensor([0.0, 0.0, 0.0, 1.0, 1.0, 1.0])
    nan = float("nan")
    points = torch.tensor(
        [
            [[2.0, 0.5, 0.5], [0.5, 0.5, 0.5], [nan, nan, nan], [1.0, 1.0, 1.0]],  # two inside
            [[0.25, 0.5, 0.5], [5.0, 5.0, 5.0], [5.0, 5.0, 5.0], [5.0, 5.0, 5.0]],  # one inside
        ]
    )
    colors = torch.arange(2 * 4 * 3, dtype=torch.float32).reshape(2, 4, 3)
    cube, kept, mask = crop_to_cube(points, colors, bounds)
    assert cube.shape == (2, 2, 3) and mask.tolist() == [[True, True], [True, False]]
    torch.testing.assert_close(cube[0], world_to_cube(points[0, [1, 3]], bounds))  # in their order
    torch.testing.assert_close(kept[0], colors[0, [1, 3]])
    assert torch.equal(cube[1, 1], torch.zeros(3))  # the padding is a finite point the mask drops


def test_cloud_box_is_the_extent_of_the_points_inside_the_bounds() -> None:
    bounds = torch.tensor([0.0, 0.0, 0.0, 1.0, 1.0, 1.0])
    points = torch.tensor([[[0.2, 0.3, 0.1], [0.6, 0.4, 0.9], [3.0, 3.0, 3.0]]])
    torch.testing.assert_close(cloud_box(points, bounds), torch.tensor([[0.2, 0.3, 0.1, 0.6, 0.4, 0.9]]))
    with pytest.raises(ValueError, match="no points inside"):
        cloud_box(points[:, 2:], bounds)
