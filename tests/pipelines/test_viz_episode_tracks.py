"""The episode viewer's reading side: depth back-projection, even subsampling, and a bad episode index named."""

from __future__ import annotations

import numpy as np
import pytest

from pipelines.viz.episode_tracks import backproject_depth, load_episode_dataset, subsample_evenly
from tests.pipelines import viz_fixtures as fx


def test_backproject_depth_inverts_the_renderer():
    K = fx.intrinsics()
    E = fx.look_at(np.array([0.4, -0.3, 1.2]), fx.CUBE_CENTER, np.array([0.0, 0.0, 1.0]))
    _, depth = fx.render(K, E)
    xyz, flat = backproject_depth(depth[..., 0], K, E, max_depth_m=3.0)
    assert len(xyz) == fx.H * fx.W == len(flat)
    assert fx.on_scene_surface(xyz, tol=1e-5).all()
    far = depth.copy()
    far[0, 0, 0] = fx.MISS_DEPTH_M
    xyz_far, flat_far = backproject_depth(far[..., 0], K, E, max_depth_m=3.0)
    assert len(xyz_far) == fx.H * fx.W - 1 and 0 not in flat_far


def test_subsample_evenly():
    assert subsample_evenly(5, 10).tolist() == [0, 1, 2, 3, 4]
    idx = subsample_evenly(1000, 7)
    assert len(idx) == 7 and idx[0] == 0 and idx[-1] == 999 and np.all(np.diff(idx) > 0)


def test_bad_episode_index_names_the_dataset(tmp_path):
    dense = fx.write_dense_dataset(tmp_path / "dense", write_sidecar=True)
    with pytest.raises(ValueError, match="episode index 7 out of range"):
        load_episode_dataset(dense.root, 7)
