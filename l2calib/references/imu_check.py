"""Cross-check of a reference's rotation rate against the IMU gyro.

The angular speed ``|ω|`` is the same for every frame rigidly attached to one body, whatever the
extrinsic, so a ground-truth file of the LiDAR, the IMU or a mocap body must show the same
``|ω(t)|`` as the gyro. Comparing the two catches, before any training, a file on another clock
(the curves match only when shifted: the shift is the missing ``time_offset_s``) and orientations
that are not the body's (wrong quaternion order, angles of another body: the curves do not match
at all). Which clock a shift belongs to (the file's, or the IMU's against the LiDAR) is decided by
the caller (:mod:`l2calib.references.clock_shift`): the check only measures it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from l2calib import geometry as geo
from l2calib.data import NS_PER_S, ImuSamples
from l2calib.trajectory import Trajectory

GRID_S = 0.01
SMOOTH_S = 0.05
MIN_DIRECTION_RATE = 0.2  # rad/s RMS below which gyro noise could dominate the direction check


@dataclass(frozen=True)
class RateCheck:
    """Outcome of :func:`compare_rotation_rate`.

    Attributes:
        checked: False if there was too little rotation or overlap to say anything.
        correlation: Normalised correlation of the two ``|ω|`` curves at zero shift.
        best_shift_s: Shift of the reference that correlates best (``ω_ref(t + shift)``
            matches ``ω_gyro(t)``), within ``±max_shift_s``.
        best_correlation: Correlation at that shift.
        scale: Median ratio ``|ω_ref| / |ω_gyro|`` where the gyro turns faster than 0.2 rad/s.
        direction_residual: RMS of ``ω_ref - R ω_gyro`` over RMS ``|ω_gyro|`` for the best
            constant rotation ``R`` (Kabsch), at the best shift: body rates of rigidly attached
            frames differ by a constant rotation, so this is small for a consistent file (it
            catches permuted quaternion components, which leave ``|ω|`` unchanged).
        R_body_imu: ``[3, 3]`` that rotation (the rotation of the extrinsic, as a by-product).
    """

    checked: bool
    correlation: float = float("nan")
    best_shift_s: float = 0.0
    best_correlation: float = float("nan")
    scale: float = float("nan")
    direction_residual: float = float("nan")
    R_body_imu: np.ndarray | None = None


def _smooth(x: np.ndarray, width: int) -> np.ndarray:
    if width <= 1:
        return x
    return np.convolve(x, np.ones(width) / width, mode="same")


def _overlap(a: np.ndarray, b: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """``a[i + k]`` and ``b[i]`` over their common indices."""
    return (a[k:], b[: len(b) - k]) if k >= 0 else (a[: len(a) + k], b[-k:])


def pearson(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson correlation of two equally long series (0 when either is constant)."""
    a, b = a - a.mean(), b - b.mean()
    den = float(np.sqrt((a * a).sum() * (b * b).sum()))
    return float((a * b).sum() / den) if den > 0 else 0.0


def compare_rotation_rate(
    ref: Trajectory,
    imu: ImuSamples,
    start_ns: int,
    end_ns: int,
    max_shift_s: float = 1.0,
    min_rate_std: float = 0.1,
) -> RateCheck:
    """Compares ``|ω|`` of ``ref`` with the gyro over ``[start_ns, end_ns]``.

    Shifts of the reference up to ``±max_shift_s`` are tried for the clock check.

    Returns:
        A :class:`RateCheck`; ``checked`` is False when the gyro's ``|ω|`` varies by less than
        ``min_rate_std`` rad/s or the overlap is shorter than 2 s.
    """
    lo = max(start_ns, int(imu.stamps_ns[0]), int(ref.stamps_ns[0]))
    hi = min(end_ns, int(imu.stamps_ns[-1]), int(ref.stamps_ns[-1]))
    n = int((hi - lo) / (GRID_S * NS_PER_S))
    if n < int(2.0 / GRID_S):
        return RateCheck(False)
    grid = lo + np.arange(n, dtype=np.int64) * int(GRID_S * NS_PER_S)
    sampled, ok = ref.sample(grid, max_gap_s=max(1.0, 2 * max_shift_s))
    R = geo.quat_to_matrix(torch.from_numpy(sampled.quat_xyzw))
    rate_ref = np.full(n - 1, np.nan)
    both = ok[:-1] & ok[1:]
    idx = np.flatnonzero(ok)
    pos = np.searchsorted(idx, np.flatnonzero(both))
    step = R[pos].transpose(-1, -2) @ R[pos + 1]
    w_ref = np.full((n - 1, 3), np.nan)
    w_ref[both] = geo.so3_log(step).numpy() / GRID_S
    rate_ref = np.linalg.norm(w_ref, axis=1)
    mid = grid[:-1] + int(GRID_S * NS_PER_S / 2)
    gyro = np.stack([np.interp(mid, imu.stamps_ns, imu.gyro_rad_s[:, k]) for k in range(3)], axis=1)
    rate_gyro = np.linalg.norm(gyro, axis=1)
    width = int(round(SMOOTH_S / GRID_S))
    good = np.isfinite(rate_ref)
    if good.sum() < int(2.0 / GRID_S) or float(np.std(rate_gyro[good])) < min_rate_std:
        return RateCheck(False)
    fill = np.where(
        good, rate_ref, np.interp(np.arange(n - 1), np.flatnonzero(good), rate_ref[good])
    )
    a, b = _smooth(fill, width), _smooth(rate_gyro, width)
    best, best_c = 0, -2.0
    max_k = min(int(max_shift_s / GRID_S), (n - 1) // 3)
    for k in range(-max_k, max_k + 1):
        c = pearson(*_overlap(a, b, k))
        if c > best_c:
            best, best_c = k, c
    fast = good & (rate_gyro > 0.2)
    scale = float(np.median(rate_ref[fast] / rate_gyro[fast])) if fast.sum() > 10 else float("nan")
    # Kabsch: w_ref ≈ R w_gyro with one rotation (unweighted Umeyama without translation), at
    # the best shift so that a clock offset does not read as inconsistent directions
    w_ref_s, gyro_s = _overlap(w_ref, gyro, best)
    good_s = np.isfinite(w_ref_s).all(axis=1)
    wr = np.stack([_smooth(w_ref_s[good_s, k], width) for k in range(3)], axis=1)
    wg = np.stack([_smooth(gyro_s[good_s, k], width) for k in range(3)], axis=1)
    U, _, Vt = np.linalg.svd(wr.T @ wg)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R_bi = U @ D @ Vt
    resid = float(np.sqrt(np.mean(np.sum((wr - wg @ R_bi.T) ** 2, axis=1))))
    spread = float(np.sqrt(np.mean(np.sum(wg**2, axis=1))))
    ratio = resid / spread if spread >= MIN_DIRECTION_RATE else float("nan")  # else noise-bound
    return RateCheck(True, pearson(a, b), best * GRID_S, best_c, scale, ratio, R_bi)
