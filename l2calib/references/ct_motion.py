"""The per-scan continuous-time motion of ``ct-lidar`` (:mod:`l2calib.references.ct_odometry`).

R(τ) = R_b · Exp(τ ω + τ² α)        t(τ) = t_b + τ v + τ² a        τ = point time − scan start
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from l2calib.data import NS_PER_S


def _skew(v: np.ndarray) -> np.ndarray:
    """``[N, 3, 3]`` cross-product matrices of ``v`` ``[N, 3]``."""
    z = np.zeros(len(v))
    return np.stack(
        [z, -v[:, 2], v[:, 1], v[:, 2], z, -v[:, 0], -v[:, 1], v[:, 0], z], axis=1
    ).reshape(-1, 3, 3)


def right_jacobian(phi: np.ndarray) -> np.ndarray:
    """``[N, 3, 3]`` right Jacobian of SO(3) at rotation vectors ``phi`` ``[N, 3]``."""
    th = np.linalg.norm(phi, axis=1)
    small = th < 1e-6
    ths = np.where(small, 1.0, th)
    c1 = np.where(small, 0.5 - th**2 / 24, (1 - np.cos(ths)) / ths**2)
    c2 = np.where(small, 1 / 6 - th**2 / 120, (ths - np.sin(ths)) / ths**3)
    K = _skew(phi)
    return np.eye(3) - c1[:, None, None] * K + c2[:, None, None] * (K @ K)


@dataclass(frozen=True)
class ScanMotion:
    """The motion of one scan (module docstring); ``R_b`` ``[3, 3]``, the rest ``[3]``."""

    R_b: np.ndarray
    t_b: np.ndarray
    omega: np.ndarray
    alpha: np.ndarray
    v: np.ndarray
    a: np.ndarray

    def rotvec(self, tau: np.ndarray) -> np.ndarray:
        """``[N, 3]`` rotation vector ``τω + τ²α`` at times ``tau`` ``[N]`` (s)."""
        return tau[:, None] * self.omega + (tau**2)[:, None] * self.alpha

    def poses(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``R [N, 3, 3]`` and ``t [N, 3]`` of ``T_world_lidar`` at ``tau`` ``[N]`` (s)."""
        R = self.R_b @ Rotation.from_rotvec(self.rotvec(tau)).as_matrix()
        t = self.t_b + tau[:, None] * self.v + (tau**2)[:, None] * self.a
        return R, t

    def transform(self, points: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """``[N, 3]`` world coordinates of LiDAR points ``[N, 3]`` taken at ``tau`` ``[N]``."""
        R, t = self.poses(tau)
        return np.einsum("nij,nj->ni", R, points) + t

    def propagate(self, dt: float) -> tuple[ScanMotion, np.ndarray]:
        """The motion's state ``dt`` seconds on (the next scan's prediction) and its Jacobian.

        Returns:
            The predicted motion and ``F`` ``[18, 18]``, the derivative of the predicted state's
            tangent-space error with respect to this one's (update order of :meth:`retract`).
        """
        tau = np.array([dt])
        R, t = self.poses(tau)
        phi = self.rotvec(tau)
        Jr = right_jacobian(phi)[0]
        rate = Jr @ (self.omega + 2 * dt * self.alpha)
        R_rel = Rotation.from_rotvec(phi[0]).as_matrix()
        pred = ScanMotion(R[0], t[0], rate, R_rel.T @ self.alpha, self.v + 2 * dt * self.a, self.a)
        F = np.eye(18)
        F[0:3, 0:3] = R_rel.T
        F[0:3, 6:9] = dt * Jr
        F[0:3, 9:12] = dt**2 * Jr
        F[3:6, 12:15] = dt * np.eye(3)
        F[3:6, 15:18] = dt**2 * np.eye(3)
        F[6:9, 9:12] = 2 * dt * np.eye(3)
        F[9:12, 9:12] = R_rel.T
        F[12:15, 15:18] = 2 * dt * np.eye(3)
        return pred, F

    def retract(self, dx: np.ndarray) -> ScanMotion:
        """Applies an 18-vector update ``[δθ (right), δt, δω, δα, δv, δa]``."""
        dR = Rotation.from_rotvec(dx[:3]).as_matrix()
        return ScanMotion(
            self.R_b @ dR,
            self.t_b + dx[3:6],
            self.omega + dx[6:9],
            self.alpha + dx[9:12],
            self.v + dx[12:15],
            self.a + dx[15:18],
        )


def prior_residual(m: ScanMotion, pred: ScanMotion) -> np.ndarray:
    """``[18]`` difference of ``m`` from ``pred`` (update order of :meth:`ScanMotion.retract`)."""
    rot = Rotation.from_matrix(pred.R_b.T @ m.R_b).as_rotvec()
    return np.concatenate(
        [
            rot,
            m.t_b - pred.t_b,
            m.omega - pred.omega,
            m.alpha - pred.alpha,
            m.v - pred.v,
            m.a - pred.a,
        ]
    )


def sample_poses(
    stamps_ns: np.ndarray, motions: list[ScanMotion], last_end_ns: int, per_scan: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Poses at ``per_scan`` even times in every scan interval plus the last scan's end.

    Returns:
        Stamps ``[N]`` int64 ns, rotations ``[N, 3, 3]`` and positions ``[N, 3]``
        (``T_world_lidar``).
    """
    ends = np.append(stamps_ns[1:], last_end_ns)
    out_t, out_R, out_p = [], [], []
    for k, m in enumerate(motions):
        span = int(ends[k] - stamps_ns[k])
        offs = np.unique((np.arange(per_scan) * span) // per_scan)
        if k == len(motions) - 1:
            offs = np.append(offs, span) if span > offs[-1] else offs
        R, t = m.poses(offs / NS_PER_S)
        out_t.append(stamps_ns[k] + offs)
        out_R.append(R)
        out_p.append(t)
    return np.concatenate(out_t), np.concatenate(out_R), np.concatenate(out_p)
