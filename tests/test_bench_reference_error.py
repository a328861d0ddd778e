"""The reference-error experiment's hybrids put exactly one part of the error in at a time."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from benchmarks.experiment_reference_error import KINDS, hybrid_trajectory, reference_vs_truth
from l2calib.trajectory import Trajectory


def _pair():
    """A turning truth and a reference of it in another world frame with slow and fast errors."""
    t = np.arange(400) * 0.05  # 20 s at 20 Hz
    p = np.stack([3 * np.cos(0.3 * t), 3 * np.sin(0.3 * t), 0.1 * np.sin(t)], 1)
    R = Rotation.from_euler("zyx", np.stack([0.3 * t, 0.05 * np.sin(t), 0.02 * t], 1))
    stamps = (t * 1e9).astype(np.int64)
    truth = Trajectory(stamps, p, R.as_quat(), "lidar", "world")
    rng = np.random.default_rng(0)
    dp = np.stack([0.01 * t / 20, -0.02 * t / 20, 0 * t], 1) + 0.002 * rng.standard_normal((400, 3))
    dr = np.stack([0.001 * t / 20, 0 * t, 0 * t], 1) + 1e-4 * rng.standard_normal((400, 3))
    A = Rotation.from_euler("z", 40, degrees=True)  # the reference's own world frame
    p_ref = A.apply(p + dp) + [5.0, -2.0, 1.0]
    R_ref = A * Rotation.from_rotvec(dr) * R
    return truth, Trajectory(stamps, p_ref, R_ref.as_quat(), "lidar", "odom"), dp, dr


def _errors(truth, traj):
    dp = traj.t_world_body - truth.t_world_body
    R_t, R = Rotation.from_quat(truth.quat_xyzw), Rotation.from_quat(traj.quat_xyzw)
    return dp, (R * R_t.inv()).as_rotvec()


def test_each_hybrid_carries_only_its_part_of_the_reference_error():
    truth, ref, dp_true, dr_true = _pair()
    errors = {k: _errors(truth, hybrid_trajectory(truth, ref, k, 2.0)) for k in KINDS}
    # gt is the truth; ct is the reference brought into the truth's frame, its error kept up
    # to what the rigid alignment absorbs (a shift and a small rotation of the drift).
    assert np.abs(np.concatenate(errors["gt"])).max() < 1e-9
    dp, dr = errors["ct"]
    kept = dp - dp.mean(0) - (dp_true - dp_true.mean(0))
    assert np.sqrt((kept**2).mean()) < 0.3 * np.sqrt(((dp_true - dp_true.mean(0)) ** 2).mean())
    assert np.abs(dr - dr_true).max() < 5e-3
    # positions from one, orientations from the other
    np.testing.assert_allclose(errors["ct_pos"][0], dp, atol=1e-9)
    assert np.abs(errors["ct_pos"][1]).max() < 1e-9
    np.testing.assert_allclose(errors["ct_rot"][1], dr, atol=1e-9)
    assert np.abs(errors["ct_rot"][0]).max() < 1e-9
    # slow + fast = all of it, and the fast part has no drift left
    np.testing.assert_allclose(errors["ct_slow"][0] + errors["ct_fast"][0], dp, atol=1e-9)
    np.testing.assert_allclose(errors["ct_slow"][1] + errors["ct_fast"][1], dr, atol=1e-9)
    fast = errors["ct_fast"][0]
    assert abs(fast[-40:].mean(0) - fast[:40].mean(0)).max() < 2e-3 < abs(dp[-1] - dp[0]).max()


def test_an_unknown_kind_is_refused():
    truth, ref, *_ = _pair()
    with pytest.raises(ValueError, match="unknown kind"):
        hybrid_trajectory(truth, ref, "ct_yaw", 2.0)


def test_reference_vs_truth_reads_offset_jitter_and_drift_in_the_lidar_frame():
    t = np.arange(400) * 0.05
    # a rig turning on a straight path: an offset fixed in it is no rigid motion of the path
    p = np.stack([t, 0.5 * np.sin(0.5 * t), 0 * t], 1)
    R = Rotation.from_euler("zyx", np.stack([0.3 * t, 0.05 * np.sin(t), 0 * t], 1))
    truth = Trajectory((t * 1e9).astype(np.int64), p, R.as_quat(), "lidar", "world")
    A = Rotation.from_euler("z", -25, degrees=True)  # the reference's own world frame

    def reference(offset_body, dr_body):
        p_ref = A.apply(p + R.apply(offset_body)) + [1.0, 2.0, 0.0]
        R_ref = A * R * Rotation.from_rotvec(dr_body)
        return Trajectory(truth.stamps_ns, p_ref, R_ref.as_quat(), "lidar", "odom")

    # 2 cm along the LiDAR's y, turning with it: a constant offset, no rotation error
    v = reference_vs_truth(truth, reference([0.0, 0.02, 0.0], np.zeros((400, 3))), 2.0)
    assert v["duration_s"] == pytest.approx(19.95, abs=0.1)
    np.testing.assert_allclose(v["pos_mean_cm"], [0.0, 2.0, 0.0], atol=0.15)
    # roll drifting 0.057 deg in 20 s plus white jitter of 1e-4 rad about each axis
    drift = np.stack([0.001 * t / 20, 0 * t, 0 * t], 1)
    jitter = 1e-4 * np.random.default_rng(1).standard_normal((400, 3))
    v = reference_vs_truth(truth, reference(np.zeros(3), drift + jitter), 2.0)
    assert v["rms_pos_cm"] < 1e-6
    assert v["rot_drift_deg"][0] == pytest.approx(np.rad2deg(0.001) * 18 / 20, rel=0.15)
    assert max(v["rot_drift_deg"][1:]) < 0.01
    np.testing.assert_allclose(v["rot_jitter_deg"], np.rad2deg(1e-4), rtol=0.15)
