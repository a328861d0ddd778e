from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation, Slerp

from l2calib import geometry as geo


def _random_quats(rng, n):
    return Rotation.random(n, random_state=rng.integers(1 << 31)).as_quat()  # xyzw


def test_quat_matrix_roundtrip_matches_scipy(rng):
    q = _random_quats(rng, 500)
    R = geo.quat_to_matrix(torch.from_numpy(q))
    np.testing.assert_allclose(R.numpy(), Rotation.from_quat(q).as_matrix(), atol=1e-12)
    q_back = geo.matrix_to_quat(R).numpy()
    q_canon = q * np.sign(q[:, 3:4])
    np.testing.assert_allclose(q_back, q_canon, atol=1e-12)
    assert np.all(q_back[:, 3] >= 0)


def test_matrix_to_quat_near_pi_is_stable():
    axes = torch.tensor([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [1.0, 1.0, 0]])
    axes = axes / axes.norm(dim=-1, keepdim=True)
    for angle in (np.pi, np.pi - 1e-9, 1e-12, 0.0):
        R = geo.so3_exp(axes * angle)
        q = geo.matrix_to_quat(R)
        np.testing.assert_allclose(geo.quat_to_matrix(q).numpy(), R.numpy(), atol=1e-12)


def test_so3_exp_log_roundtrip_and_scipy(rng):
    q = _random_quats(rng, 300)
    rotvec = Rotation.from_quat(q).as_rotvec()
    R = geo.so3_exp(torch.from_numpy(rotvec))
    np.testing.assert_allclose(R.numpy(), Rotation.from_rotvec(rotvec).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(geo.so3_log(R).numpy(), rotvec, atol=1e-9)
    tiny = torch.tensor([[1e-10, -2e-10, 3e-10]])
    np.testing.assert_allclose(geo.so3_log(geo.so3_exp(tiny)).numpy(), tiny.numpy(), atol=1e-16)


def test_rotation_angle_matches_scipy(rng):
    q = _random_quats(rng, 200)
    R = geo.quat_to_matrix(torch.from_numpy(q))
    np.testing.assert_allclose(
        geo.rotation_angle(R).numpy(), Rotation.from_quat(q).magnitude(), atol=1e-12
    )


def test_se3_exp_log_inverse_compose(rng):
    xi = torch.from_numpy(rng.normal(size=(100, 6)))
    phi_norm = xi[:, 3:].norm(dim=-1, keepdim=True)
    xi[:, 3:] *= torch.clamp(3.0 / phi_norm, max=1.0)  # the log returns angles in [0, π]
    T = geo.se3_exp(xi)
    np.testing.assert_allclose(geo.se3_log(T).numpy(), xi.numpy(), atol=1e-9)
    eye = T @ geo.transform_inverse(T)
    np.testing.assert_allclose(eye.numpy(), np.tile(np.eye(4), (100, 1, 1)), atol=1e-12)
    pts = torch.from_numpy(rng.normal(size=(100, 7, 3)))
    moved = geo.transform_points(T, pts)
    manual = (T[:, None, :3, :3] @ pts[..., None])[..., 0] + T[:, None, :3, 3]
    np.testing.assert_allclose(moved.numpy(), manual.numpy(), atol=1e-12)


def test_quat_multiply_matches_matrix_product(rng):
    q1, q2 = (torch.from_numpy(_random_quats(rng, 50)) for _ in range(2))
    lhs = geo.quat_to_matrix(geo.quat_multiply(q1, q2))
    rhs = geo.quat_to_matrix(q1) @ geo.quat_to_matrix(q2)
    np.testing.assert_allclose(lhs.numpy(), rhs.numpy(), atol=1e-12)
    inv = geo.quat_multiply(q1, geo.quat_conjugate(q1))
    np.testing.assert_allclose(geo.quat_canonical(inv).numpy(), [[0, 0, 0, 1]] * 50, atol=1e-12)


def test_slerp_matches_scipy(rng):
    q = _random_quats(rng, 2)
    taus = np.linspace(0, 1, 11)
    ref = Slerp([0, 1], Rotation.from_quat(q))(taus).as_matrix()
    out = geo.quat_slerp(
        torch.from_numpy(np.repeat(q[:1], 11, 0)),
        torch.from_numpy(np.repeat(q[1:], 11, 0)),
        torch.from_numpy(taus),
    )
    np.testing.assert_allclose(geo.quat_to_matrix(out).numpy(), ref, atol=1e-12)


@pytest.mark.parametrize("pitch", [0.3, np.pi / 2, -np.pi / 2])
def test_euler_rpy_convention_and_roundtrip(rng, pitch):
    rpy = np.column_stack(
        [rng.uniform(-np.pi, np.pi, 50), np.full(50, pitch), rng.uniform(-np.pi, np.pi, 50)]
    )
    R = geo.euler_rpy_to_matrix(torch.from_numpy(rpy))
    # R = Rz(yaw) Ry(pitch) Rx(roll) == scipy extrinsic 'xyz' with [roll, pitch, yaw]
    np.testing.assert_allclose(R.numpy(), Rotation.from_euler("xyz", rpy).as_matrix(), atol=1e-12)
    back = geo.matrix_to_euler_rpy(R)
    np.testing.assert_allclose(geo.euler_rpy_to_matrix(back).numpy(), R.numpy(), atol=1e-7)
    if abs(pitch) < 1:
        np.testing.assert_allclose(back.numpy(), rpy, atol=1e-10)


def test_float32_inputs_stay_float32():
    q = torch.tensor([[0.1, 0.2, 0.3, 0.9]], dtype=torch.float32)
    assert geo.quat_to_matrix(q).dtype == torch.float32
    assert geo.so3_log(geo.quat_to_matrix(q)).dtype == torch.float32
