"""Batched SO(3)/SE(3) geometry in torch, float64-safe.

Conventions (stated once, used everywhere):

* Quaternions are Hamilton, scalar last: ``quat_xyzw = [x, y, z, w]``. ``q`` and ``-q`` are the
  same rotation; :func:`quat_canonical` picks ``w >= 0``.
* Rotation matrices act on column vectors: ``p_a = R_a_b @ p_b``.
* Homogeneous transforms are ``[..., 4, 4]``; ``T_a_b`` maps points from frame ``b`` into ``a``.
* Tangent vectors of SE(3) are ``xi = [rho, phi]`` (translation part first, then rotation).
* Euler angles for reporting are roll-pitch-yaw in the ZYX convention:
  ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (extrinsic x-y-z = intrinsic z-y'-x'', the ROS/URDF
  convention), returned as ``[roll, pitch, yaw]`` in radians.

All functions are batched over arbitrary leading dimensions and differentiable where that makes
sense. No well-kept library fits cleanly here: scipy's ``Rotation`` is numpy-only (no autograd,
no batching over leading dims), and pypose pulls a large dependency for a few formulas.
"""

from __future__ import annotations

import torch
from torch import Tensor

_EPS = 1e-12


def _small(dtype: torch.dtype) -> float:
    return 1e-6 if dtype == torch.float32 else 1e-10


# --------------------------------------------------------------------------- quaternions
def quat_normalize(q: Tensor) -> Tensor:
    """Normalises quaternions ``[..., 4]`` to unit norm."""
    return q / q.norm(dim=-1, keepdim=True).clamp_min(_EPS)


def quat_canonical(q: Tensor) -> Tensor:
    """Returns the representative with ``w >= 0`` of each quaternion ``[..., 4]`` (xyzw)."""
    sign = torch.where(q[..., 3:4] < 0, -1.0, 1.0).to(q.dtype)
    return q * sign


def quat_conjugate(q: Tensor) -> Tensor:
    """Conjugate (inverse for unit quaternions) of ``[..., 4]`` xyzw quaternions."""
    return torch.cat([-q[..., :3], q[..., 3:]], dim=-1)


def quat_multiply(q1: Tensor, q2: Tensor) -> Tensor:
    """Hamilton product ``q1 ⊗ q2`` of xyzw quaternions ``[..., 4]`` (broadcasting)."""
    x1, y1, z1, w1 = q1.unbind(-1)
    x2, y2, z2, w2 = q2.unbind(-1)
    return torch.stack(
        [
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        ],
        dim=-1,
    )


def quat_to_matrix(quat_xyzw: Tensor) -> Tensor:
    """Rotation matrices ``[..., 3, 3]`` from xyzw quaternions ``[..., 4]`` (normalised first)."""
    q = quat_normalize(quat_xyzw)
    x, y, z, w = q.unbind(-1)
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    rows = [
        1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy),
        2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx),
        2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy),
    ]  # fmt: skip
    return torch.stack(rows, dim=-1).reshape(*q.shape[:-1], 3, 3)


def matrix_to_quat(R: Tensor) -> Tensor:
    """Unit xyzw quaternions ``[..., 4]`` (``w >= 0``) from rotation matrices ``[..., 3, 3]``.

    Uses the numerically stable branch selection of Shepperd's method (largest diagonal term).
    """
    m = R
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    trace = m00 + m11 + m22
    # Four candidate (unnormalised) quaternions, each well conditioned in its own region.
    cand = torch.stack(
        [
            torch.stack(
                [
                    m[..., 2, 1] - m[..., 1, 2],
                    m[..., 0, 2] - m[..., 2, 0],
                    m[..., 1, 0] - m[..., 0, 1],
                    1 + trace,
                ],
                -1,
            ),
            torch.stack(
                [
                    1 + m00 - m11 - m22,
                    m[..., 0, 1] + m[..., 1, 0],
                    m[..., 0, 2] + m[..., 2, 0],
                    m[..., 2, 1] - m[..., 1, 2],
                ],
                -1,
            ),
            torch.stack(
                [
                    m[..., 0, 1] + m[..., 1, 0],
                    1 - m00 + m11 - m22,
                    m[..., 1, 2] + m[..., 2, 1],
                    m[..., 0, 2] - m[..., 2, 0],
                ],
                -1,
            ),
            torch.stack(
                [
                    m[..., 0, 2] + m[..., 2, 0],
                    m[..., 1, 2] + m[..., 2, 1],
                    1 - m00 - m11 + m22,
                    m[..., 1, 0] - m[..., 0, 1],
                ],
                -1,
            ),
        ],
        dim=-2,
    )  # [..., 4, 4]
    key = torch.stack([trace, m00, m11, m22], dim=-1)
    idx = key.argmax(dim=-1)
    q = torch.gather(cand, -2, idx[..., None, None].expand(*idx.shape, 1, 4)).squeeze(-2)
    return quat_canonical(quat_normalize(q))


def quat_slerp(q0: Tensor, q1: Tensor, tau: Tensor | float) -> Tensor:
    """Spherical linear interpolation between unit xyzw quaternions (shortest path).

    Args:
        q0: Start quaternions ``[..., 4]``.
        q1: End quaternions ``[..., 4]``.
        tau: Interpolation fraction in ``[0, 1]``, broadcastable to ``[...]``.

    Returns:
        Unit quaternions ``[..., 4]``; ``tau=0`` gives ``q0``, ``tau=1`` gives ``±q1``.
    """
    tau = torch.as_tensor(tau, dtype=q0.dtype, device=q0.device)
    dot = (q0 * q1).sum(-1)
    q1 = torch.where((dot < 0)[..., None], -q1, q1)
    dot = dot.abs().clamp(max=1.0)
    theta = torch.acos(dot)
    sin_theta = torch.sin(theta)
    near = sin_theta < 1e-9
    safe_sin = torch.where(near, torch.ones_like(sin_theta), sin_theta)
    w0 = torch.where(near, 1 - tau, torch.sin((1 - tau) * theta) / safe_sin)
    w1 = torch.where(near, tau, torch.sin(tau * theta) / safe_sin)
    return quat_normalize(w0[..., None] * q0 + w1[..., None] * q1)


# --------------------------------------------------------------------------- SO(3)
def hat(v: Tensor) -> Tensor:
    """Skew-symmetric matrices ``[..., 3, 3]`` with ``hat(v) @ u == cross(v, u)``."""
    x, y, z = v.unbind(-1)
    o = torch.zeros_like(x)
    return torch.stack([o, -z, y, z, o, -x, -y, x, o], dim=-1).reshape(*v.shape[:-1], 3, 3)


def vee(S: Tensor) -> Tensor:
    """Inverse of :func:`hat` for ``[..., 3, 3]`` (antisymmetric part is used)."""
    return 0.5 * torch.stack(
        [S[..., 2, 1] - S[..., 1, 2], S[..., 0, 2] - S[..., 2, 0], S[..., 1, 0] - S[..., 0, 1]],
        dim=-1,
    )


def so3_exp(phi: Tensor) -> Tensor:
    """Rotation matrices ``[..., 3, 3]`` from rotation vectors ``[..., 3]`` (axis·angle, rad)."""
    theta2 = (phi * phi).sum(-1, keepdim=True)[..., None]
    theta = theta2.sqrt()
    small = theta2 < _small(phi.dtype)
    safe = torch.where(small, torch.ones_like(theta), theta)
    a = torch.where(small, 1 - theta2 / 6, torch.sin(safe) / safe)
    b = torch.where(small, 0.5 - theta2 / 24, (1 - torch.cos(safe)) / (safe * safe))
    K = hat(phi)
    eye = torch.eye(3, dtype=phi.dtype, device=phi.device).expand_as(K)
    return eye + a * K + b * (K @ K)


def rotation_angle(R: Tensor) -> Tensor:
    """Geodesic angle ``[...]`` (radians, in ``[0, π]``) of rotation matrices ``[..., 3, 3]``.

    Computed as ``atan2(|vee(R)|, (tr R - 1)/2)``, accurate near 0 and π (unlike ``arccos``).
    """
    cos = 0.5 * (R[..., 0, 0] + R[..., 1, 1] + R[..., 2, 2] - 1)
    sin = vee(R).norm(dim=-1)
    return torch.atan2(sin, cos)


def so3_log(R: Tensor) -> Tensor:
    """Rotation vectors ``[..., 3]`` (radians) of rotation matrices ``[..., 3, 3]``.

    Goes through the quaternion, which is well conditioned for all angles including π.
    """
    q = matrix_to_quat(R)  # w >= 0, so angle in [0, π]
    v = q[..., :3]
    s = v.norm(dim=-1, keepdim=True)
    angle = 2 * torch.atan2(s, q[..., 3:4])
    small = s < 1e-12
    scale = torch.where(small, 2.0 / q[..., 3:4].clamp_min(_EPS), angle / s.clamp_min(_EPS))
    return v * scale


def so3_left_jacobian(phi: Tensor) -> Tensor:
    """Left Jacobian ``J_l(phi)`` ``[..., 3, 3]`` of SO(3) (used by the SE(3) exponential)."""
    theta2 = (phi * phi).sum(-1, keepdim=True)[..., None]
    theta = theta2.sqrt()
    small = theta2 < _small(phi.dtype)
    safe = torch.where(small, torch.ones_like(theta), theta)
    b = torch.where(small, 0.5 - theta2 / 24, (1 - torch.cos(safe)) / (safe * safe))
    c = torch.where(small, 1.0 / 6 - theta2 / 120, (safe - torch.sin(safe)) / (safe**3))
    K = hat(phi)
    eye = torch.eye(3, dtype=phi.dtype, device=phi.device).expand_as(K)
    return eye + b * K + c * (K @ K)


# --------------------------------------------------------------------------- SE(3)
def make_transform(R: Tensor, t: Tensor) -> Tensor:
    """Homogeneous transforms ``[..., 4, 4]`` from rotations ``[..., 3, 3]`` and translations."""
    batch = torch.broadcast_shapes(R.shape[:-2], t.shape[:-1])
    T = torch.zeros(*batch, 4, 4, dtype=R.dtype, device=R.device)
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1
    return T


def transform_from_quat(quat_xyzw: Tensor, t: Tensor) -> Tensor:
    """Transforms ``[..., 4, 4]`` from xyzw quaternions and translations ``[..., 3]``."""
    return make_transform(quat_to_matrix(quat_xyzw), t)


def transform_inverse(T: Tensor) -> Tensor:
    """Inverse of rigid transforms ``[..., 4, 4]`` (``T_b_a`` from ``T_a_b``)."""
    R_inv = T[..., :3, :3].transpose(-1, -2)
    return make_transform(R_inv, -(R_inv @ T[..., :3, 3:4])[..., 0])


def transform_points(T: Tensor, points: Tensor) -> Tensor:
    """Applies ``T [..., 4, 4]`` to points ``[..., N, 3]``: ``p_a = R_a_b p_b + t_a_b``."""
    return points @ T[..., :3, :3].transpose(-1, -2) + T[..., None, :3, 3]


def se3_exp(xi: Tensor) -> Tensor:
    """Transforms ``[..., 4, 4]`` from twists ``xi = [rho, phi]`` ``[..., 6]``."""
    rho, phi = xi[..., :3], xi[..., 3:]
    R = so3_exp(phi)
    t = (so3_left_jacobian(phi) @ rho[..., None])[..., 0]
    return make_transform(R, t)


def se3_log(T: Tensor) -> Tensor:
    """Twists ``[rho, phi]`` ``[..., 6]`` of transforms ``[..., 4, 4]`` (inverse of se3_exp)."""
    phi = so3_log(T[..., :3, :3])
    J = so3_left_jacobian(phi)
    rho = torch.linalg.solve(J, T[..., :3, 3:4])[..., 0]
    return torch.cat([rho, phi], dim=-1)


# --------------------------------------------------------------------------- Euler (reporting)
def euler_rpy_to_matrix(rpy: Tensor) -> Tensor:
    """Rotation matrices from ``[roll, pitch, yaw]`` radians: ``R = Rz(yaw) Ry(pitch) Rx(roll)``."""
    r, p, y = rpy.unbind(-1)
    cr, sr, cp, sp, cy, sy = r.cos(), r.sin(), p.cos(), p.sin(), y.cos(), y.sin()
    rows = [
        cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr,
        sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr,
        -sp, cp * sr, cp * cr,
    ]  # fmt: skip
    return torch.stack(rows, dim=-1).reshape(*rpy.shape[:-1], 3, 3)


def matrix_to_euler_rpy(R: Tensor) -> Tensor:
    """``[roll, pitch, yaw]`` radians (ZYX convention, see module doc) from ``[..., 3, 3]``.

    At gimbal lock (``|pitch| = π/2``) roll is set to 0 and yaw absorbs the remaining rotation.
    """
    sp = (-R[..., 2, 0]).clamp(-1.0, 1.0)
    pitch = torch.asin(sp)
    cp = torch.sqrt(R[..., 2, 1] ** 2 + R[..., 2, 2] ** 2)
    lock = cp < 1e-9
    roll = torch.where(lock, torch.zeros_like(pitch), torch.atan2(R[..., 2, 1], R[..., 2, 2]))
    yaw_free = torch.atan2(R[..., 1, 0], R[..., 0, 0])
    yaw_lock = torch.atan2(-R[..., 0, 1], R[..., 1, 1])
    yaw = torch.where(lock, yaw_lock, yaw_free)
    return torch.stack([roll, pitch, yaw], dim=-1)
