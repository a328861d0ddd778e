"""Trajectory association, Umeyama alignment (SE(3)/Sim(3), batched) and absolute pose errors.

Equation numbers refer to S. Umeyama, "Least-squares estimation of transformation parameters
between two point patterns", IEEE TPAMI 13(4), 1991.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from l2calib import geometry as geo
from l2calib.errors import DataError
from l2calib.trajectory import Trajectory


def umeyama(
    src: Tensor, dst: Tensor, weights: Tensor | None = None, with_scale: bool = False
) -> tuple[Tensor, Tensor, Tensor]:
    """Least-squares similarity ``dst ≈ s R src + t``, batched over leading dims.

    Args:
        src: ``[..., N, 3]`` source points.
        dst: ``[..., N, 3]`` destination points (broadcastable with ``src``).
        weights: ``[..., N]`` non-negative weights (a 0/1 validity mask, typically) or ``None``.
        with_scale: Estimate the scale ``s`` (Sim(3)); otherwise ``s = 1`` (SE(3)).

    Returns:
        ``R [..., 3, 3]``, ``t [..., 3]`` and ``s [...]``.
    """
    src, dst = torch.broadcast_tensors(src, dst)
    w = (
        torch.ones(src.shape[:-1], dtype=src.dtype, device=src.device)
        if weights is None
        else (weights.to(src.dtype).expand(src.shape[:-1]))
    )
    wsum = w.sum(-1).clamp_min(1e-300)
    mu_x = (w[..., None] * src).sum(-2) / wsum[..., None]  # eq. 34
    mu_y = (w[..., None] * dst).sum(-2) / wsum[..., None]  # eq. 35
    xc = src - mu_x[..., None, :]
    yc = dst - mu_y[..., None, :]
    sigma_x2 = (w * (xc * xc).sum(-1)).sum(-1) / wsum  # eq. 36
    cov = (yc * w[..., None]).transpose(-1, -2) @ xc / wsum[..., None, None]  # eq. 38
    U, D, Vh = torch.linalg.svd(cov)
    sign = torch.sign(torch.linalg.det(U) * torch.linalg.det(Vh))
    sign = torch.where(sign == 0, torch.ones_like(sign), sign)
    S = torch.ones_like(D)
    S[..., 2] = sign  # eq. 39 / 43
    R = U @ (S[..., None] * Vh)  # eq. 40
    if with_scale:
        s = (D * S).sum(-1) / sigma_x2.clamp_min(1e-300)  # eq. 42
    else:
        s = torch.ones_like(sigma_x2)
    t = mu_y - s[..., None] * (R @ mu_x[..., None])[..., 0]  # eq. 41
    return R, t, s


def apply_similarity(T: Tensor, R: Tensor, t: Tensor, s: Tensor) -> Tensor:
    """Applies ``x -> s R x + t`` to poses ``T [..., N, 4, 4]`` (rotation part gets ``R``)."""
    out = T.clone()
    out[..., :3, :3] = R[..., None, :, :] @ T[..., :3, :3]
    out[..., :3, 3] = s[..., None, None] * (T[..., :3, 3] @ R.transpose(-1, -2)) + t[..., None, :]
    return out


def pose_errors(T_est: Tensor, T_ref: Tensor) -> tuple[Tensor, Tensor]:
    """Per-pose translation error (m) and rotation error (rad) between matched poses.

    ``e_t = |t_est - t_ref|`` and ``e_r = angle(R_est R_refᵀ)``, the paper's Sec. III-C terms
    when ``T_est`` is the estimated LiDAR pose (``T_world_imu · T_imu_lidar``).

    Args:
        T_est: ``[..., N, 4, 4]`` estimated poses.
        T_ref: ``[..., N, 4, 4]`` reference poses (already aligned), broadcastable.

    Returns:
        ``e_t [..., N]`` and ``e_r [..., N]``.
    """
    e_t = (T_est[..., :3, 3] - T_ref[..., :3, 3]).norm(dim=-1)
    e_r = geo.rotation_angle(T_est[..., :3, :3] @ T_ref[..., :3, :3].transpose(-1, -2))
    return e_t, e_r


def align_reference_to_estimates(
    T_ref: Tensor, T_est: Tensor, valid: Tensor | None = None, with_scale: bool = False
) -> Tensor:
    """Umeyama-aligns a reference onto each of K estimates using positions of valid poses.

    Args:
        T_ref: ``[N, 4, 4]`` or ``[K, N, 4, 4]`` reference poses at the estimate stamps.
        T_est: ``[K, N, 4, 4]`` estimated poses.
        valid: ``[K, N]`` bool mask of poses to use, or ``None`` for all.
        with_scale: Sim(3) instead of SE(3).

    Returns:
        ``[K, N, 4, 4]`` aligned reference poses.
    """
    R, t, s = umeyama(T_ref[..., :3, 3], T_est[..., :3, 3], valid, with_scale)
    return apply_similarity(T_ref.expand_as(T_est), R, t, s)


@dataclass(frozen=True)
class ApeResult:
    """Absolute pose error of one estimate against a reference (after optional alignment).

    Attributes:
        stamps_ns: ``[N]`` stamps of the matched poses.
        e_t: ``[N]`` translation errors (m).
        e_r: ``[N]`` rotation errors (rad).
        T_align: ``[4, 4]`` similarity applied to the estimate (identity if not aligned).
        scale: Scale of the alignment (1 for SE(3)).
    """

    stamps_ns: np.ndarray
    e_t: np.ndarray
    e_r: np.ndarray
    T_align: np.ndarray
    scale: float

    @property
    def rmse_t(self) -> float:
        """Translation RMSE (m)."""
        return float(np.sqrt(np.mean(self.e_t**2)))

    @property
    def rmse_r_deg(self) -> float:
        """Rotation RMSE (degrees)."""
        return float(np.degrees(np.sqrt(np.mean(self.e_r**2))))


def associate(
    reference: Trajectory, estimate: Trajectory, max_gap_s: float = 0.2
) -> tuple[Trajectory, Trajectory]:
    """Matches poses by interpolating the reference at the estimate's stamps.

    Returns:
        ``(reference_at_matches, estimate_at_matches)`` with identical stamps.

    Raises:
        DataError: if fewer than 3 estimate stamps fall inside the reference.
    """
    ref_at, valid = reference.sample(estimate.stamps_ns, max_gap_s)
    if valid.sum() < 3:
        raise DataError(
            f"only {int(valid.sum())} of {len(estimate)} {estimate.body_frame} poses fall inside "
            f"the {reference.body_frame} reference ([{reference.stamps_s[0]:.3f}, "
            f"{reference.stamps_s[-1]:.3f}] s)",
            fix="check both trajectories use the same clock and overlap in time",
        )
    est = Trajectory(
        estimate.stamps_ns[valid],
        estimate.t_world_body[valid],
        estimate.quat_xyzw[valid],
        estimate.body_frame,
        estimate.world_frame,
    )
    return ref_at, est


def ape(
    reference: Trajectory,
    estimate: Trajectory,
    align: bool = True,
    with_scale: bool = False,
    max_gap_s: float = 0.2,
) -> ApeResult:
    """Absolute pose error of ``estimate`` after aligning it onto ``reference`` (evo's APE)."""
    ref, est = associate(reference, estimate, max_gap_s)
    T_ref, T_est = ref.matrices(), est.matrices()
    if align:
        R, t, s = umeyama(T_est[:, :3, 3], T_ref[:, :3, 3], with_scale=with_scale)
    else:
        R, t, s = (
            torch.eye(3, dtype=T_est.dtype),
            torch.zeros(3, dtype=T_est.dtype),
            torch.ones((), dtype=T_est.dtype),
        )
    T_est_aligned = apply_similarity(T_est, R, t, s)
    e_t, e_r = pose_errors(T_est_aligned, T_ref)
    T_align = torch.eye(4, dtype=T_est.dtype)
    T_align[:3, :3] = s * R
    T_align[:3, 3] = t
    return ApeResult(ref.stamps_ns, e_t.numpy(), e_r.numpy(), T_align.numpy(), float(s))
