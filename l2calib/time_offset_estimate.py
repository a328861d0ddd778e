"""LiDAR–IMU time offset before any calibration (``l2calib inspect``, issue 21).

The angular speed ``|ω(t)|`` is the same for every frame of one rigid body, whatever the
extrinsic, so the rotation rate of a LiDAR-only odometry (ct-lidar, on the LiDAR clock) and the
gyro's (on the IMU clock) differ only by the clock offset. Over the most excited stretch of the
recording (``stretch_s``, default 6 s: the odometry runs on that stretch only, which bounds the
cost), both ``|ω|`` curves are brought onto a 1 ms grid (the gyro averaged over the odometry's
pose interval, as the odometry's rate is), their normalised correlation is scanned over shifts
``±max_shift_s`` and the peak is refined by a parabola.

Sign: ``ω_odo(t + s)`` matches ``ω_gyro(t)`` at shift ``s = -time_offset_s`` with
``t_imu = t_lidar + time_offset_s``.

Observability: when ``|ω|`` hardly varies (UAV cruising, ground vehicle: its standard deviation
below ``MIN_RATE_STD_RAD_S``) or the correlation peak is flat (``sharpness`` below
``MIN_SHARPNESS``) the offset is **weakly observable** and no number is claimed.

Measured (docs/time_offset.md): on exact poses and on ct-lidar poses of simulated hand-held
bags the estimate is within 0.1 ms of the truth (sharpness 12-100); KISS-ICP's poses were biased
by 7-27 ms (scan-rate poses of a constant-velocity deskew), which is why ct-lidar runs here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from l2calib import geometry as geo
from l2calib.data import NS_PER_S, ImuSamples, Sequence
from l2calib.references.imu_check import pearson
from l2calib.trajectory import Trajectory

GRID_S = 0.001
#: ``|ω|`` standard deviation (rad/s) below which the offset is weakly observable.
MIN_RATE_STD_RAD_S = 0.3
#: Least peak sharpness: correlation lost 20 ms from the peak over the misfit ``1 - peak``
#: (exact poses of a hand-held sway: ~15; KISS-ICP on a 16-beam, 256-column simulation: 0.1-0.2).
MIN_SHARPNESS = 1.0
#: Least peak correlation of the two ``|ω|`` curves for the odometry to be trusted at all.
MIN_CORRELATION = 0.8


@dataclass
class OffsetEstimate:
    """What the rate correlation found.

    Attributes:
        time_offset_s: ``t_imu = t_lidar + time_offset_s`` (s); NaN when not estimated.
        observable: False when the offset is weakly observable here (``reason`` says why).
        correlation: Peak normalised correlation of the two ``|ω|`` curves.
        peak_drop: Correlation lost 20 ms either side of the peak (mean of both sides).
        sharpness: ``peak_drop / (1 - correlation)``: how far the peak stands above the misfit.
        rate_std_rad_s: Standard deviation of the gyro's ``|ω|`` over the stretch (rad/s).
        stretch: ``[start, end]`` of the stretch used (s, LiDAR clock).
        reason: Why the offset is not reported ("" when it is).
    """

    time_offset_s: float
    observable: bool
    correlation: float = float("nan")
    peak_drop: float = float("nan")
    sharpness: float = float("nan")
    rate_std_rad_s: float = float("nan")
    stretch: tuple[float, float] = (float("nan"), float("nan"))
    reason: str = ""


def most_excited_stretch(imu: ImuSamples, start_ns: int, end_ns: int, length_s: float):
    """``(a, b)`` ns: the ``length_s`` window in ``[start_ns, end_ns]`` of most varying ``|ω|``."""
    length = int(length_s * NS_PER_S)
    if end_ns - start_ns <= length:
        return start_ns, end_ns
    grid = np.arange(start_ns, end_ns, int(0.1 * NS_PER_S))
    rate = np.linalg.norm(
        np.stack([np.interp(grid, imu.stamps_ns, imu.gyro_rad_s[:, k]) for k in range(3)], 1),
        axis=1,
    )
    n = int(round(length_s / 0.1))
    c1 = np.concatenate([[0.0], np.cumsum(rate)])
    c2 = np.concatenate([[0.0], np.cumsum(rate**2)])
    var = (c2[n:] - c2[:-n]) / n - ((c1[n:] - c1[:-n]) / n) ** 2
    a = int(grid[int(np.argmax(var))])
    return a, a + length


def _rates(traj: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """``|ω|`` (rad/s) between consecutive poses, at the midpoints of their stamps (ns)."""
    R = geo.quat_to_matrix(torch.from_numpy(traj.quat_xyzw))
    dt = np.diff(traj.stamps_ns) / NS_PER_S
    angle = geo.rotation_angle(R[:-1].transpose(-1, -2) @ R[1:]).numpy()
    return (traj.stamps_ns[:-1] + traj.stamps_ns[1:]) // 2, angle / dt


def correlate_rates(
    odometry: Trajectory, imu: ImuSamples, max_shift_s: float = 0.2
) -> OffsetEstimate:
    """Offset from the ``|ω|`` of a LiDAR-frame (or any body-frame) trajectory and the gyro.

    Args:
        odometry: Poses on the LiDAR clock (e.g. KISS-ICP's), any world frame.
        imu: Gyro samples on the IMU clock (rad/s) covering the trajectory ± ``max_shift_s``.
        max_shift_s: Largest offset searched (s).
    """
    mid, rate_odo = _rates(odometry)
    a, b = int(mid[0]), int(mid[-1])
    grid = np.arange(a, b, int(GRID_S * NS_PER_S))
    odo = np.interp(grid, mid, rate_odo)
    # the gyro averaged over the same pose interval (the odometry's rate is a mean over it)
    step = int(np.median(np.diff(odometry.stamps_ns)))
    pad = int(max_shift_s * NS_PER_S) + step
    fine = np.arange(a - pad, b + pad, int(GRID_S * NS_PER_S))
    gyro = np.stack([np.interp(fine, imu.stamps_ns, imu.gyro_rad_s[:, k]) for k in range(3)], 1)
    # An odd number of grid points: np.convolve's "same" window of even width is centred half
    # a point (0.5 ms) late, which biased the offset found from a 100 Hz reference by +0.52 ms.
    width = max(1, int(round(step / (GRID_S * NS_PER_S)))) | 1
    g = np.convolve(np.linalg.norm(gyro, axis=1), np.ones(width) / width, mode="same")
    std = float(np.std(g))
    stretch = (a / NS_PER_S, b / NS_PER_S)
    if std < MIN_RATE_STD_RAD_S:
        return OffsetEstimate(
            float("nan"), False, rate_std_rad_s=std, stretch=stretch,
            reason=f"|ω| hardly varies (std {std:.2f} rad/s < {MIN_RATE_STD_RAD_S} rad/s)",
        )  # fmt: skip
    k_max = int(round(max_shift_s / GRID_S))
    base = int(round(pad / (GRID_S * NS_PER_S)))  # index in ``fine`` of the grid's start
    # the gyro at t pairs with the odometry at t + s, s = k ms: gyro index base - k + j
    corr = np.array(
        [pearson(odo, g[base - k : base - k + len(odo)]) for k in range(-k_max, k_max + 1)]
    )
    i = int(np.argmax(corr))
    best = corr[i]
    frac = 0.0
    if 0 < i < len(corr) - 1:  # parabola through the peak and its neighbours
        den = corr[i - 1] - 2 * best + corr[i + 1]
        frac = 0.5 * (corr[i - 1] - corr[i + 1]) / den if den < 0 else 0.0
    shift = (i - k_max + frac) * GRID_S
    j = int(round(0.02 / GRID_S))
    drop = float(best - np.mean([corr[max(i - j, 0)], corr[min(i + j, len(corr) - 1)]]))
    sharp = drop / max(1.0 - best, 1e-9)
    est = OffsetEstimate(-shift, True, float(best), drop, sharp, std, stretch)
    if best < MIN_CORRELATION:
        est.observable, est.reason = (
            False,
            (f"the odometry's |ω| does not follow the gyro's (correlation {best:.2f})"),
        )
    elif sharp < MIN_SHARPNESS:
        est.observable, est.reason = (
            False,
            (f"the correlation peak is flat (sharpness {sharp:.2f} < {MIN_SHARPNESS:g})"),
        )
    elif abs(i - k_max) >= k_max:
        est.observable, est.reason = False, f"the peak is at the ±{max_shift_s:g} s search edge"
    return est


def estimate_offset(
    seq: Sequence, stretch_s: float = 6.0, max_shift_s: float = 0.2
) -> OffsetEstimate:
    """Runs ct-lidar on the most excited ``stretch_s`` of ``seq`` and correlates its ``|ω|``.

    ct-lidar, not KISS-ICP: its poses follow the motion within each scan (four per scan), and
    on simulated hand-held 16/32-beam and MID-360 bags the offset came out within 0.1 ms where
    KISS-ICP's were 7-27 ms off (module docstring). Where ct-lidar loses track on the stretch,
    the offset is reported as not determined, with the reason.

    Raises:
        DataError: from reading the scans.
    """
    from l2calib.errors import ReferenceLostTrackError
    from l2calib.references.ct_lidar_source import run_segment
    from l2calib.references.options import CtLidarOptions

    margin = int((max_shift_s + 0.2) * NS_PER_S)
    a, b = most_excited_stretch(seq.imu, seq.start_ns + margin, seq.end_ns - margin, stretch_s)
    seg = seq.segment(a, b)
    try:
        poses = run_segment(seg.scans, [], CtLidarOptions(), "offset")
    except ReferenceLostTrackError as e:
        return OffsetEstimate(
            float("nan"), False, stretch=(a / NS_PER_S, b / NS_PER_S),
            reason=f"the LiDAR-only odometry lost track on the stretch ({e.message})",
        )  # fmt: skip
    return correlate_rates(poses, seq.imu, max_shift_s)


def offset_from_references(
    references: list, segments: list, sequences: list, max_shift_s: float
) -> OffsetEstimate | None:
    """The offset where the references' ``|ω|`` best follows the gyro: the median over segments.

    The starting value of the offset's estimation when no other is given (issue 21): a rate
    correlation pins a 20-50 ms offset to ~0.1 ms on hand-held data (module docstring), which
    PPO otherwise has to find while it learns the extrinsic. Uses the references with full
    poses on the LiDAR clock, except KISS-ICP's (its scan-rate poses were 7-27 ms off).

    Args:
        references: ``ReferenceTrajectory`` per segment.
        segments: The segments (for their sequence).
        sequences: The sequences (their IMU, which reaches past each segment).
        max_shift_s: Largest offset searched (s).

    Returns:
        The median estimate over the segments where it is observable, or ``None``.
    """
    imu = {s.name: s.imu for s in sequences}
    seg_of = {s.name: s for s in segments}
    found = []
    for ref in references:
        seg = seg_of.get(ref.segment)
        if ref.constrains != "pose" or ref.source == "kiss-icp" or seg is None:
            continue
        if seg.sequence not in imu or len(ref.trajectory) < 3:
            continue
        est = correlate_rates(ref.trajectory, imu[seg.sequence], max_shift_s)
        if est.observable:
            found.append(est)
    if not found:
        return None
    return found[int(np.argsort([e.time_offset_s for e in found])[len(found) // 2])]
