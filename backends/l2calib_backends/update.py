"""Iterated point-to-plane measurement update of K filters (FAST-LIO2 style).

For IMU-frame points ``q`` (LiDAR points moved by the candidate extrinsic and deskewed to the
scan end), each iteration re-associates ``p_w = R q + p`` with the map's planes, forms residuals
``z = nᵀ p_w + d`` and solves the Gauss–Newton step of

    ‖z + H δ‖²_W + ‖(x ⊟ x̂) + δ‖²_{P̂⁻¹},

which is the iterated EKF update of FAST-LIO (eq. 18 of Xu & Zhang 2021, with J ≈ I).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import torch
from torch import Tensor

from l2calib_backends.state import FilterState

PlaneQuery = Callable[[Tensor, bool], tuple[Tensor, Tensor, Tensor]]


@dataclass(frozen=True)
class UpdateSettings:
    """Settings of the iterated update."""

    max_iterations: int = 4
    point_sigma_m: float = 0.05
    gate_scale: float = 0.11  # |z| < gate_scale * sqrt(range), FAST-LIO's plausibility test
    min_correspondences: int = 20
    converge_eps: float = 1e-4


def plane_normal_equations(
    R: Tensor,
    p: Tensor,
    q_imu: Tensor,
    mask: Tensor,
    gate: Tensor,
    query: PlaneQuery,
    widen: bool,
    w_sigma: float,
) -> tuple[Tensor, Tensor, Tensor]:
    """Point-to-plane normal equations of K IMU poses, shared by the IEKF and the GTSAM backend.

    Associates ``p_w = R q + p`` with the map's planes and linearises ``z = nᵀ p_w + d`` in the
    perturbation ``[δθ, δp]`` (``R = R̂ Exp(δθ)``, ``p = p̂ + δp``, world-frame ``δp``).

    Args:
        R: ``[K, 3, 3]`` IMU orientations ``R_world_imu``.
        p: ``[K, 3]`` IMU positions ``t_world_imu`` (m).
        q_imu: ``[K, m, 3]`` points in the IMU frame.
        mask: ``[K, m]`` or ``[m]`` usable points.
        gate: ``[m]`` or ``[K, m]`` largest accepted ``|z|`` (m).
        query: Plane lookup (see :func:`iterated_update`).
        widen: Ask for the wider neighbour search.
        w_sigma: Weight ``1/σ²`` of a residual (1/m²).

    Returns:
        ``HᵀWH [K, 6, 6]``, ``HᵀWz [K, 6]`` and the ``[K]`` number of matched points.
    """
    p_w = q_imu @ R.transpose(-1, -2) + p[:, None, :]
    normal, d, ok = query(p_w, widen)
    z = (normal * p_w).sum(-1) + d
    ok = ok & mask & (z.abs() < gate)
    u = normal @ R  # Rᵀ n, row-wise
    H = torch.cat([torch.cross(q_imu, u, dim=-1), normal], dim=-1)  # [K, m, 6]
    Hw = H * (ok.to(R.dtype) * w_sigma)[..., None]
    HtWH = Hw.transpose(-1, -2) @ H  # [K, 6, 6]
    HtWz = (Hw * z[..., None]).sum(1)  # [K, 6]
    return HtWH, HtWz, ok.sum(-1)


def iterated_update(
    prior: FilterState,
    q_imu: Tensor,
    mask: Tensor,
    ranges: Tensor,
    query: PlaneQuery,
    settings: UpdateSettings,
) -> tuple[FilterState, Tensor]:
    """Runs the iterated update for every candidate.

    Args:
        prior: Propagated states (``K`` candidates).
        q_imu: ``[K, m, 3]`` deskewed points in the IMU frame at the scan end.
        mask: ``[K, m]`` or ``[m]`` usable points.
        ranges: ``[m]`` point ranges (m) for the residual gate.
        query: ``query(world_points [K, m, 3], widen)`` -> ``(normal, d, ok)`` of their planes;
            ``widen`` asks for the wider (neighbour-voxel) search on the first iteration.
        settings: Update settings.

    Returns:
        Posterior states (prior kept where a candidate had too few correspondences) and the
        ``[K]`` number of correspondences used in the last iteration.
    """
    K = prior.num
    P_inv = torch.linalg.inv(prior.P)
    gate = settings.gate_scale * ranges.clamp_min(0.1).sqrt()
    w_sigma = 1.0 / settings.point_sigma_m**2
    x = prior
    A = P_inv
    n_ok = torch.zeros(K, dtype=torch.int64)
    for it in range(settings.max_iterations):
        HtWH, HtWz, n_ok = plane_normal_equations(
            x.R, x.p, q_imu, mask, gate, query, it == 0, w_sigma
        )
        A = P_inv.clone()
        A[:, :6, :6] += HtWH
        rhs = -(P_inv @ x.boxminus(prior)[..., None])[..., 0]
        rhs[:, :6] -= HtWz
        delta = torch.linalg.solve(A, rhs)
        enough = n_ok >= settings.min_correspondences
        delta = torch.where(enough[:, None], delta, torch.zeros_like(delta))
        x = x.boxplus(delta)
        if float(delta.abs().max()) < settings.converge_eps:
            break
    enough = n_ok >= settings.min_correspondences
    P_post = torch.linalg.inv(A)
    P_post = 0.5 * (P_post + P_post.transpose(-1, -2))
    post = replace(x, P=torch.where(enough[:, None, None], P_post, prior.P))
    post = post.where(enough, prior)
    return post, n_ok
