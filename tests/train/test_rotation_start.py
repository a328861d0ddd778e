"""PPO's rotation start from the references' body rates against the gyro (issue 27).

:mod:`l2calib.train.rotation_start`.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from l2calib.data import ImuSamples
from l2calib.interfaces import ReferenceTrajectory
from l2calib.recipe import recipe_from_dict
from l2calib.train.rotation_start import (
    CAP_DEG,
    FLOOR_DEG,
    fit_rotation,
    mean_gyro,
    rotation_from_rates,
    rotation_start,
)
from l2calib.trajectory import Trajectory

R_TRUE = Rotation.from_euler("xyz", [170.0, 5.0, 80.0], degrees=True).as_matrix()


def test_mean_gyro_is_the_interval_average():
    stamps = np.arange(0, 1_000_000_001, 5_000_000, dtype=np.int64)  # 200 Hz over 1 s
    t = stamps / 1e9
    gyro = np.stack([np.ones_like(t), 2 * t, t**2], axis=1)
    a, b = np.array([100_000_000, 400_000_000]), np.array([300_000_000, 900_000_000])
    got = mean_gyro(stamps, gyro, a, b)
    ta, tb = a / 1e9, b / 1e9
    expect = np.stack([np.ones(2), tb + ta, (tb**3 - ta**3) / (3 * (tb - ta))], axis=1)
    assert got == pytest.approx(expect, abs=1e-4)  # trapezoids on t² at 5 ms steps


def test_the_fit_recovers_rotation_and_per_segment_biases():
    rng = np.random.default_rng(0)
    pairs = []
    for bias in ([0.01, -0.02, 0.005], [-0.015, 0.0, 0.02]):
        w_lidar = rng.normal(scale=0.5, size=(400, 3))
        w_imu = w_lidar @ R_TRUE.T + bias + rng.normal(scale=0.002, size=(400, 3))
        pairs.append((w_lidar, w_imu))
    R, res, sv = fit_rotation(pairs)
    err = np.degrees(Rotation.from_matrix(R_TRUE.T @ R).magnitude())
    assert err < 0.05
    assert np.sqrt(np.mean(res**2)) == pytest.approx(0.002, rel=0.1)  # biases removed
    assert sv[0] == 1.0 and sv[2] > 0.5  # every direction excited


def _reference_and_imu(w_lidar_fn, duration_s=20.0, noise=0.002, seed=0):
    """A LiDAR trajectory (10 Hz poses) and a 200 Hz gyro of the same motion through R_TRUE."""
    rng = np.random.default_rng(seed)
    fine = np.arange(0, duration_s, 0.001)
    w = w_lidar_fn(fine)
    rots = [Rotation.identity()]
    for k in range(len(fine) - 1):  # body-frame rates integrated at 1 kHz
        rots.append(rots[-1] * Rotation.from_rotvec(w[k] * 0.001))
    quat = Rotation.concatenate(rots).as_quat()
    start = 1_000_000_000
    pick = np.arange(0, len(fine), 100)
    traj = Trajectory(start + (fine[pick] * 1e9).astype(np.int64), np.zeros((len(pick), 3)),
                      quat[pick], "lidar")  # fmt: skip
    imu_idx = np.arange(0, len(fine), 5)
    gyro = w[imu_idx] @ R_TRUE.T + rng.normal(scale=noise, size=(len(imu_idx), 3))
    imu = ImuSamples(start + (fine[imu_idx] * 1e9).astype(np.int64), gyro, np.zeros_like(gyro))
    return traj, imu


def _data(traj, imu, source="gt"):
    from types import SimpleNamespace

    seq = SimpleNamespace(name="drive", imu=imu)
    seg = SimpleNamespace(name="drive#0", sequence="drive")
    return [ReferenceTrajectory("drive#0", traj, "pose", source)], [seg], [seq]


def test_planar_drive_starts_tight_in_tilt_and_wide_about_the_vertical():
    def w(t):  # yaw about the LiDAR's z (mounted upright), tiny roll/pitch from terrain
        return np.stack([0.01 * np.sin(3.1 * t), 0.01 * np.cos(2.3 * t), 0.4 * np.sin(0.3 * t)], 1)

    start = rotation_from_rates(*_data(*_reference_and_imu(w, noise=0.03)), 0.0)
    assert start is not None
    R = Rotation.from_quat(start.quat_xyzw).as_matrix()
    tilt_err = np.degrees(np.arccos(np.clip((R @ [0, 0, 1]) @ (R_TRUE @ [0, 0, 1]), -1, 1)))
    assert tilt_err < 0.5
    assert start.singular_values[2] < 0.01  # planar: yaw about the vertical rests on little
    assert start.sigma_deg[2] > 2 * max(start.sigma_deg[:2])  # the vertical is the wide axis
    assert FLOOR_DEG <= min(start.sigma_deg) and max(start.sigma_deg) <= CAP_DEG
    assert start.to_dict()["sigma_deg"] == [round(v, 3) for v in start.sigma_deg]


def test_rates_that_do_not_follow_the_gyro_give_no_start():
    def w(t):
        return np.stack([np.sin(t), np.cos(1.3 * t), 0.5 * np.sin(0.7 * t)], 1)

    traj, imu = _reference_and_imu(w, duration_s=10.0)
    rng = np.random.default_rng(1)
    gyro = rng.normal(scale=1.0, size=imu.gyro_rad_s.shape)
    noisy = ImuSamples(imu.stamps_ns, gyro, imu.accel_m_s2)
    assert rotation_from_rates(*_data(traj, noisy), 0.0) is None
    refs, segs, seqs = _data(traj, imu)
    position_only = [ReferenceTrajectory(r.segment, r.trajectory, "position", "rtk") for r in refs]
    assert rotation_from_rates(position_only, segs, seqs, 0.0) is None


def test_the_simulators_hand_held_rig_starts_within_a_tenth_of_a_degree(hand_held):
    run, data = hand_held
    notes = []
    start = rotation_start(recipe_from_dict({}), data, notes.append)
    assert start is not None and "rotation rates" in notes[0] and data.notes == notes
    R = Rotation.from_quat(start.quat_xyzw).as_matrix()
    assert np.degrees(Rotation.from_matrix(run.T_imu_lidar[:3, :3].T @ R).magnitude()) < 0.1
    # the user's prior wins, and the start can be turned off
    prior = recipe_from_dict({"policy": {"prior": {"rpy_deg": [0, 0, 0]}}})
    assert rotation_start(prior, data, notes.append) is None
    off = recipe_from_dict({"train": {"rotation_from_rates": False}})  # YAML 1.1 reads `off`
    assert off.train.rotation_from_rates == "off"
    assert rotation_start(off, data, notes.append) is None


@pytest.mark.parametrize("kind", ["bingham", "gaussian"])
def test_the_policy_starts_at_the_rate_rotation_with_its_spread(kind, hand_held):
    from l2calib.plugins import get_plugin

    start = rotation_start(recipe_from_dict({}), hand_held[1], lambda _m: None)
    spec = get_plugin("l2calib.policies", kind)
    policy = spec.build(spec.config.model_validate({}), rotation_start=start, seed=0)
    R = policy.mode().T_imu_lidar[:3, :3]
    R_start = torch.from_numpy(Rotation.from_quat(start.quat_xyzw).as_matrix())
    assert torch.allclose(R, R_start, atol=1e-6)
    sigma = torch.rad2deg(policy.uncertainty().rotation_sigma_rad)
    assert sigma.max() < 4 * FLOOR_DEG  # concentrated, not uniform (~100°)
    if kind == "bingham":  # per LiDAR axis, as given
        assert sigma.numpy() == pytest.approx(start.sigma_deg, rel=0.1)
