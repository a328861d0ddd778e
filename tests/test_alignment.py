"""Umeyama and APE cross-checked against evo (GPL-3, test-only dependency)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from l2calib import geometry as geo
from l2calib.alignment import ape, associate, umeyama
from l2calib.errors import DataError
from l2calib.trajectory import Trajectory

evo_geometry = pytest.importorskip("evo.core.geometry")
from evo.core import metrics  # noqa: E402
from evo.core.trajectory import PoseTrajectory3D  # noqa: E402


def _random_case(rng, n=60):
    stamps = np.arange(n, dtype=np.int64) * 100_000_000 + 10**18
    pos = np.cumsum(rng.normal(scale=0.5, size=(n, 3)), axis=0)
    quat = Rotation.random(n, random_state=rng.integers(1 << 31)).as_quat()
    ref = Trajectory(stamps, pos, quat, "lidar")
    offset = geo.se3_exp(torch.from_numpy(rng.normal(scale=2.0, size=6))).numpy()
    noise_rot = Rotation.from_rotvec(rng.normal(scale=0.02, size=(n, 3)))
    est_T = offset @ ref.matrices().numpy()
    est_T[:, :3, :3] = est_T[:, :3, :3] @ noise_rot.as_matrix()
    est_T[:, :3, 3] += rng.normal(scale=0.05, size=(n, 3))
    return ref, Trajectory.from_matrices(stamps, est_T, "lidar")


def _to_evo(traj: Trajectory) -> PoseTrajectory3D:
    wxyz = np.roll(traj.quat_xyzw, 1, axis=1)
    return PoseTrajectory3D(traj.t_world_body.copy(), wxyz, traj.stamps_s)


@pytest.mark.parametrize("with_scale", [False, True])
def test_umeyama_matches_evo_on_100_random_trajectories(rng, with_scale):
    for _ in range(100):
        ref, est = _random_case(rng)
        x, y = est.t_world_body, ref.t_world_body
        r_evo, t_evo, c_evo = evo_geometry.umeyama_alignment(x.T, y.T, with_scale)
        R, t, s = umeyama(torch.from_numpy(x), torch.from_numpy(y), with_scale=with_scale)
        np.testing.assert_allclose(R.numpy(), r_evo, atol=1e-9)
        np.testing.assert_allclose(t.numpy(), t_evo, atol=1e-9)
        np.testing.assert_allclose(float(s), c_evo, atol=1e-9)


@pytest.mark.parametrize("with_scale", [False, True])
def test_ape_matches_evo_on_100_random_trajectories(rng, with_scale):
    for _ in range(100):
        ref, est = _random_case(rng)
        ours = ape(ref, est, align=True, with_scale=with_scale)
        evo_ref, evo_est = _to_evo(ref), _to_evo(est)
        evo_est.align(evo_ref, correct_scale=with_scale)
        for relation, values in (
            (metrics.PoseRelation.translation_part, ours.e_t),
            (metrics.PoseRelation.rotation_angle_rad, ours.e_r),
        ):
            metric = metrics.APE(relation)
            metric.process_data((evo_ref, evo_est))
            np.testing.assert_allclose(values, metric.error, atol=1e-9)


def test_batched_masked_umeyama_equals_per_candidate(rng):
    K, N = 5, 40
    src = torch.from_numpy(rng.normal(size=(N, 3)))
    dst = torch.from_numpy(rng.normal(size=(K, N, 3)))
    valid = torch.from_numpy(rng.random((K, N)) > 0.3)
    R, t, s = umeyama(src, dst, valid, with_scale=True)
    for k in range(K):
        m = valid[k]
        Rk, tk, sk = umeyama(src[m], dst[k, m], with_scale=True)
        np.testing.assert_allclose(R[k].numpy(), Rk.numpy(), atol=1e-12)
        np.testing.assert_allclose(t[k].numpy(), tk.numpy(), atol=1e-12)
        np.testing.assert_allclose(float(s[k]), float(sk), atol=1e-12)


def test_umeyama_recovers_exact_transform(rng):
    src = torch.from_numpy(rng.normal(size=(30, 3)))
    T = geo.se3_exp(torch.from_numpy(rng.normal(size=6)))
    dst = geo.transform_points(T, src)
    R, t, s = umeyama(src, dst)
    np.testing.assert_allclose(R.numpy(), T[:3, :3].numpy(), atol=1e-12)
    np.testing.assert_allclose(t.numpy(), T[:3, 3].numpy(), atol=1e-12)


def test_associate_interpolates_and_rejects_disjoint(rng):
    ref, est = _random_case(rng)
    shifted = est.shifted(30_000_000)  # 30 ms later: reference is interpolated
    r, e = associate(ref, shifted)
    assert np.array_equal(r.stamps_ns, e.stamps_ns)
    assert len(e) == len(est) - 1  # the last one falls outside the reference
    with pytest.raises(DataError, match="fall inside the lidar reference"):
        associate(ref, est.shifted(10**12))
