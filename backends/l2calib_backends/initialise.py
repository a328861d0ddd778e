"""Starting states of K filters from the reference trajectory and the candidate extrinsics.

A selected segment usually starts in motion, so the static initialisation of FAST-LIO does not
apply. Instead, at the scan end where a filter starts (the first scan, or the first scan of each
re-anchored window) every candidate starts from the reference LiDAR pose moved by its own
extrinsic, with the velocity of its IMU origin from the reference motion, and with the
gravity vector that best explains the segment's accelerometer readings for that extrinsic:

    g_world = (v_imu(t_b) - v_imu(t_a)) / (t_b - t_a) - mean_s R_world_lidar(t_s) R_imu_lidarᵀ a_s

(the mean specific force rotated to the world, corrected by the net velocity change). The
accelerometer is read at ``t_s + time_offset_s`` on its own clock for the reference pose at
``t_s`` on the LiDAR clock (``t_imu = t_lidar + time_offset_s``), per candidate (they used to be
paired at equal stamps; on a simulated hand-held recording whose IMU lags by 50 ms that cost
little: the reward at the true extrinsic and offset rose from 0.9322 to 0.9325,
``benchmarks/results/experiments/time_offset_plus50.json``).

With ``start_biases: estimate`` (what ``auto`` picks on well-excited data) the gyro and
accelerometer biases start from a least-squares fit over the segment and gravity is fitted with
them (:mod:`l2calib_backends.start_bias`), unless they come out beyond ``PLAUSIBLE`` start-prior
sigmas (a wrong rotation's, not the IMU's); otherwise, and with ``zero``, the biases start at
zero and gravity is the formula above, which holds the accelerometer bias where the attitude
barely changes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from l2calib import geometry as geo
from l2calib.errors import BackendError
from l2calib.trajectory import Trajectory
from l2calib_backends import start_bias
from l2calib_backends.prepare import PreparedSegment
from l2calib_backends.state import BA, BG, DIM, GRAV, POS, TH, VEL, FilterState

_H_S = 0.05  # half-width of the central differences (s)
PLAUSIBLE = 3.0  # estimated start biases beyond this many prior sigmas are not used


@dataclass(frozen=True)
class ReferenceMotion:
    """Extrinsic-independent reference quantities used to start the filters (world = reference).

    Attributes:
        R0, p0: ``[W, 3, 3]``, ``[W, 3]`` LiDAR poses at the W start scans.
        v0, w0: ``[W, 3]`` LiDAR velocity and world angular velocity there.
        R_imu: ``[S, 3, 3]`` LiDAR orientation at the IMU samples used for gravity.
        accel: ``[S, 3]`` those accelerometer samples (m/s²).
        imu_t: ``[S]`` their stamps (s, segment-relative): the LiDAR-clock times of ``R_imu``.
        all_t, all_accel: ``[A]``, ``[A, 3]`` every accelerometer sample of the segment (s,
            segment-relative, IMU clock; with the segment's margins), read at shifted times
            when a candidate has a time offset.
        R_a, v_a, w_a / R_b, v_b, w_b: LiDAR motion at the first and last scan end.
        span_s: Time between first and last scan end (s).
        start_biases: ``estimate`` (gyro and accelerometer biases and gravity from
            :mod:`l2calib_backends.start_bias`), ``gyro`` (the gyro bias only) or ``zero``.
        all_gyro: ``[A, 3]`` every gyro sample of the segment (rad/s, IMU clock).
        bounds: ``[C + 1]`` chunk bounds into the ``imu_t`` samples.
        R_B, v_B, dR_B: ``[C + 1, ...]`` at the bounds: LiDAR orientation, the central
            differences (over ±``_H_S``) of the LiDAR position and orientation matrix: the
            mean velocity of any point of the LiDAR body over that window.
    """

    R0: Tensor
    p0: Tensor
    v0: Tensor
    w0: Tensor
    R_imu: Tensor
    accel: Tensor
    imu_t: Tensor
    all_t: Tensor
    all_accel: Tensor
    R_a: Tensor
    v_a: Tensor
    w_a: Tensor
    R_b: Tensor
    v_b: Tensor
    w_b: Tensor
    span_s: float
    start_biases: str
    all_gyro: Tensor
    bounds: Tensor
    R_B: Tensor
    v_B: Tensor
    dR_B: Tensor


def _kinematics(ref: Trajectory, stamps_ns: np.ndarray, name: str):
    h = int(_H_S * 1e9)
    query = np.concatenate([stamps_ns - h, stamps_ns, stamps_ns + h])
    lo, hi = ref.stamps_ns[0], ref.stamps_ns[-1]
    query = np.clip(query, lo, hi)
    order = np.argsort(query, kind="stable")
    uniq, inv = np.unique(query[order], return_inverse=True)
    sampled, valid = ref.sample(uniq, max_gap_s=1.0)
    if not valid.all():
        raise BackendError(
            f"the reference trajectory does not cover segment {name}",
            fix="use a reference that spans the selected segments",
        )
    T = sampled.matrices()
    back = torch.from_numpy(np.empty_like(order))
    back[torch.from_numpy(order)] = torch.from_numpy(inv)
    T = T[back]
    n = len(stamps_ns)
    T_m, T_0, T_p = T[:n], T[n : 2 * n], T[2 * n :]
    dt = torch.from_numpy((query[2 * n :] - query[:n]).astype(np.float64) * 1e-9).clamp_min(1e-3)
    v = (T_p[:, :3, 3] - T_m[:, :3, 3]) / dt[:, None]
    w = geo.so3_log(T_p[:, :3, :3] @ T_m[:, :3, :3].transpose(-1, -2)) / dt[:, None]
    dR = (T_p[:, :3, :3] - T_m[:, :3, :3]) / dt[:, None, None]
    return T_0[:, :3, :3], T_0[:, :3, 3], v, w, dR


def reference_motion(
    seg: PreparedSegment,
    reference: Trajectory,
    start_scans: list[int],
    start_biases: str = "zero",
) -> ReferenceMotion:
    """Samples the reference at the start scans, the first/last scan end and the IMU samples."""
    starts = seg.end_stamps_ns[start_scans]
    R0, p0, v0, w0, _ = _kinematics(reference, starts, seg.name)
    ends = seg.end_stamps_ns[[0, -1]]
    R, _, v, w, _ = _kinematics(reference, ends, seg.name)
    imu_ns = seg.start_ns + np.round(seg.imu.t.numpy() * 1e9).astype(np.int64)
    inside = (imu_ns >= ends[0]) & (imu_ns <= ends[1])
    R_imu, _, v_imu, _, dR_imu = _kinematics(reference, imu_ns[inside], seg.name)
    imu_t = seg.imu.t[torch.from_numpy(inside)]
    bounds = start_bias.chunk_bounds(imu_t, margin_s=_H_S)
    return ReferenceMotion(
        R0=R0,
        p0=p0,
        v0=v0,
        w0=w0,
        R_imu=R_imu,
        accel=seg.imu.accel[torch.from_numpy(inside)],
        imu_t=imu_t,
        all_t=seg.imu.t,
        all_accel=seg.imu.accel,
        R_a=R[0],
        v_a=v[0],
        w_a=w[0],
        R_b=R[1],
        v_b=v[1],
        w_b=w[1],
        span_s=float((ends[1] - ends[0]) * 1e-9),
        start_biases=start_biases,
        all_gyro=seg.imu.gyro,
        bounds=bounds,
        R_B=R_imu[bounds],
        v_B=v_imu[bounds],
        dR_B=dR_imu[bounds],
    )


def _imu_velocity(R_wl: Tensor, v_wl: Tensor, w_w: Tensor, t_li: Tensor) -> Tensor:
    """Velocity ``[K, 3]`` of the IMU origin ``t_li [K, 3]`` (LiDAR frame) on the LiDAR body."""
    arm = t_li @ R_wl.transpose(-1, -2)
    return v_wl + torch.cross(w_w.expand_as(arm), arm, dim=-1)


def _shifted(motion: ReferenceMotion, values: Tensor, time_offset_s: Tensor) -> Tensor:
    """``[K, S, 3]`` IMU ``values [A, 3]`` at ``imu_t + offset_k`` (IMU clock), interpolated."""
    t = motion.all_t
    query = (motion.imu_t[None] + time_offset_s[:, None]).clamp(t[0], t[-1])
    hi = torch.searchsorted(t, query.contiguous(), right=True).clamp(1, len(t) - 1)
    lo = hi - 1
    w = ((query - t[lo]) / (t[hi] - t[lo]).clamp_min(1e-9))[..., None]
    return (1 - w) * values[lo] + w * values[hi]


def _gyro_bias(motion: ReferenceMotion, R_il: Tensor, time_offset_s: Tensor | None) -> Tensor:
    """``[K, 3]`` gyro biases (rad/s) of the candidates (:func:`start_bias.gyro_bias`).

    The gyro is integrated once over chunks of its own clock; a candidate's time offset moves
    the reference's chunk ends instead (the IMU's ``[t_a, t_b]`` is the LiDAR's
    ``[t_a − offset, t_b − offset]``), which keeps the integration out of the per-candidate work.
    """
    inside = (motion.all_t >= motion.imu_t[0]) & (motion.all_t <= motion.imu_t[-1])
    gyro = motion.all_gyro[inside][None]
    R_B = motion.R_B
    if time_offset_s is not None and bool(time_offset_s.any()):
        R_B = _orientation_at(motion, motion.imu_t[motion.bounds][None] - time_offset_s[:, None])
    return start_bias.gyro_bias(gyro, motion.imu_t, motion.bounds, R_B, R_il)


def _orientation_at(motion: ReferenceMotion, t: Tensor) -> Tensor:
    """Reference LiDAR orientation ``[..., 3, 3]`` at LiDAR-clock times ``t`` (s).

    Interpolated on SO(3) between the orientations ``R_imu`` at the IMU samples; ``t`` is
    clamped to their span.
    """
    ts = motion.imu_t
    q = t.clamp(ts[0], ts[-1])
    hi = torch.searchsorted(ts, q.contiguous(), right=True).clamp(1, len(ts) - 1)
    lo = hi - 1
    w = ((q - ts[lo]) / (ts[hi] - ts[lo]).clamp_min(1e-9))[..., None]
    R_lo = motion.R_imu[lo]
    return R_lo @ geo.so3_exp(w * geo.so3_log(R_lo.transpose(-1, -2) @ motion.R_imu[hi]))


def _start_biases(
    motion: ReferenceMotion,
    force_world: Tensor,
    R_il: Tensor,
    t_li: Tensor,
    time_offset_s: Tensor | None,
) -> tuple[Tensor, Tensor, Tensor]:
    """Gyro bias, accel bias and gravity ``[K, 3]`` each (:mod:`l2calib_backends.start_bias`)."""
    bg = _gyro_bias(motion, R_il, time_offset_s)
    ba, g = start_bias.accel_bias_and_gravity(
        force_world, motion.R_imu, R_il.transpose(-1, -2), motion.imu_t, motion.bounds,
        (motion.v_B, motion.dR_B), t_li, _H_S,
    )  # fmt: skip
    return bg, ba, g


def initial_states(
    motion: ReferenceMotion,
    T_imu_lidar: Tensor,
    sigmas: dict[str, float],
    time_offset_s: Tensor | None = None,
) -> FilterState:
    """States of K×W filters for candidate extrinsics ``[K, 4, 4]`` at the W start scans.

    Filter ``b = k * W + w`` is candidate ``k`` started at start scan ``w``; ``time_offset_s``
    ``[K]`` (s, ``t_imu = t_lidar + offset``) or ``None`` for none.
    """
    K, W = T_imu_lidar.shape[0], motion.R0.shape[0]
    R_il, t_il = T_imu_lidar[:, :3, :3], T_imu_lidar[:, :3, 3]
    R_li = R_il.transpose(-1, -2)
    t_li = -(R_li @ t_il[..., None])[..., 0]  # IMU origin in the LiDAR frame, [K, 3]
    # Gravity per candidate over the whole segment: [K, 3].
    if time_offset_s is None or not bool(time_offset_s.any()):
        a_lidar = torch.einsum("kij,sj->ksi", R_li, motion.accel)
    else:
        shifted = _shifted(motion, motion.all_accel, time_offset_s.to(motion.all_t.dtype))
        a_lidar = torch.einsum("kij,ksj->ksi", R_li, shifted)
    zeros = torch.zeros(K, 3, dtype=T_imu_lidar.dtype)
    mean_force = torch.einsum("sij,ksj->ki", motion.R_imu, a_lidar) / max(len(motion.accel), 1)
    v_a = _imu_velocity(motion.R_a, motion.v_a, motion.w_a, t_li)
    v_b = _imu_velocity(motion.R_b, motion.v_b, motion.w_b, t_li)
    g = (v_b - v_a) / max(motion.span_s, 1e-3) - mean_force
    bg, ba = zeros, zeros.clone()
    if motion.start_biases == "gyro" and len(motion.bounds) > 1:
        bg_e = _gyro_bias(motion, R_il, time_offset_s)
        fits = bg_e.norm(dim=-1) <= PLAUSIBLE * sigmas["bg"]  # as below
        bg = torch.where(fits[:, None], bg_e, bg)
    if motion.start_biases == "estimate" and len(motion.bounds) > 1:
        force_world = torch.einsum("sij,ksj->ksi", motion.R_imu, a_lidar)
        bg_e, ba_e, g_e = _start_biases(motion, force_world, R_il, t_li, time_offset_s)
        # Biases beyond PLAUSIBLE priors' sigmas are a wrong rotation's, not the IMU's: such
        # candidates start as without the estimate, so that they are not helped to fit.
        fits = (bg_e.norm(dim=-1) <= PLAUSIBLE * sigmas["bg"]) & (
            ba_e.norm(dim=-1) <= PLAUSIBLE * sigmas["ba"]
        )
        bg = torch.where(fits[:, None], bg_e, bg)
        ba = torch.where(fits[:, None], ba_e, ba)
        g = torch.where(fits[:, None], g_e, g)
    # Start states per (candidate, window).
    R0 = motion.R0[None].expand(K, -1, -1, -1)  # [K, W, 3, 3]
    R_wi = (R0 @ R_li[:, None]).reshape(K * W, 3, 3)
    arm = torch.einsum("kwij,kj->kwi", R0, t_li)  # R_wl t_li, [K, W, 3]
    p_wi = (motion.p0[None] + arm).reshape(K * W, 3)
    v_wi = motion.v0[None] + torch.cross(motion.w0[None].expand_as(arm), arm, dim=-1)
    v_wi = v_wi.reshape(K * W, 3)
    P = torch.zeros(K * W, DIM, DIM, dtype=T_imu_lidar.dtype)
    for block, key in (
        (TH, "rot"),
        (POS, "pos"),
        (VEL, "vel"),
        (BG, "bg"),
        (BA, "ba"),
        (GRAV, "grav"),
    ):
        idx = torch.arange(block.start, block.stop)
        P[:, idx, idx] = sigmas[key] ** 2

    def per_filter(x: Tensor) -> Tensor:
        return x[:, None].expand(K, W, 3).reshape(K * W, 3)

    return FilterState(
        R=R_wi, p=p_wi, v=v_wi, bg=per_filter(bg), ba=per_filter(ba), g=per_filter(g), P=P
    )
