"""Quaternion / matrix / Euler conversions against scipy, and the 72-bin discretisation with the gimbal fix."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from sigma_policy.rotation import (
    bins_to_quat,
    euler_xyz_to_quat,
    matrix_to_quat,
    normalize_quat,
    quat_to_bins,
    quat_to_euler_xyz,
    quat_to_matrix,
)


def _random_quats(n: int, seed: int = 0) -> torch.Tensor:
    return torch.from_numpy(Rotation.random(n, random_state=seed).as_quat()).double()


def test_conversions_match_scipy() -> None:
    q = _random_quats(500)
    ref = Rotation.from_quat(q.numpy())
    torch.testing.assert_close(quat_to_matrix(q), torch.from_numpy(ref.as_matrix()))
    qn = normalize_quat(q)
    assert (qn[:, 3] >= 0).all()
    torch.testing.assert_close(matrix_to_quat(quat_to_matrix(q)), qn)
    torch.testing.assert_close(quat_to_euler_xyz(q), torch.from_numpy(ref.as_euler("xyz", degrees=True)))
    torch.testing.assert_close(euler_xyz_to_quat(quat_to_euler_xyz(q)), qn)


def test_matrix_to_quat_near_180_degrees() -> None:
    q = torch.tensor([[1.0, 0.0, 0.0, 0.0], [0.0, 0.7071068, 0.7071068, 1e-8]], dtype=torch.float64)
    torch.testing.assert_close(matrix_to_quat(quat_to_matrix(q)), normalize_quat(q), atol=1e-7, rtol=0)


def test_bins_round_trip_on_bin_centres() -> None:
    g = torch.Generator().manual_seed(0)
    bins = torch.randint(0, 72, (400, 3), generator=g)
    bins[:, 1] = torch.randint(19, 54, (400,), generator=g)  # pitch in (-85, 85): away from the gimbal lock
    torch.testing.assert_close(quat_to_bins(bins_to_quat(bins)), bins, rtol=0, atol=0)
    assert (bins_to_quat(bins)[:, 3] >= 0).all()


def test_bins_match_scipy_reference_and_decode_within_half_bin() -> None:
    q = _random_quats(300, seed=1)
    euler = Rotation.from_quat(q.numpy()).as_euler("xyz", degrees=True)
    keep = np.abs(np.abs(euler[:, 1]) - 90) > 1.5  # the gimbal region is tested separately
    want = np.round((euler[keep] + 180) / 5).astype(np.int64) % 72
    got = quat_to_bins(q[keep].float())
    np.testing.assert_array_equal(got.numpy(), want)
    # Decoded rotation is within half a bin per axis: angle between rotations <= 3 * 2.5 degrees.
    rel = Rotation.from_quat(bins_to_quat(got).double().numpy()) * Rotation.from_quat(q[keep].numpy()).inv()
    assert np.degrees(rel.magnitude()).max() <= 7.5


@pytest.mark.parametrize("pitch", [89.4, 90.0, -90.6, -89.2])
def test_gimbal_fix(pitch: float) -> None:
    roll, yaw = 30.0, 40.0
    q = torch.from_numpy(Rotation.from_euler("xyz", [roll, pitch, yaw], degrees=True).as_quat())[None]
    bins = quat_to_bins(q)[0]
    sign = 1 if pitch > 0 else -1
    assert bins[1] == round((sign * 90 + 180) / 5)
    assert bins[2] == 36  # yaw folded to 0
    # Roll absorbs yaw: Rz(yaw) Ry(+-90) Rx(roll) == Ry(+-90) Rx(roll -+ yaw).
    expected_roll = roll - yaw if sign > 0 else roll + yaw
    assert bins[0] == round((expected_roll + 180) / 5) % 72
    # The decoded rotation equals the snapped one.
    snapped = Rotation.from_euler("xyz", [roll, sign * 90, yaw], degrees=True)
    dec = Rotation.from_quat(bins_to_quat(bins[None]).double().numpy())
    assert np.degrees((dec * snapped.inv()).magnitude()) < 2.5 + 1e-6
