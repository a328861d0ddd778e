"""Where PPO's translation starts without a prior: the reference's accelerations against the IMU.

Once the extrinsic rotation is known (:mod:`l2calib.train.rotation_start`), the lever arm enters
linearly. With ``r`` the IMU's origin in the LiDAR frame (``r = −R_imu_lidarᵀ t_imu_lidar``),
the IMU moves as ``p_wi(t) = p_wl(t) + R_wl(t) r`` and its accelerometer reads
``f = R_iw (p̈_wi − g) + b``. Averaging both sides with the hat kernel of three reference poses
``t₋ < t₀ < t₊`` turns the second derivatives into the second divided differences of the
reference's poses — exact, and no noisy derivative is ever taken:

``D²[p_wl] + D²[R_wl] r = K[R_wl R_imu_lidarᵀ f] − K[R_wl] b' + g``,

where ``D²[x] = 2 x[t₋, t₀, t₊]`` (the divided difference) and ``K[x]`` is the IMU's samples
averaged with the same kernel (``b' = R_imu_lidarᵀ b``). Per segment the gravity ``g`` (in the
reference's world frame: a LiDAR-only reference does not know where "down" is) and the bias
``b'`` are unknown; ``r`` is shared. One linear least squares solves all of them, and its
covariance (residual variance × inverse normal matrix, × :data:`INFLATE` for residuals that
are correlated between overlapping kernels) gives the start's σ per IMU axis, floored at
:data:`FLOOR_M` and capped at :data:`CAP_M`. On purely planar motion the
lever arm along the rotation axis leaves no trace in ``D²[R_wl] r`` and its σ comes out wide by
itself; the simulator's drives on gently sloped terrain pin it to 0.2–0.3 cm with the exact
trajectory (the vertical hold still takes it: issue 27, ``l2calib.train.vertical_hold``).

Measured on the simulator's cases (``python -m benchmarks.experiment_lever_start``,
``benchmarks/results/experiments/lever_start.json``; start minus truth): 0.01 cm hand-held,
0.30 cm on three uav flights, 0.34 cm on three ground-vehicle drives and 0.07 cm on one VLP-32C
drive with the exact LiDAR trajectory; 0.28 cm hand-held from the LiDAR alone (``ct-lidar``).
Where a 16/32-beam ``ct-lidar`` reference of a slow drive is too noisy for the ±0.25 s kernel,
a wider one is taken (:data:`WIDER_HALF_WIDTHS_S`).
PPO, started there and at the rate rotation, is narrow enough for the refinement after its
first iteration (issue 23: ``benchmarks/results/experiments/speed_starts.json``).

This is the same idea as LI-Init's lever-arm step, on the reference's poses instead of a
spline; written here because no library solves it and it is ~100 lines of numpy.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from l2calib.data import NS_PER_S

#: Factor on the fit's 1-σ (overlapping kernels and a reference's slow drift correlate the
#: residuals).
INFLATE = 3.0
#: Least starting σ per axis (m).
FLOOR_M = 0.02
#: Largest starting σ per axis (m): the policy's own start without a guess
#: (``policy.options.init_translation_sigma_m``' default).
CAP_M = 0.5
#: Fewest kernel windows over all segments for a start.
MIN_WINDOWS = 30
#: Largest residual relative to the kernel-averaged specific force's variation: beyond it the
#: reference does not follow the accelerometer.
MAX_RELATIVE_RESIDUAL = 0.5
#: The kernel's half-width (s): long enough to average the reference's position noise
#: (σ_p √6 / h² ≈ 0.02 m/s² at 2 mm and 0.25 s), short enough to keep a hand-held rig's
#: rotation (D²[R_wl] grows like ω² + ω̇).
HALF_WIDTH_S = 0.25
#: Wider kernels tried in turn when the one before is rejected. Both sides of the fit are the
#: same kernel's averages, so any width is exact; a wider one averages a noisier reference's
#: position noise down by 1/h² and keeps a slow vehicle's accelerations (a 16-beam ct-lidar
#: reference on a 60 s drive: residual 94 % of the signal at 0.25 s, 36 % at 0.75 s, x / y
#: 0.1 / 2.1 cm from the truth; ``python -m benchmarks.experiment_lever_start --half-widths``).
WIDER_HALF_WIDTHS_S = (0.5, 0.75, 1.0)


@dataclass(frozen=True)
class LeverStart:
    """The translation PPO starts from.

    Attributes:
        translation_m: ``t_imu_lidar`` (m, IMU frame).
        sigma_m: Starting σ per IMU axis (m).
        fit_sigma_m: The fit's own 1-σ per IMU axis (m), before inflation and limits.
        relative_residual: RMS residual over the RMS of the kernel-averaged specific force
            minus its per-segment mean (how much of the motion the model leaves unexplained).
        windows: Kernel windows used.
        half_width_s: The kernel's half-width (s).
    """

    translation_m: tuple[float, float, float]
    sigma_m: tuple[float, float, float]
    fit_sigma_m: tuple[float, float, float]
    relative_residual: float
    windows: int
    half_width_s: float

    def describe(self) -> str:
        """One line for the console."""
        sig = " / ".join(f"{100 * v:.1f}" for v in self.sigma_m)
        return (
            f"the references' accelerations against the accelerometer put the lever arm's start "
            f"at σ {sig} cm (IMU x / y / z; {self.windows} windows of ±{self.half_width_s:g} s, "
            f"residual {100 * self.relative_residual:.1f} % of the specific force's variation)"
        )

    def to_dict(self) -> dict[str, Any]:
        """``calibration.yaml`` → ``translation_start``."""
        return {
            "translation_m": [round(float(v), 5) for v in self.translation_m],
            "sigma_m": [round(float(v), 4) for v in self.sigma_m],
            "fit_sigma_m": [round(float(v), 5) for v in self.fit_sigma_m],
            "relative_residual": round(float(self.relative_residual), 4),
            "windows": int(self.windows),
            "half_width_s": float(self.half_width_s),
            "meaning": "PPO's first attempt started its translation here (the references' "
            "accelerations against the accelerometer at the rate rotation); restarts start "
            "from zero",
        }


def _d2(x: np.ndarray, knots: tuple[int, int, int], t: np.ndarray) -> np.ndarray:
    """``2 x[t₋, t₀, t₊]``: the hat-kernel average of ``ẍ`` over three samples of ``x``."""
    a, b, c = knots
    return 2.0 * ((x[c] - x[b]) / (t[c] - t[b]) - (x[b] - x[a]) / (t[b] - t[a])) / (t[c] - t[a])


def _kernel_rows(traj: Any, imu: Any, R_il: np.ndarray, shift_ns: int, step: int):
    """Per hat kernel of three reference poses: ``(D²p [3], D²R [3, 3], K[R f] [3], K[R] [3, 3])``.

    ``step``: poses between the kernel's knots (its half-width).
    """
    from scipy.spatial.transform import Rotation, Slerp

    t_ref = (traj.stamps_ns - traj.stamps_ns[0]) / NS_PER_S
    R_wl = Rotation.from_quat(traj.quat_xyzw)
    slerp = Slerp(t_ref, R_wl)
    Rm = R_wl.as_matrix()
    t_imu = (imu.stamps_ns - shift_ns - traj.stamps_ns[0]) / NS_PER_S  # on the LiDAR clock
    dt_imu = np.gradient(t_imu)
    rows = []
    for k in range(step, len(t_ref) - step, max(1, step // 2)):
        tm, t0, tp = t_ref[k - step], t_ref[k], t_ref[k + step]
        lo, hi = np.searchsorted(t_imu, [tm, tp])
        if hi - lo < 6 or lo == 0 or hi >= len(t_imu):
            continue
        ts = t_imu[lo:hi]
        hat = np.where(ts < t0, (ts - tm) / (t0 - tm), (tp - ts) / (tp - t0))
        w = 2.0 / (tp - tm) * np.clip(hat, 0.0, None) * dt_imu[lo:hi]
        w /= w.sum()  # the discrete kernel integrates to one
        R_s = slerp(ts).as_matrix()  # [S, 3, 3] R_wl at the IMU samples
        KR = np.einsum("s,sij->ij", w, R_s)
        KRf = np.einsum("s,sij,jk,sk->i", w, R_s, R_il.T, imu.accel_m_s2[lo:hi])

        knots = (k - step, k, k + step)
        rows.append((_d2(traj.t_world_body, knots, t_ref), _d2(Rm, knots, t_ref), KRf, KR))
    return rows


def lever_arm_from_accelerations(
    references: list,
    segments: list,
    sequences: list,
    R_imu_lidar: np.ndarray,
    time_offset_s: float,
    half_width_s: float = HALF_WIDTH_S,
    max_relative_residual: float = MAX_RELATIVE_RESIDUAL,
) -> LeverStart | None:
    """The lever arm from every pose reference's accelerations, or ``None`` if untrustworthy.

    ``None``: fewer than :data:`MIN_WINDOWS` windows, or a residual above
    :data:`MAX_RELATIVE_RESIDUAL`.

    Args:
        references: ``ReferenceTrajectory`` per segment (those with full LiDAR poses count).
        segments: The segments (for their sequence's name).
        sequences: The sequences (their IMU).
        R_imu_lidar: ``[3, 3]`` the extrinsic rotation (from the rates).
        time_offset_s: ``t_imu = t_lidar + offset`` (s).
        half_width_s: The hat kernel's half-width (s).
        max_relative_residual: The rejection limit (an experiment passes ``inf`` to see every
            fit).
    """
    from l2calib.train.rotation_start import pose_references

    shift = int(round(time_offset_s * NS_PER_S))
    blocks = []
    for traj, samples in pose_references(references, segments, sequences, 7):
        period = float(np.median(np.diff(traj.stamps_ns))) / NS_PER_S
        step = max(1, int(round(half_width_s / period)))
        rows = _kernel_rows(traj, samples, R_imu_lidar, shift, step)
        if rows:
            blocks.append(rows)
    n = sum(len(b) for b in blocks)
    if n < MIN_WINDOWS:
        return None
    # unknowns: r (3), then per block: b' (3), g (3)
    J = np.zeros((3 * n, 3 + 6 * len(blocks)))
    y = np.zeros(3 * n)
    centred = []
    i = 0
    for b_idx, rows in enumerate(blocks):
        col = 3 + 6 * b_idx
        rhs = np.array([krf - d2p for d2p, _, krf, _ in rows])
        centred.append(rhs - rhs.mean(axis=0))
        for d2p, d2R, krf, kr in rows:
            J[i : i + 3, :3] = d2R
            J[i : i + 3, col : col + 3] = kr
            J[i : i + 3, col + 3 : col + 6] = -np.eye(3)
            y[i : i + 3] = krf - d2p
            i += 3
    x, *_ = np.linalg.lstsq(J, y, rcond=None)
    res = y - J @ x
    var = float(res @ res) / max(3 * n - J.shape[1], 1)
    cov_r = var * np.linalg.pinv(J.T @ J)[:3, :3]
    t = -R_imu_lidar @ x[:3]
    cov_t = R_imu_lidar @ cov_r @ R_imu_lidar.T
    fit = np.sqrt(np.clip(np.diag(cov_t), 0.0, None))
    sigma = np.clip(INFLATE * fit, FLOOR_M, CAP_M)
    scale = float(np.sqrt(np.mean(np.vstack(centred) ** 2)))
    relative = float(np.sqrt(np.mean(res**2)) / max(scale, 1e-12))
    if relative > max_relative_residual:
        return None
    return LeverStart(
        tuple(float(v) for v in t),  # type: ignore[arg-type]
        tuple(float(v) for v in sigma),  # type: ignore[arg-type]
        tuple(float(v) for v in fit),  # type: ignore[arg-type]
        relative,
        n,
        half_width_s,
    )


def widening_fit(
    references: list, segments: list, sequences: list, R_imu_lidar: np.ndarray, offset_s: float
) -> LeverStart | None:
    """The lever-arm fit at the narrowest kernel half-width that is accepted.

    :func:`lever_arm_from_accelerations` at :data:`HALF_WIDTH_S`, else at the first of
    :data:`WIDER_HALF_WIDTHS_S` whose fit is accepted, else ``None``.
    """
    for h in (HALF_WIDTH_S, *WIDER_HALF_WIDTHS_S):
        fit = lever_arm_from_accelerations(
            references, segments, sequences, R_imu_lidar, offset_s, half_width_s=h
        )
        if fit is not None:
            return fit
    return None


def lever_start(
    recipe: Any, data: Any, rotation: Any | None, offset_s: float, say: Callable[[str], None]
) -> LeverStart | None:
    """The first attempt's translation start (``train.translation_from_accelerations``).

    ``None`` with ``off``, with a ``policy.prior``, without a rotation start (``rotation``:
    :class:`~l2calib.train.rotation_start.RotationStart` or ``None``), or where the fit cannot
    be trusted; the reason is told where there was a rotation to fit with.

    Args:
        recipe: The recipe (``train``, ``policy.prior``).
        data: The prepared data (references, segments, sequences; the note goes to ``notes``).
        rotation: The rotation start, or ``None``.
        offset_s: The time offset the rotation start used (s, ``t_imu = t_lidar + offset``).
        say: Tells the user.
    """
    off = recipe.train.translation_from_accelerations == "off"
    if off or recipe.policy.prior is not None or rotation is None:
        return None
    from scipy.spatial.transform import Rotation

    R = Rotation.from_quat(rotation.quat_xyzw).as_matrix()
    start = widening_fit(data.references, data.segments, data.sequences, R, offset_s)
    if start is None:
        msg = (
            "the references' accelerations do not pin the lever arm (too few windows, or they "
            "do not follow the accelerometer): PPO starts its translation at zero"
        )
    else:
        msg = start.describe()
    data.notes.append(msg)
    say(msg)
    return start
