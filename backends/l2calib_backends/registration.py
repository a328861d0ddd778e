"""Batched scan-to-map registration: the LiDAR measurement of the GTSAM backend.

For B filters at once, Gauss–Newton on the point-to-plane residuals of one deskewed scan (IMU
frame, see :func:`l2calib_backends.iekf.deskew`) against the plane map, started from the
IMU-predicted pose and *without* a prior: the IMU information enters the factor graph through
the preintegrated IMU factor instead, so adding it here as well would count it twice.

The result is a measured IMU pose ``T_world_imu`` and its information matrix ``HᵀWH`` at the
solution, which is what the linearised point-to-plane factors would contribute to the graph
(FAST-LIO's update uses the same ``HᵀWH``). It is expressed in GTSAM's ``Pose3`` tangent
``[δθ, δt_body]`` (retraction ``T Exp(ξ)``, so ``δp_world = R δt_body``) for a
``PriorFactorPose3``. Directions the scan does not constrain (a corridor, a few planes) get a tiny
information ``damping`` rather than a guess, so the graph leaves them to the IMU.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from l2calib import geometry as geo
from l2calib_backends.update import PlaneQuery, plane_normal_equations


@dataclass(frozen=True)
class RegistrationSettings:
    """Settings of :func:`register_scans`.

    Attributes:
        max_iterations: Gauss–Newton iterations (planes re-associated at each).
        point_sigma_m: Standard deviation of a point-to-plane residual (m).
        info_scale: Multiplies the information (``< 1`` inflates the covariance: residuals of
            neighbouring points are correlated, so ``HᵀWH`` is overconfident).
        gate_scale: ``|z| < gate_scale · sqrt(range)`` (FAST-LIO's plausibility test).
        min_correspondences: Fewer matched points: no measurement for that filter.
        damping: Information added on the diagonal (1/rad², 1/m²) to keep it invertible
            (σ ≈ 30 rad or m: no constraint, but a well-conditioned factor).
        converge_eps: Stop when every step is below this.
    """

    max_iterations: int = 4
    point_sigma_m: float = 0.05
    info_scale: float = 1.0
    gate_scale: float = 0.11
    min_correspondences: int = 20
    damping: float = 1e-3
    converge_eps: float = 1e-4


@dataclass(frozen=True)
class Registration:
    """Registered IMU poses of B filters.

    Attributes:
        R: ``[B, 3, 3]`` ``R_world_imu``.
        p: ``[B, 3]`` ``t_world_imu`` (m).
        information: ``[B, 6, 6]`` information in GTSAM's ``Pose3`` tangent ``[δθ, δt_body]``.
        num_matches: ``[B]`` point-to-plane matches of the last iteration.
        ok: ``[B]`` registrations usable as measurements (enough matches, finite).
    """

    R: Tensor
    p: Tensor
    information: Tensor
    num_matches: Tensor
    ok: Tensor


def register_scans(
    R0: Tensor,
    p0: Tensor,
    q_imu: Tensor,
    mask: Tensor,
    ranges: Tensor,
    query: PlaneQuery,
    settings: RegistrationSettings,
) -> Registration:
    """Registers B deskewed scans to the map, starting from the predicted IMU poses.

    Args:
        R0: ``[B, 3, 3]`` predicted ``R_world_imu``.
        p0: ``[B, 3]`` predicted ``t_world_imu`` (m).
        q_imu: ``[B, m, 3]`` deskewed points in the IMU frame at the scan end.
        mask: ``[B, m]`` usable points.
        ranges: ``[B, m]`` point ranges (m), for the residual gate.
        query: Plane lookup ``query(world_points, widen) -> (normal, d, ok)``.
        settings: Registration settings.
    """
    B = R0.shape[0]
    dtype = R0.dtype
    gate = settings.gate_scale * ranges.clamp_min(0.1).sqrt()
    w_sigma = 1.0 / settings.point_sigma_m**2
    eye6 = torch.eye(6, dtype=dtype).expand(B, 6, 6)
    R, p = R0, p0
    HtWH = torch.zeros(B, 6, 6, dtype=dtype)
    n_ok = torch.zeros(B, dtype=torch.int64)
    for it in range(settings.max_iterations):
        HtWH, HtWz, n_ok = plane_normal_equations(R, p, q_imu, mask, gate, query, it == 0, w_sigma)
        # Levenberg-style damping scaled to the problem keeps unobserved directions still.
        lam = 1e-9 * HtWH.diagonal(dim1=-2, dim2=-1).sum(-1).clamp_min(1.0)
        delta = -torch.linalg.solve(HtWH + lam[:, None, None] * eye6, HtWz[..., None])[..., 0]
        enough = n_ok >= settings.min_correspondences
        delta = torch.where(enough[:, None] & torch.isfinite(delta), delta, 0.0)
        R = R @ geo.so3_exp(delta[:, :3])
        p = p + delta[:, 3:]
        if float(delta.abs().max()) < settings.converge_eps:
            break
    # Information in [δθ, δp_world] -> GTSAM's [δθ, δt_body]: δp_world = R δt_body.
    J = torch.eye(6, dtype=dtype).repeat(B, 1, 1)
    J[:, 3:, 3:] = R
    info = settings.info_scale * (J.transpose(-1, -2) @ HtWH @ J) + settings.damping * eye6
    info = 0.5 * (info + info.transpose(-1, -2))
    finite = torch.isfinite(R).flatten(1).all(1) & torch.isfinite(p).all(1)
    finite &= torch.isfinite(info).flatten(1).all(1)
    ok = (n_ok >= settings.min_correspondences) & finite
    R = torch.where(finite[:, None, None], R, R0)
    p = torch.where(finite[:, None], p, p0)
    info = torch.where(finite[:, None, None], info, settings.damping * eye6)
    return Registration(R, p, info, n_ok, ok)
