"""Where PPO's rotation starts without a prior: the reference's body rates against the gyro.

A rigid body's angular velocity seen in the LiDAR frame (the reference's rotation increments)
and in the IMU frame (the gyro, averaged over the same intervals) differ by the extrinsic
rotation alone: ``w_imu = R_imu_lidar w_lidar + b_gyro``. Its least-squares ``R`` (Kabsch/SVD,
with a constant gyro bias per segment) needs no odometry run. Measured on the simulator's
recordings with the exact LiDAR trajectory (``benchmarks/experiment_rate_rotation.py``,
``benchmarks/results/experiments/rotation_from_rates.json``): 0.044° from the truth hand-held,
0.48° on a uav flight, 0.10° / 0.78° on ground-vehicle drives.

Why it matters (issue 27, ``docs/backends.md``): on planar drives the reward is a needle in
roll and pitch (0.961 at the truth, 0.87 at 2°, ~0.1 at 5°), so PPO from a uniform rotation saw
rewards near 0 for 60 iterations and was trapped 28-39° off on a VLP-32C drive. Started at the
rate rotation with a spread per LiDAR axis from the fit's own covariance, it starts inside.

The spread (``sigma_deg``, per LiDAR axis) is the fit's 1-σ (residual variance × inverse
information ``Σ [w]ₓᵀ[w]ₓ``), times :data:`INFLATE` for residuals correlated in time, floored
at :data:`FLOOR_DEG` and capped at :data:`CAP_DEG`. On planar data the rotation about the
vertical rests on the small off-axis rates only, and its σ comes out wide by itself. The σ is
per LiDAR axis (the Bingham's concentrations are), so with a LiDAR mounted tilted from upright
on a ground vehicle the wide vertical σ spreads over two axes.

A wrong start (a reference that lost track) cannot trap every attempt: restarts after a failed
reference-agreement check start from no guess (``l2calib.training``), and the attempt with the
highest reward is kept.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from l2calib.data import NS_PER_S

#: Factor on the fit's 1-σ: rate residuals at 10-40 Hz are correlated over several intervals.
INFLATE = 3.0
#: Least starting σ per axis (deg): the planar reward's roll/pitch needle is ~2-5° wide.
FLOOR_DEG = 2.0
#: Largest starting σ per axis (deg); an axis the rates do not determine starts this wide.
CAP_DEG = 30.0
#: Fewest rate intervals over all segments for a start.
MIN_INTERVALS = 30
#: Largest residual relative to the rates' RMS: beyond it the reference does not follow the gyro
#: (rates unrelated to the gyro give ~1; ct-lidar on a gentle VLP-32C drive gave 0.17, with the
#: start 0.05° from the truth: ``results/experiments/rotation_start.json``).
MAX_RELATIVE_RESIDUAL = 0.5


@dataclass(frozen=True)
class RotationStart:
    """The rotation PPO starts from.

    Attributes:
        quat_xyzw: ``R_imu_lidar`` as a unit quaternion ``(x, y, z, w)``.
        sigma_deg: Starting σ per LiDAR axis (deg).
        fit_sigma_deg: The fit's own 1-σ per LiDAR axis (deg), before inflation and limits.
        singular_values: Of ``Σ w_lidar w_imuᵀ``, normalised by the largest (how much motion
            each direction rests on; ~0.001 on planar drives).
        relative_residual: RMS of ``w_imu − R w_lidar − b`` over the RMS of ``w_imu``.
        intervals: Rate intervals used.
    """

    quat_xyzw: tuple[float, float, float, float]
    sigma_deg: tuple[float, float, float]
    fit_sigma_deg: tuple[float, float, float]
    singular_values: tuple[float, float, float]
    relative_residual: float
    intervals: int

    def describe(self) -> str:
        """One line for the console."""
        sig = " / ".join(f"{v:.1f}" for v in self.sigma_deg)
        return (
            f"the references' rotation rates against the gyro put the extrinsic rotation's start "
            f"at σ {sig}° (LiDAR x / y / z; {self.intervals} intervals, residual "
            f"{100 * self.relative_residual:.1f} % of the rates)"
        )

    def to_dict(self) -> dict[str, Any]:
        """``calibration.yaml`` → ``rotation_start``."""
        return {
            "quat_xyzw": [round(float(v), 6) for v in self.quat_xyzw],
            "sigma_deg": [round(float(v), 3) for v in self.sigma_deg],
            "fit_sigma_deg": [round(float(v), 4) for v in self.fit_sigma_deg],
            "singular_values": [round(float(v), 5) for v in self.singular_values],
            "relative_residual": round(float(self.relative_residual), 4),
            "intervals": int(self.intervals),
            "meaning": "PPO's first attempt started its rotation here (the references' body "
            "rates against the gyro, SVD); restarts start from no guess",
        }


def mean_gyro(stamps_ns: np.ndarray, gyro: np.ndarray, a_ns: np.ndarray, b_ns: np.ndarray):
    """The gyro ``[N, 3]`` (rad/s) averaged over each interval ``[a, b]`` (IMU clock, ns).

    Through the running trapezoid integral, vectorised over the intervals.
    """
    t = (stamps_ns - stamps_ns[0]) / NS_PER_S
    steps = 0.5 * (gyro[1:] + gyro[:-1]) * np.diff(t)[:, None]
    integral = np.vstack([np.zeros((1, 3)), np.cumsum(steps, axis=0)])
    ta, tb = (a_ns - stamps_ns[0]) / NS_PER_S, (b_ns - stamps_ns[0]) / NS_PER_S
    at = np.stack([np.interp(tb, t, integral[:, k]) - np.interp(ta, t, integral[:, k])
                   for k in range(3)], axis=1)  # fmt: skip
    return at / (tb - ta)[:, None]


def _skew(w: np.ndarray) -> np.ndarray:
    """``[N, 3, 3]`` cross-product matrices of ``[N, 3]`` vectors."""
    out = np.zeros((len(w), 3, 3))
    out[:, 0, 1], out[:, 0, 2], out[:, 1, 2] = -w[:, 2], w[:, 1], -w[:, 0]
    return out - out.transpose(0, 2, 1)


def fit_rotation(pairs: list[tuple[np.ndarray, np.ndarray]], iterations: int = 4):
    """``R_imu_lidar`` and a gyro bias per pair from body rates ``(w_lidar, w_imu)`` ``[N, 3]``.

    Alternates the Kabsch rotation with the per-pair mean residual (the bias).

    Returns:
        ``(R [3, 3], residuals [N_all, 3], singular values [3])``.
    """
    bias = [np.zeros(3) for _ in pairs]
    wl = np.vstack([p[0] for p in pairs])
    for _ in range(iterations):
        wi = np.vstack([p[1] - b for p, b in zip(pairs, bias, strict=True)])
        U, S, Vt = np.linalg.svd(wl.T @ wi)
        D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
        R = Vt.T @ D @ U.T
        bias = [np.mean(p[1] - p[0] @ R.T, axis=0) for p in pairs]
    res = np.vstack([p[1] - p[0] @ R.T - b for p, b in zip(pairs, bias, strict=True)])
    return R, res, S / S[0]


def pose_references(references: list, segments: list, sequences: list, min_poses: int):
    """``(trajectory, imu)`` of every full-pose reference with ``min_poses`` poses or more.

    A trajectory shared by several segments (one reference for a whole recording) comes once,
    with its sequence's IMU samples.
    """
    imu = {s.name: s.imu for s in sequences}
    seq_of = {s.name: s.sequence for s in segments}
    seen = set()
    for ref in references:
        samples = imu.get(seq_of.get(ref.segment, ""))
        traj = ref.trajectory
        if ref.constrains != "pose" or samples is None or len(traj) < min_poses:
            continue
        if id(traj) not in seen:
            seen.add(id(traj))
            yield traj, samples


def rotation_from_rates(
    references: list, segments: list, sequences: list, time_offset_s: float
) -> RotationStart | None:
    """The rate rotation over every pose reference, or ``None`` where it cannot be trusted.

    Args:
        references: ``ReferenceTrajectory`` per segment (those with full LiDAR poses count).
        segments: The segments (for their sequence's name).
        sequences: The sequences (their IMU).
        time_offset_s: ``t_imu = t_lidar + offset`` (s) used to pick the gyro's intervals.
    """
    from scipy.spatial.transform import Rotation

    pairs = []
    for traj, samples in pose_references(references, segments, sequences, 3):
        R = Rotation.from_quat(traj.quat_xyzw).as_matrix()
        dt = np.diff(traj.stamps_ns) / NS_PER_S
        rel = np.einsum("nji,njk->nik", R[:-1], R[1:])  # R_iᵀ R_{i+1}: the LiDAR-frame step
        w_lidar = Rotation.from_matrix(rel).as_rotvec() / dt[:, None]
        shift = int(round(time_offset_s * NS_PER_S))
        a, b = traj.stamps_ns[:-1] + shift, traj.stamps_ns[1:] + shift
        inside = (a >= samples.stamps_ns[0]) & (b <= samples.stamps_ns[-1]) & (dt > 0)
        if inside.sum() >= 3:
            w_imu = mean_gyro(samples.stamps_ns, samples.gyro_rad_s, a[inside], b[inside])
            pairs.append((w_lidar[inside], w_imu))
    n = sum(len(p[0]) for p in pairs)
    if n < MIN_INTERVALS:
        return None
    R, res, sv = fit_rotation(pairs)
    scale = np.sqrt(np.mean(np.vstack([p[1] for p in pairs]) ** 2) * 3)
    relative = float(np.sqrt(np.mean(np.sum(res**2, axis=1))) / max(scale, 1e-12))
    if relative > MAX_RELATIVE_RESIDUAL:
        return None
    centred = np.vstack([p[0] - p[0].mean(axis=0) for p in pairs])
    K = _skew(centred)
    info = np.einsum("nji,njk->ik", K, K)  # Σ [w]ₓᵀ[w]ₓ in the LiDAR frame
    var = float(np.sum(res**2)) / max(3 * n - 3 - 3 * len(pairs), 1)
    cov = var * np.linalg.pinv(info)
    fit = np.degrees(np.sqrt(np.clip(np.diag(cov), 0.0, None)))
    sigma = np.clip(INFLATE * fit, FLOOR_DEG, CAP_DEG)
    q = Rotation.from_matrix(R).as_quat()
    return RotationStart(
        tuple(float(v) for v in q),  # type: ignore[arg-type]
        tuple(float(v) for v in sigma),  # type: ignore[arg-type]
        tuple(float(v) for v in fit),  # type: ignore[arg-type]
        tuple(float(v) for v in sv),  # type: ignore[arg-type]
        relative,
        n,
    )


def rotation_start(recipe: Any, data: Any, say: Callable[[str], None]) -> RotationStart | None:
    """The first attempt's rotation start (``train.rotation_from_rates``), or ``None``.

    ``None`` with ``off``, with a ``policy.prior`` (the user's guess wins), or where the rates
    do not give a trustworthy fit; the reason is told.
    """
    if recipe.train.rotation_from_rates == "off" or recipe.policy.prior is not None:
        return None

    offset = start_offset_s(recipe, data)
    start = rotation_from_rates(data.references, data.segments, data.sequences, offset)
    if start is None:
        msg = (
            "the references' rotation rates do not pin the extrinsic rotation (too few pose "
            "intervals, or they do not follow the gyro): PPO starts from a uniform rotation"
        )
    else:
        msg = start.describe()
    data.notes.append(msg)
    say(msg)
    return start


def start_offset_s(recipe: Any, data: Any) -> float:
    """The time offset the starts are fitted at (s).

    The one the odometry runs at: held, else where its estimate starts.
    """
    from l2calib.train.offset_hold import offset_start_s

    train = recipe.train
    offset = train.known_time_offset_s
    if offset is None:
        offset = offset_start_s(train, data.time_offset_hint_s)
    return offset or 0.0
