"""Excitation of sliding windows from IMU samples (paper Sec. III-D).

For every window ``[s, s + window_s]`` (stride ``step_s``) of a sequence's LiDAR–IMU overlap:

* ``J_r`` stacks the angular velocities ω_k (rad/s), ``J_t`` the gravity-free linear
  accelerations a_k (m/s²). Both are normalised per sample (``JᵀJ / N``, the second-moment
  matrix), so scores do not depend on the IMU rate or the window length; their minimum
  eigenvalues (λ_r, λ_t) are the paper's criteria.
* **Gravity removal**: the gyro is integrated over the whole sequence (exact quaternion
  products, a parallel prefix scan), each specific force f_k is rotated into that frame,
  and the window's mean R_k f_k is taken as gravity there: ``a_k = f_k − R_kᵀ ḡ``. Constant gravity
  (and a constant accelerometer bias while not rotating) therefore never counts as excitation,
  and neither does gravity merely turning in the IMU frame while the IMU tilts. Gyro bias drift
  over one window (e.g. 0.005 rad/s × 5 s → 0.25 m/s² at the window edges) is the residual.
* **Score** ``min(√λ_r / min_gyro_rad_s, √λ_t / min_accel_m_s2)``: ≥ 1 means every axis of
  both is excited above the recipe thresholds (defaults 0.2 rad/s, 0.3 m/s² RMS).
* **Eligibility**: a window is never chosen if it contains a still block (a ``step_s`` block
  with RMS |ω| < 0.05 rad/s and RMS |f − mean f| < 0.15 m/s²; IMU noise and bias of MEMS parts
  stay well below, walking or driving stays well above), an IMU gap (> 5 median intervals and
  > 20 ms) or a LiDAR gap (> 1.8 median scan intervals; a hole left by up to
  :data:`~l2calib.io.stamps.MAX_BRIDGED_EMPTY_SCANS` empty scans, dropped on reading, is not a
  gap: :func:`~l2calib.io.stamps.lidar_gaps`).
* **Gaps split the data**: a gap-free stretch that holds no whole window (e.g. the 4 s on either
  side of a 2 s IMU gap with 5 s windows) gets one window of its own, up to ``window_s`` long from
  its start, if it is at least :data:`MIN_STRETCH_SHARE` of a window long.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from l2calib.data import NS_PER_S, Sequence
from l2calib.io.stamps import lidar_gaps
from l2calib.recipe import SelectionConfig

STILL_GYRO_RAD_S = 0.05
STILL_ACCEL_M_S2 = 0.15
IMU_GAP_FACTOR, IMU_MIN_GAP_S, LIDAR_GAP_FACTOR = 5.0, 0.02, 1.8
#: A gap-free stretch shorter than a window gets a window of its own from this share of one.
MIN_STRETCH_SHARE = 0.5


@dataclass(frozen=True, eq=False)
class WindowStats:
    """Excitation of every candidate window of one sequence.

    Attributes:
        sequence: Sequence name.
        start_ns, end_ns: ``[W]`` window bounds (ns).
        gyro_moment: ``[W, 3, 3]`` mean ω ωᵀ in the IMU frame ((rad/s)²).
        accel_moment: ``[W, 3, 3]`` mean a aᵀ of gravity-free acceleration ((m/s²)²).
        lambda_gyro, lambda_accel: ``[W]`` minimum eigenvalues of those.
        score: ``[W]`` normalised score (see module docs).
        still_share: ``[W]`` fraction of the window's blocks that are still.
        gap: ``[W]`` whether an IMU or LiDAR gap falls inside.
        eligible: ``[W]`` may be chosen.
        block_start_ns: ``[B]`` starts of the still-detection blocks.
        block_still: ``[B]`` whether each block is still.
        imu_gaps_ns: ``[(before_ns, after_ns), ...]`` IMU gaps (samples around each).
        lidar_gaps_ns: ``[(before_ns, after_ns), ...]`` LiDAR gaps (kept scans around each).
    """

    sequence: str
    start_ns: np.ndarray
    end_ns: np.ndarray
    gyro_moment: np.ndarray
    accel_moment: np.ndarray
    lambda_gyro: np.ndarray
    lambda_accel: np.ndarray
    score: np.ndarray
    still_share: np.ndarray
    gap: np.ndarray
    eligible: np.ndarray
    block_start_ns: np.ndarray
    block_still: np.ndarray
    imu_gaps_ns: tuple[tuple[int, int], ...] = ()
    lidar_gaps_ns: tuple[tuple[int, int], ...] = ()

    def __len__(self) -> int:
        return int(self.start_ns.shape[0])


def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of ``[..., 4]`` xyzw quaternions."""
    ax, ay, az, aw = np.moveaxis(a, -1, 0)
    bx, by, bz, bw = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ],
        axis=-1,
    )


def integrate_gyro(stamps_ns: np.ndarray, gyro_rad_s: np.ndarray) -> np.ndarray:
    """``[M, 4]`` xyzw orientations R_k (IMU k → frame of sample 0) from the gyro alone.

    Uses ω_k over ``[t_k, t_{k+1}]``; the cumulative product is a Hillis–Steele scan
    (log2 M vectorised steps) because numpy/scipy have no cumulative rotation product.
    """
    m = len(stamps_ns)
    dt = np.diff(stamps_ns).astype(np.float64) / NS_PER_S
    rv = gyro_rad_s[:-1] * dt[:, None]
    ang = np.linalg.norm(rv, axis=1)
    half = 0.5 * ang
    s = np.where(ang > 1e-12, np.sin(half) / np.where(ang > 1e-12, ang, 1.0), 0.5)
    q = np.concatenate([rv * s[:, None], np.cos(half)[:, None]], axis=1)
    q = np.concatenate([[[0.0, 0.0, 0.0, 1.0]], q], axis=0)
    d = 1
    while d < m:
        q[d:] = _qmul(q[:-d].copy(), q[d:])
        d *= 2
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _rotate(q: np.ndarray, v: np.ndarray, inverse: bool = False) -> np.ndarray:
    """Rotates ``[N, 3]`` vectors by ``[N, 4]`` xyzw quaternions (or their inverses)."""
    u, w = q[:, :3], q[:, 3:4]
    if inverse:
        u = -u
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def _gap_mask(starts: np.ndarray, ends: np.ndarray, gaps: list[tuple[int, int]]) -> np.ndarray:
    bad = np.zeros(len(starts), bool)
    for a, b in gaps:
        bad |= (starts < b) & (ends > a)
    return bad


def find_gaps(stamps: np.ndarray, factor: float, min_s: float) -> list[tuple[int, int]]:
    """``[(before_ns, after_ns), ...]`` around intervals > ``factor`` x median and > ``min_s``."""
    d = np.diff(stamps)
    if d.size == 0:
        return []
    thr = max(factor * float(np.median(d)), min_s * NS_PER_S)
    return [(int(stamps[i]), int(stamps[i + 1])) for i in np.flatnonzero(d > thr)]


def _stretch_windows(
    starts: np.ndarray, ends: np.ndarray, lo: int, hi: int, win: int, gaps: list
) -> tuple[np.ndarray, np.ndarray]:
    """Adds a window to each gap-free stretch of ``[lo, hi]`` that holds no whole window."""
    merged: list[list[int]] = []
    for a, b in sorted((max(a, lo), min(b, hi)) for a, b in gaps if a < hi and b > lo):
        if merged and a <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], b)
        else:
            merged.append([a, b])
    cuts = [lo, *(x for g in merged for x in g), hi]
    extra_s, extra_e = [], []
    for a, b in zip(cuts[::2], cuts[1::2], strict=True):
        inside = (starts >= a) & (ends <= b)
        if b - a >= MIN_STRETCH_SHARE * win and not inside.any():
            extra_s.append(a)
            extra_e.append(min(b, a + win))
    if not extra_s:
        return starts, ends
    starts = np.concatenate([starts, np.array(extra_s, dtype=np.int64)])
    ends = np.concatenate([ends, np.array(extra_e, dtype=np.int64)])
    order = np.argsort(starts, kind="stable")
    return starts[order], ends[order]


def window_excitation(seq: Sequence, config: SelectionConfig) -> WindowStats:
    """Scores every window of ``seq`` (only its IMU samples and scan stamps are used)."""
    imu = seq.imu
    st, w, f = imu.stamps_ns, imu.gyro_rad_s, imu.accel_m_s2
    lo, hi = seq.start_ns, seq.end_ns
    win = int(round(min(config.window_s, (hi - lo) / NS_PER_S) * NS_PER_S))
    step = int(round(config.step_s * NS_PER_S))
    starts = np.arange(lo, hi - win + 1, step, dtype=np.int64) if win > 0 else np.zeros(0, int)
    ends = starts + win
    imu_gaps = find_gaps(st, IMU_GAP_FACTOR, IMU_MIN_GAP_S)
    scan_gaps = lidar_gaps(
        np.asarray(seq.scans.stamps_ns), getattr(seq.scans, "empty_before", None), LIDAR_GAP_FACTOR
    )
    gaps = imu_gaps + scan_gaps
    if win > 0:
        starts, ends = _stretch_windows(starts, ends, lo, hi, win, gaps)
    q = integrate_gyro(st, w)
    f_world = _rotate(q, f)
    n = len(starts)
    gm, am = np.zeros((n, 3, 3)), np.zeros((n, 3, 3))
    i0 = np.searchsorted(st, starts, "left")
    i1 = np.searchsorted(st, ends, "right")
    for k in range(n):
        a, b = i0[k], i1[k]
        if b - a < 2:
            continue
        ww = w[a:b]
        g_bar = f_world[a:b].mean(axis=0)
        lin = f[a:b] - _rotate(q[a:b], np.broadcast_to(g_bar, (b - a, 3)), inverse=True)
        gm[k] = ww.T @ ww / (b - a)
        am[k] = lin.T @ lin / (b - a)
    lam_g = np.clip(np.linalg.eigvalsh(gm)[:, 0], 0, None) if n else np.zeros(0)
    lam_a = np.clip(np.linalg.eigvalsh(am)[:, 0], 0, None) if n else np.zeros(0)
    score = np.minimum(
        np.sqrt(lam_g) / config.min_gyro_rad_s, np.sqrt(lam_a) / config.min_accel_m_s2
    )
    # still blocks
    b_starts = np.arange(lo, hi, step, dtype=np.int64)
    j0 = np.searchsorted(st, b_starts, "left")
    j1 = np.searchsorted(st, b_starts + step, "left")
    still = np.zeros(len(b_starts), bool)
    for k, (a, b) in enumerate(zip(j0, j1, strict=True)):
        if b - a >= 2:
            rms_w = np.sqrt(np.mean(np.sum(w[a:b] ** 2, axis=1)))
            std_f = np.sqrt(np.sum(f[a:b].var(axis=0)))
            still[k] = rms_w < STILL_GYRO_RAD_S and std_f < STILL_ACCEL_M_S2
    share = np.zeros(n)
    for k in range(n):
        inside = (b_starts >= starts[k]) & (b_starts + step <= ends[k])
        share[k] = still[inside].mean() if inside.any() else 0.0
    gap = _gap_mask(starts, ends, gaps)
    eligible = (share == 0) & ~gap & ((i1 - i0) >= 2)
    return WindowStats(
        seq.name,
        starts,
        ends,
        gm,
        am,
        lam_g,
        lam_a,
        score,
        share,
        gap,
        eligible,
        b_starts,
        still,
        tuple(imu_gaps),
        tuple(scan_gaps),
    )
