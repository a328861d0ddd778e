"""IMU forward propagation of K filters with covariance, and the pose track used for deskewing.

Each IMU interval ``[t_i, t_i+1]`` uses the mean of its two samples (as FAST-LIO does). Every
filter integrates over its own window ``[t0_b, t1_b]`` (windows differ between candidates with
different LiDAR–IMU time offsets, and between re-anchored windows of a segment); intervals are
clipped to each window.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch
from torch import Tensor

from l2calib import geometry as geo
from l2calib.recipe import ImuInput
from l2calib_backends.state import BA, BG, DIM, GRAV, POS, TH, VEL, FilterState


@dataclass(frozen=True)
class ImuNoise:
    """Continuous-time IMU noise densities (units per sqrt(Hz))."""

    gyro: float
    accel: float
    gyro_bias: float
    accel_bias: float

    @classmethod
    def from_recipe(cls, imu: ImuInput | None) -> ImuNoise:
        """The densities of a recipe's ``data.imu`` (its defaults if ``None``)."""
        imu = imu or ImuInput()
        return cls(
            imu.gyro_noise_density,
            imu.accel_noise_density,
            imu.gyro_bias_random_walk,
            imu.accel_bias_random_walk,
        )


@dataclass(frozen=True)
class ImuTensors:
    """IMU samples of one segment: ``t [S]`` (s, segment-relative), ``gyro``, ``accel [S, 3]``."""

    t: Tensor
    gyro: Tensor
    accel: Tensor


@dataclass(frozen=True)
class PoseTrack:
    """Piecewise-constant-acceleration IMU motion over one propagation, per candidate.

    Interval ``i`` of candidate ``k`` starts at ``t[k, i]`` with pose ``R[k, i]``, ``p[k, i]``,
    velocity ``v[k, i]``, body rate ``w[k, i]`` (rad/s, bias-corrected) and world acceleration
    ``a[k, i]`` (m/s², gravity included). ``t[k, -1]`` is the window end.
    """

    t: Tensor  # [K, n+1]
    R: Tensor  # [K, n, 3, 3]
    p: Tensor  # [K, n, 3]
    v: Tensor  # [K, n, 3]
    w: Tensor  # [K, n, 3]
    a: Tensor  # [K, n, 3]

    def poses_at(self, t_query: Tensor) -> tuple[Tensor, Tensor]:
        """IMU poses ``R [K, m, 3, 3]``, ``p [K, m, 3]`` at ``t_query [K, m]`` (clamped)."""
        n = self.R.shape[1]
        starts = self.t[:, :-1].contiguous()
        idx = (torch.searchsorted(starts, t_query.contiguous(), right=True) - 1).clamp(0, n - 1)
        t0 = torch.gather(starts, 1, idx)
        dt = (t_query - t0).clamp_min(0.0)[..., None]
        take3 = idx[..., None].expand(-1, -1, 3)
        R0 = torch.gather(self.R, 1, idx[..., None, None].expand(-1, -1, 3, 3))
        w = torch.gather(self.w, 1, take3)
        p0 = torch.gather(self.p, 1, take3)
        v0 = torch.gather(self.v, 1, take3)
        a = torch.gather(self.a, 1, take3)
        return R0 @ geo.so3_exp(w * dt), p0 + v0 * dt + 0.5 * a * dt * dt


def propagate(
    state: FilterState, imu: ImuTensors, t0: Tensor, t1: Tensor, noise: ImuNoise
) -> tuple[FilterState, PoseTrack]:
    """Propagates every filter ``b`` from ``t0[b]`` to ``t1[b]`` (s, segment-relative).

    Each filter walks its own IMU samples (gathered by index), so filters at very different
    times (windows spread over a segment) cost no more than filters at the same time.

    Returns:
        The propagated state (with covariance) and the pose track for deskewing.
    """
    B = state.num
    dtype = state.R.dtype
    ts = imu.t
    last = len(ts) - 2  # last interval start
    lo = (torch.searchsorted(ts, t0, right=True) - 1).clamp(0, last)
    hi = torch.searchsorted(ts, t1, right=False).clamp(1, last + 1)
    steps = int((hi - lo).max()) if B else 0
    eye3 = torch.eye(3, dtype=dtype).expand(B, 3, 3)
    R, p, v = state.R, state.p, state.v
    # Error-state transition over the whole window, accumulated from the IMU intervals
    # (first order in each interval): one 18×18 product per scan instead of one per sample.
    total = torch.zeros(B, dtype=dtype)
    phi = torch.zeros(B, 3, dtype=dtype)  # Σ ω dt
    v_th = torch.zeros(B, 3, 3, dtype=dtype)  # Σ -R [a]× dt
    v_ba = torch.zeros(B, 3, 3, dtype=dtype)  # Σ -R dt
    p_th = torch.zeros(B, 3, 3, dtype=dtype)
    p_ba = torch.zeros(B, 3, 3, dtype=dtype)
    track_t, track_R, track_p, track_v, track_w, track_a = [t0], [], [], [], [], []
    no_time = torch.zeros((), dtype=dtype)
    for j in range(max(steps, 1)):
        i = (lo + j).clamp(max=last)
        a_t = t0 if j == 0 else torch.minimum(torch.maximum(ts[i], t0), t1)
        # The last interval of each filter ends at t1 even if the IMU stops just before it.
        b_t = torch.where(i + 1 >= hi, t1, torch.minimum(torch.maximum(ts[i + 1], t0), t1))
        # [B]; 0 once a filter has reached t1, and once it has used its own last interval: a
        # window ending past the last IMU sample (a positive time offset at a segment's end)
        # has i clamped there with a_t < t1, which integrated that stretch again on every
        # extra step other filters of the batch still took (a 50 ms offset: 649 ms, not 100).
        dt = torch.where(lo + j < hi, (b_t - a_t).clamp_min(0.0), no_time)
        w_m = 0.5 * (imu.gyro[i] + imu.gyro[i + 1]) - state.bg  # [B, 3]
        a_m = 0.5 * (imu.accel[i] + imu.accel[i + 1]) - state.ba
        dt1 = dt[:, None]
        dt3 = dt[:, None, None]
        R_next = R @ geo.so3_exp(w_m * dt1)
        # Trapezoid in the world frame: each accelerometer sample rotated by its own attitude
        # (rotating the mean by the start attitude alone biases fast-turning motion).
        a_world = (
            0.5
            * (
                (R @ (imu.accel[i] - state.ba)[..., None])[..., 0]
                + (R_next @ (imu.accel[i + 1] - state.ba)[..., None])[..., 0]
            )
            + state.g
        )
        track_R.append(R)
        track_p.append(p)
        track_v.append(v)
        track_w.append(w_m)
        track_a.append(a_world)
        track_t.append(b_t)
        # Blocks of the accumulated transition (position blocks pick up the velocity blocks).
        p_th = p_th + v_th * dt3
        p_ba = p_ba + v_ba * dt3
        v_th = v_th - (R @ geo.hat(a_m)) * dt3
        v_ba = v_ba - R * dt3
        phi = phi + w_m * dt1
        total = total + dt
        # Nominal state.
        p = p + v * dt1 + 0.5 * a_world * dt1 * dt1
        v = v + a_world * dt1
        R = R_next
    T1, T3 = total[:, None], total[:, None, None]
    F = torch.eye(DIM, dtype=dtype).repeat(B, 1, 1)
    F[:, TH, TH] = geo.so3_exp(-phi)
    F[:, TH, BG] = -eye3 * T3
    F[:, POS, TH] = p_th
    F[:, POS, VEL] = eye3 * T3
    F[:, POS, BA] = p_ba
    F[:, POS, GRAV] = 0.5 * eye3 * T3 * T3
    F[:, VEL, TH] = v_th
    F[:, VEL, BA] = v_ba
    F[:, VEL, GRAV] = eye3 * T3
    q_diag = torch.zeros(B, DIM, dtype=dtype)
    q_diag[:, TH] = noise.gyro**2 * T1
    q_diag[:, VEL] = noise.accel**2 * T1
    q_diag[:, BG] = noise.gyro_bias**2 * T1
    q_diag[:, BA] = noise.accel_bias**2 * T1
    P = F @ state.P @ F.transpose(-1, -2) + torch.diag_embed(q_diag)
    track = PoseTrack(
        torch.stack(track_t, 1),
        torch.stack(track_R, 1),
        torch.stack(track_p, 1),
        torch.stack(track_v, 1),
        torch.stack(track_w, 1),
        torch.stack(track_a, 1),
    )
    return replace(state, R=R, p=p, v=v, P=0.5 * (P + P.transpose(-1, -2))), track
