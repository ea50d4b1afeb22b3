"""The tolerance benchmark: perturbed keyframes are moved and turned by exactly the asked amounts, and a real
robosuite replay runs once per condition."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from benchmarks.bench_tolerance import ToleranceConfig, conditions, markdown, perturb, run_variation


def _keyframes(k: int = 5) -> np.ndarray:
    rng = np.random.default_rng(0)
    quat = Rotation.random(k, random_state=1).as_quat()
    return np.concatenate([rng.uniform(-0.3, 0.3, (k, 3)), quat, rng.integers(0, 2, (k, 2))], axis=1)


def test_every_keyframe_moves_by_exactly_r_and_keeps_its_flags():
    kf = _keyframes()
    moved = perturb(kf, 2.0, 0.0, np.random.default_rng(3))
    np.testing.assert_allclose(np.linalg.norm(moved[:, :3] - kf[:, :3], axis=1), 0.02, atol=1e-12)
    np.testing.assert_array_equal(moved[:, 3:], kf[:, 3:])
    again = perturb(kf, 2.0, 0.0, np.random.default_rng(3))
    np.testing.assert_array_equal(moved, again)  # seeded: a rerun replays the same draws


def test_every_keyframe_turns_by_exactly_theta_about_the_vertical():
    kf = _keyframes()
    turned = perturb(kf, 0.0, 10.0, np.random.default_rng(4))
    np.testing.assert_array_equal(turned[:, :3], kf[:, :3])
    np.testing.assert_array_equal(turned[:, 7:], kf[:, 7:])
    delta = Rotation.from_quat(turned[:, 3:7]) * Rotation.from_quat(kf[:, 3:7]).inv()
    rotvec = delta.as_rotvec(degrees=True)
    np.testing.assert_allclose(np.abs(rotvec[:, 2]), 10.0, atol=1e-9)
    np.testing.assert_allclose(rotvec[:, :2], 0.0, atol=1e-9)


def test_chosen_keyframes_share_one_horizontal_move_and_turn():
    """``steps``/``horizontal``/``shared``: the approach, grasp and close (0-2) move together, in x-y, and turn by
    the same angle; the later keyframes are the expert's."""
    kf = _keyframes(6)
    moved = perturb(kf, 1.5, 20.0, np.random.default_rng(5), steps=[0, 1, 2, 9], horizontal=True, shared=True)
    shift = moved[:3, :3] - kf[:3, :3]
    np.testing.assert_allclose(shift, np.broadcast_to(shift[0], (3, 3)), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(shift[0, :2]), 0.015, atol=1e-12)
    assert shift[0, 2] == 0.0
    turns = (Rotation.from_quat(moved[:3, 3:7]) * Rotation.from_quat(kf[:3, 3:7]).inv()).as_rotvec(
        degrees=True
    )
    np.testing.assert_allclose(turns, np.broadcast_to(turns[0], (3, 3)), atol=1e-9)
    np.testing.assert_allclose(abs(turns[0, 2]), 20.0, atol=1e-9)
    np.testing.assert_array_equal(moved[3:], kf[3:])
    unshared = perturb(kf, 1.5, 0.0, np.random.default_rng(5), steps=[0, 1, 2])
    assert not np.allclose(
        unshared[0, :3] - kf[0, :3], unshared[1, :3] - kf[1, :3]
    )  # fresh draw per keyframe


def test_conditions_and_table():
    cfg = ToleranceConfig(positions_cm=[1.0], yaws_deg=[20.0])
    conds = conditions(cfg)
    assert conds == [(0.0, 0.0), (1.0, 0.0), (0.0, 20.0)]
    outcome = {
        "task": "lift",
        "variation": "lift_cube",
        "replays": {
            "exact": {"successes": 2, "episodes": 2},
            "1 cm": {"successes": 1, "episodes": 2},
            "20°": {"successes": 0, "episodes": 2},
        },
    }
    text = markdown([outcome], conds)
    assert "| variation | exact | 1 cm | 20° |" in text
    assert "| lift:lift_cube | 2/2 (34–100%) | 1/2 (9–91%) | 0/2 (0–66%) |" in text
    assert "| **lift** | 2/2" in text


def test_a_real_replay_per_condition():
    """One Lift expert episode in robosuite, replayed exactly and with 3 cm displacements."""
    outcome = run_variation("lift", "lift_cube", [0], [(0.0, 0.0), (3.0, 0.0)])
    assert outcome["expert_failed"] == []
    assert outcome["replays"]["exact"] == {"successes": 1, "episodes": 1}
    assert outcome["replays"]["3 cm"]["episodes"] == 1
