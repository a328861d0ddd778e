"""IMU biases and gravity at a filter's start, per candidate, from the reference motion.

A filter that starts with zero biases must learn the turn-on biases from the LiDAR updates.
On weakly excited data (UAV, ground vehicle) that is slow, and an accelerometer bias the filter
has not learned yet looks like a lever arm: on a simulated UAV flight with a VN100-like IMU
(turn-on bias σ 0.02 m/s²) the reward peaked 2.6 cm / 0.20° from the true extrinsic, and
0.4 cm without turn-on biases (``benchmarks/results/experiments/start_bias.json``). With the
reference trajectory and a candidate's rotation the biases follow from the whole segment:

* gyro: the gyro integrated over chunks of about ``CHUNK_S`` against the reference's rotation
  over them, turned into the IMU frame by the candidate (:func:`gyro_bias`);
* accelerometer: over the same chunks ``[t_a, t_b]``,
  ``v_imu(t_b) − v_imu(t_a) = Σ_s R_world_imu(s) (a_s − b_a) Δt_s + g (t_b − t_a)``, linear in
  the bias ``b_a`` (IMU frame), gravity ``g`` (world) and the IMU's lever arm, which is fitted
  too, so that the bias does not take up a candidate's lever-arm error
  (:func:`accel_bias_and_gravity`). A body-fixed bias and the world-fixed gravity separate only
  where the attitude changes; a prior ``N(0, PRIOR_BA²)`` on ``b_a`` leaves the rest in ``g``
  (what the filters' start did before: the mean specific force).

Written by hand: small linear least squares (3 and 9 unknowns per candidate), batched over
candidates in torch; no library fits this shape.
"""

from __future__ import annotations

import torch
from torch import Tensor

from l2calib import geometry as geo

CHUNK_S = 0.25  # chunk length of the bias equations (s)
PRIOR_BA = 0.1  # prior standard deviation of the accelerometer bias (m/s²)
SIGMA_DV = 0.005  # standard deviation of a chunk's velocity difference (m/s)
PRIOR_ARM = 1.0  # prior standard deviation of the fitted lever arm (m)


def chunk_bounds(t: Tensor, chunk_s: float | None = None, margin_s: float = 0.0) -> Tensor:
    """Indices ``[C + 1]`` into samples ``t [S]`` that cut them into chunks of ~``chunk_s``.

    The first and last bound keep ``margin_s`` from the ends (the window of the velocity's
    central difference must lie inside the samples).
    """
    chunk_s = CHUNK_S if chunk_s is None else chunk_s
    last_index = len(t) - 1
    first = min(int(torch.searchsorted(t, t[0] + margin_s)), last_index)
    last = int(torch.searchsorted(t, t[-1] - margin_s, right=True)) - 1
    if last <= first:
        return torch.tensor([first], dtype=torch.long)
    count = max(1, round(float(t[last] - t[first]) / chunk_s))
    idx = torch.linspace(first, last, count + 1).round().long()
    return torch.unique_consecutive(idx)


def gyro_bias(gyro: Tensor, t: Tensor, bounds: Tensor, R_wl: Tensor, R_il: Tensor) -> Tensor:
    """``[K, 3]`` gyro biases (rad/s) from the rotation over each chunk.

    The gyro integrated over a chunk (trapezoid rule, zero bias) is compared with the
    reference's rotation over it seen in the IMU frame, ``R_il R_wl(a)ᵀ R_wl(b) R_ilᵀ``; the bias
    is the least-squares solution of ``Log(ΔR_gyroᵀ ΔR_ref) = −J b`` with ``J`` the bias
    Jacobian of the integrated rotation (``J ← dRᵀ J + Δt I`` per sample, as in IMU
    preintegration). Rotation increments, not differentiated rates: exact on fast hand-held
    motion, where the reference's numerically differentiated rate is off by ~1e-3 rad/s.

    Args:
        gyro: ``[1, S, 3]`` gyro readings (rad/s, IMU frame) at times ``t``, the same for
            every candidate (or ``[K, S, 3]``, one set per candidate).
        t: ``[S]`` their times (s).
        bounds: ``[C + 1]`` chunk bounds (:func:`chunk_bounds`).
        R_wl: ``[C + 1, 3, 3]`` reference LiDAR orientation at the bounds, or
            ``[K, C + 1, 3, 3]`` per candidate (a time offset moves the bounds on the LiDAR clock).
        R_il: ``[K, 3, 3]`` candidate rotations ``R_imu_lidar``.
    """
    dtype = gyro.dtype
    lengths = bounds[1:] - bounds[:-1]
    # All increments at once, then pairwise products (log2 of the chunk length rounds instead
    # of one Python step per sample): chunks A then B give dR = dR_A dR_B, J = dR_Bᵀ J_A + J_B.
    j = torch.arange(int(lengths.max()))
    idx = (bounds[:-1, None] + j).clamp(max=len(t) - 2)  # [C, L]
    step = torch.where(j < lengths[:, None], t[idx + 1] - t[idx], torch.zeros((), dtype=dtype))
    dR = geo.so3_exp(0.5 * (gyro[:, idx] + gyro[:, idx + 1]) * step[..., None])  # [K', C, L, 3, 3]
    J = step[..., None, None] * torch.eye(3, dtype=dtype)  # [C, L, 3, 3]
    J = J.expand_as(dR)
    while dR.shape[2] > 1:
        if dR.shape[2] % 2:  # pad with an empty sample
            dR = torch.cat([dR, torch.eye(3, dtype=dtype).expand_as(dR[:, :, :1])], dim=2)
            J = torch.cat([J, torch.zeros_like(J[:, :, :1])], dim=2)
        a, b = dR[:, :, 0::2], dR[:, :, 1::2]
        J = b.transpose(-1, -2) @ J[:, :, 0::2] + J[:, :, 1::2]
        dR = a @ b
    dR, J = dR[:, :, 0], J[:, :, 0]  # [K', C, 3, 3]
    rel = R_wl[..., :-1, :, :].transpose(-1, -2) @ R_wl[..., 1:, :, :]  # [(K,) C, 3, 3]
    ref = R_il[:, None] @ rel @ R_il[:, None].transpose(-1, -2)
    r = geo.so3_log(dR.transpose(-1, -2) @ ref)  # [K, C, 3] = -J b
    N = (J.transpose(-1, -2) @ J).sum(dim=1).expand(len(R_il), 3, 3)
    rhs = -(J.transpose(-1, -2) @ r[..., None]).sum(dim=1)[..., 0]
    return torch.linalg.solve(N, rhs)


def accel_bias_and_gravity(
    force_world: Tensor,
    R_wl: Tensor,
    R_li: Tensor,
    t: Tensor,
    bounds: Tensor,
    lidar_motion: tuple[Tensor, Tensor],
    t_li: Tensor,
    half_window_s: float,
) -> tuple[Tensor, Tensor]:
    """Accelerometer biases ``[K, 3]`` (m/s², IMU frame) and gravity ``[K, 3]`` (m/s², world).

    The bias is fitted together with gravity and a lever arm of its own, so that it does not
    depend on the candidate's lever arm: fitted with the candidate's, it took up the constant
    part of a wrong lever arm's accelerations and flattened the reward along translation
    (``docs/backends.md``). Gravity is then fitted per candidate, with its lever arm and that bias.

    The reference's velocity at a bound is a central difference, the mean velocity over
    ``±half_window_s``; the IMU side is smoothed alike, so that the equations hold exactly on fast
    motion (a plain integral between the bounds was off by 0.03 m/s² on simulated hand-held
    motion): a chunk's difference of two window means integrates the specific force with a
    trapezoid weight, rising over the first window and falling over the last.

    Args:
        force_world: ``[K, S, 3]`` specific force rotated into the world, ``R_world_imu(s) a_s``.
        R_wl: ``[S, 3, 3]`` reference LiDAR orientation at the samples.
        R_li: ``[K, 3, 3]`` candidate rotations ``R_lidar_imu``.
        t: ``[S]`` sample times (s).
        bounds: ``[C + 1]`` chunk bounds (:func:`chunk_bounds`, at least ``half_window_s``
            from the ends).
        lidar_motion: ``v_B [C + 1, 3]`` and ``dR_B [C + 1, 3, 3]``: central differences of the
            LiDAR position and orientation at the bounds; a body point ``r`` (LiDAR frame) has
            the window-mean velocity ``v_B + dR_B r``.
        t_li: ``[K, 3]`` candidate IMU origins in the LiDAR frame (m).
        half_window_s: Half-width of the velocity's central difference (s).
    """
    K, dtype = force_world.shape[0], force_world.dtype
    v_B, dR_B = lidar_motion
    # Each reading stands for the half-way times on either side (midpoint rule): a reading
    # taken as the start of its interval was off by ½ ḟ Δt per sample, up to 20 mm/s per chunk
    # on hand-held motion.
    dt = 0.5 * (torch.diff(t, append=t[-1:]) + torch.diff(t, prepend=t[:1]))
    h = half_window_s
    a, b = t[bounds[:-1]], t[bounds[1:]]
    # Banded: chunk c weighs only the samples in [a_c - h, b_c + h] (memory O(K·S), not O(C·S)).
    lo = torch.searchsorted(t, a - h)
    width = int((torch.searchsorted(t, b + h, right=True) - lo).max())
    idx = (lo[:, None] + torch.arange(width)).clamp(max=len(t) - 1)  # [C, W]
    ts = t[idx]
    # The difference of two ±h window means integrates over [a + u, b + u] for u in [-h, h]:
    # a sample at s counts for the share of u with a + u <= s < b + u (exact for any b - a).
    share = (
        torch.minimum(ts - a[:, None], torch.full_like(ts, h))
        - torch.maximum(ts - b[:, None], torch.full_like(ts, -h))
    ).clamp(min=0) / (2 * h)
    inside = (lo[:, None] + torch.arange(width)) < len(t)
    weight = torch.where(inside, share, torch.zeros((), dtype=dtype)) * dt[idx]  # [C, W]
    S_c = torch.einsum("cw,kcwi->kci", weight, force_world[:, idx])
    M = torch.einsum("cw,cwij->cij", weight, R_wl[idx])[None] @ R_li[:, None]  # [K, C, 3, 3]
    span = b - a
    C = len(span)
    eye = torch.eye(3, dtype=dtype).expand(K, C, 3, 3)
    arm = (dR_B[1:] - dR_B[:-1]).expand(K, C, 3, 3)
    # y_c = Δv_lidar − S_c = −M b_a + span g − ΔdR r, unknowns (b_a, g, r)
    A = torch.cat([-M, span[None, :, None, None] * eye, -arm], dim=-1).reshape(K, 3 * C, 9)
    y = (v_B[1:] - v_B[:-1] - S_c).reshape(K, 3 * C)
    N = A.transpose(1, 2) @ A / SIGMA_DV**2
    prior = torch.tensor([PRIOR_BA**-2] * 3 + [1e-12] * 3 + [PRIOR_ARM**-2] * 3, dtype=dtype)
    rhs = (A.transpose(1, 2) @ y[..., None])[..., 0] / SIGMA_DV**2
    ba = torch.linalg.solve(N + torch.diag(prior), rhs)[:, :3]
    # gravity per candidate, with its own lever arm and the bias above
    dv = (v_B[1:] - v_B[:-1])[None] + (arm @ t_li[:, None, :, None])[..., 0]  # [K, C, 3]
    g = (dv - S_c + (M @ ba[:, None, :, None])[..., 0]).sum(dim=1) / span.sum()
    return ba, g
