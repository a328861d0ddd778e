"""The noise-free IMU is exactly consistent with the ground-truth trajectory written to disk."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from l2calib.io.trajectory_files import read_tum
from l2calib.sim import SimConfig, simulate, write_run


def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    x1, y1, z1, w1 = a
    x2, y2, z2, w2 = b
    return np.array(
        [
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        ]
    )


def _rk4_integrate(stamps_ns, gyro, accel, q0, p0, v0, g):
    """Classic RK4 over pairs of samples: a step of 2·dt uses samples k, k+1 (midpoint), k+2."""

    def f(x, w, a):
        q = x[:4] / np.linalg.norm(x[:4])
        R = Rotation.from_quat(q).as_matrix()
        return np.concatenate([0.5 * _qmul(q, np.r_[w, 0.0]), x[7:], R @ a + g])

    x = np.concatenate([q0, p0, v0])
    out, idx = [x.copy()], [0]
    t = (stamps_ns - stamps_ns[0]) / 1e9
    for k in range(0, len(t) - 2, 2):
        h = t[k + 2] - t[k]
        k1 = f(x, gyro[k], accel[k])
        k2 = f(x + h / 2 * k1, gyro[k + 1], accel[k + 1])
        k3 = f(x + h / 2 * k2, gyro[k + 1], accel[k + 1])
        k4 = f(x + h * k3, gyro[k + 2], accel[k + 2])
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        x[:4] /= np.linalg.norm(x[:4])
        out.append(x.copy())
        idx.append(k + 2)
    return np.array(idx), np.array(out)


@pytest.mark.parametrize(("profile", "rig"), [("handheld", "paper-handheld"), ("ugv", "mcd")])
def test_noise_free_imu_integrates_to_gt_imu_tum(tmp_path, profile, rig):
    cfg = SimConfig.model_validate(
        {
            "duration_s": 10.2,
            "seed": 4,
            "motion": {"profile": profile, "still_start_s": 0.5},
            "rig": {"preset": rig, "time_offset_s": 0.0125},
            "lidar": {"columns": 64} if rig != "paper-handheld" else {},
            "imu": {"noise": False, "rate_hz": 200},
        }
    )
    run = simulate(cfg)
    files = write_run(run, tmp_path, write_bag_file=False)
    gt = read_tum(files["gt_imu"], "imu")
    imu = run.imu
    assert imu.stamps_ns[0] == gt.stamps_ns[0]
    T0 = gt.matrices().numpy()[0]
    q0 = Rotation.from_matrix(T0[:3, :3]).as_quat()
    v0 = run.imu_velocity(imu.stamps_ns[:1])[0]  # the true initial velocity (0: still start)
    g = np.array([0.0, 0.0, -cfg.gravity_m_s2])
    idx, states = _rk4_integrate(
        imu.stamps_ns, imu.gyro_rad_s, imu.accel_m_s2, q0, T0[:3, 3], v0, g
    )
    # 200 Hz IMU and 100 Hz GT: every RK4 node is a GT stamp.
    at = np.searchsorted(gt.stamps_ns, imu.stamps_ns[idx])
    keep = (at < len(gt)) & ((imu.stamps_ns[idx] - imu.stamps_ns[0]) <= 10_000_000_000)
    assert keep.sum() >= 1000
    assert np.array_equal(gt.stamps_ns[at[keep]], imu.stamps_ns[idx][keep])
    T_gt = gt.matrices().numpy()[at[keep]]
    pos_err = np.linalg.norm(states[keep, 4:7] - T_gt[:, :3, 3], axis=1)
    rot_err = Rotation.from_quat(states[keep, :4]).inv() * Rotation.from_matrix(T_gt[:, :3, :3])
    rot_err_deg = np.degrees(np.linalg.norm(rot_err.as_rotvec(), axis=1))
    assert pos_err.max() < 1e-3, pos_err.max()  # < 1 mm over 10 s
    assert rot_err_deg.max() < 0.01, rot_err_deg.max()  # < 0.01 deg over 10 s
    assert run.stats["path_length_m"] > 5.0  # the rig did move


def test_accelerometer_reads_plus_g_up_at_rest_in_the_imu_frame():
    # MCD rig: the IMU is mounted upside down (R_imu_lidar ~ diag(1, -1, -1)).
    cfg = SimConfig.model_validate(
        {
            "duration_s": 1.0,
            "rig": {"preset": "mcd"},
            "motion": {"still_start_s": 1.0},
            "lidar": {"columns": 64},
            "imu": {"noise": False},
        }
    )
    run = simulate(cfg)
    R_wi = run.imu_poses(run.imu.stamps_ns[:1])[0][:3, :3]
    expected = R_wi.T @ np.array([0.0, 0.0, cfg.gravity_m_s2])
    assert np.allclose(run.imu.accel_m_s2, expected, atol=1e-12)
    assert np.allclose(run.imu.gyro_rad_s, 0.0, atol=1e-15)
    assert abs(np.linalg.norm(run.imu.accel_m_s2[0]) - 9.81) < 1e-12


def test_imu_noise_statistics_follow_the_preset():
    cfg = SimConfig.model_validate(
        {
            "duration_s": 30.0,
            "imu": {"model": "bmi088"},
            "motion": {"still_start_s": 30.0},
            "lidar": {"columns": 64},
        }
    )
    run = simulate(cfg)
    e, spec = run.imu_errors, run.imu_spec
    rate = 200.0
    # 6000 samples x 3 axes: the sample std is within ~2 % of the truth (5 % tolerance).
    assert abs(e.gyro_noise_rad_s.std() / (spec.gyro_noise_density * np.sqrt(rate)) - 1) < 0.05
    assert abs(e.accel_noise_m_s2.std() / (spec.accel_noise_density * np.sqrt(rate)) - 1) < 0.05
    # At rest the readings are bias + noise around the exact values.
    assert np.allclose(run.imu.gyro_rad_s, e.gyro_bias_rad_s + e.gyro_noise_rad_s, atol=1e-12)
