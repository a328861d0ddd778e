"""Synthetic IMU signals for unit tests (no simulator): exact rotation + gravity + noise.

Orientation is a sum of sinusoidal rotation vectors per axis; angular velocity comes from
consecutive orientations (body frame), specific force is ``R^T (a_world + g e_z)``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

G = 9.81


def imu_signal(
    duration_s: float,
    rate_hz: float = 200.0,
    rot_amp_rad: tuple[float, float, float] = (0.5, 0.5, 0.8),
    rot_freq_hz: tuple[float, float, float] = (0.4, 0.55, 0.3),
    acc_amp_m_s2: tuple[float, float, float] = (1.0, 1.0, 0.5),
    acc_freq_hz: tuple[float, float, float] = (0.7, 0.5, 1.1),
    still: list[tuple[float, float]] = (),
    start_ns: int = 1_700_000_000_000_000_000,
    noise: tuple[float, float] = (0.002, 0.02),
    yaw_rate_rad_s: float = 0.0,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Returns ``(stamps_ns [M], gyro_rad_s [M, 3], accel_m_s2 [M, 3])``.

    ``still`` periods (s, relative to the start) freeze the motion (smoothly blended over 0.5 s).
    ``yaw_rate_rad_s`` adds a constant yaw rate (planar driving).
    """
    rng = np.random.default_rng(seed)
    n = int(round(duration_s * rate_hz)) + 1
    t = np.arange(n + 1) / rate_hz
    act = np.ones_like(t)
    for a, b in still:  # 0 inside, linear 0.5 s ramps outside
        dist = np.maximum(np.maximum(a - t, t - b), 0.0)
        act = np.minimum(act, np.clip(dist / 0.5, 0.0, 1.0))
    # "Activity" integrated in time so that motion stops (not jumps) in still periods.
    tau = np.concatenate([[0.0], np.cumsum(act[1:] * np.diff(t))])
    phases = rng.uniform(0, 2 * np.pi, 6)
    rv = np.stack(
        [rot_amp_rad[i] * np.sin(2 * np.pi * rot_freq_hz[i] * tau + phases[i]) for i in range(3)],
        axis=1,
    )
    yaw = yaw_rate_rad_s * tau
    R = Rotation.from_rotvec(
        np.stack([np.zeros_like(yaw), np.zeros_like(yaw), yaw], 1)
    ) * Rotation.from_rotvec(rv)
    a_w = (
        np.stack(
            [
                acc_amp_m_s2[i] * np.sin(2 * np.pi * acc_freq_hz[i] * tau + phases[3 + i])
                for i in range(3)
            ],
            axis=1,
        )
        * act[:, None]
    )
    dR = R[:-1].inv() * R[1:]
    gyro = dR.as_rotvec() * rate_hz
    f = R[:-1].inv().apply(a_w[:-1] + np.array([0.0, 0.0, G]))
    gyro = gyro[:n] + rng.normal(0, noise[0], (n, 3))
    f = f[:n] + rng.normal(0, noise[1], (n, 3))
    stamps = start_ns + np.round(t[:n] * 1e9).astype(np.int64)
    return stamps, gyro, f
