from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation, Slerp

from l2calib import geometry as geo
from l2calib.errors import DataError
from l2calib.trajectory import Trajectory, seconds_to_ns


def _traj(rng, n=20, dt_ns=100_000_000):
    stamps = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * dt_ns
    return Trajectory(stamps, rng.normal(size=(n, 3)), Rotation.random(n, random_state=1).as_quat())


def test_interpolation_linear_and_slerp(rng):
    traj = _traj(rng)
    query = traj.stamps_ns[:-1] + 25_000_000  # a quarter between poses
    out = traj.interpolate(query)
    np.testing.assert_allclose(
        out.t_world_body, 0.75 * traj.t_world_body[:-1] + 0.25 * traj.t_world_body[1:], atol=1e-12
    )
    for i in range(len(query)):
        rots = Rotation.from_quat(traj.quat_xyzw[i : i + 2])
        expected = Slerp([0, 1], rots)([0.25]).as_matrix()[0]
        got = geo.quat_to_matrix(torch.from_numpy(out.quat_xyzw[i])).numpy()
        np.testing.assert_allclose(got, expected, atol=1e-12)


def test_exact_stamps_return_the_poses(rng):
    traj = _traj(rng)
    out = traj.interpolate(traj.stamps_ns)
    np.testing.assert_allclose(out.t_world_body, traj.t_world_body, atol=0)
    assert np.array_equal(out.stamps_ns, traj.stamps_ns)


def test_gap_and_range_checks(rng):
    traj = _traj(rng)
    keep = np.ones(len(traj), bool)
    keep[5:9] = False  # a 0.5 s gap
    gappy = Trajectory(traj.stamps_ns[keep], traj.t_world_body[keep], traj.quat_xyzw[keep])
    query = traj.stamps_ns[[2, 6, 15]] + 1
    _, valid = gappy.sample(query, max_gap_s=0.2)
    assert valid.tolist() == [True, False, True]
    _, valid = gappy.sample(query, max_gap_s=1.0)
    assert valid.all()
    with pytest.raises(DataError, match="gap longer than 0.2 s"):
        gappy.interpolate(query, max_gap_s=0.2)
    _, valid = traj.sample(np.array([traj.stamps_ns[0] - 1, traj.stamps_ns[-1] + 1]))
    assert not valid.any()


def test_bad_trajectories_are_rejected(rng):
    with pytest.raises(DataError, match="not strictly increasing at index 1"):
        Trajectory(np.array([5, 5]), np.zeros((2, 3)), np.tile([0, 0, 0, 1.0], (2, 1)))
    with pytest.raises(DataError, match="norm 2.000000"):
        Trajectory(np.array([1, 2]), np.zeros((2, 3)), np.array([[0, 0, 0, 1.0], [0, 0, 0, 2.0]]))
    with pytest.raises(DataError, match="integer array of nanoseconds"):
        Trajectory(np.array([0.1, 0.2]), np.zeros((2, 3)), np.tile([0, 0, 0, 1.0], (2, 1)))
    with pytest.raises(DataError, match="disagree"):
        Trajectory(np.array([1, 2]), np.zeros((3, 3)), np.tile([0, 0, 0, 1.0], (2, 1)))


def test_with_body_and_shift(rng):
    traj = _traj(rng)
    T_body_other = geo.se3_exp(torch.tensor([0.1, -0.2, 0.3, 0.2, 0.1, -0.3])).numpy()
    other = traj.with_body(T_body_other, "lidar")
    np.testing.assert_allclose(
        other.matrices().numpy(), traj.matrices().numpy() @ T_body_other, atol=1e-12
    )
    assert other.body_frame == "lidar"
    assert np.array_equal(traj.shifted(7).stamps_ns, traj.stamps_ns + 7)
    assert len(traj.slice_time(traj.stamps_ns[3], traj.stamps_ns[6])) == 4


def test_seconds_to_ns():
    assert seconds_to_ns(1.5).item() == 1_500_000_000
