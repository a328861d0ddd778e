"""IMU models: white noise, bias random walk and turn-on bias, with datasheet-like presets.

Continuous-time densities (Kalibr's convention): white noise ``σ_d = density · sqrt(rate)`` per
sample, bias random walk ``b_{k+1} = b_k + rw · sqrt(dt) · N(0, 1)``. The noise-free readings
are exact derivatives of the trajectory (see :mod:`l2calib.sim.motion`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from l2calib.errors import ConfigError

_DEG = np.pi / 180.0
_G = 9.80665


@dataclass(frozen=True)
class ImuSpec:
    """One IMU model.

    Attributes:
        name: Model name.
        rate_hz: Default sample rate.
        gyro_noise_density: rad/s/sqrt(Hz).
        accel_noise_density: m/s²/sqrt(Hz).
        gyro_bias_random_walk: rad/s²/sqrt(Hz).
        accel_bias_random_walk: m/s³/sqrt(Hz).
        gyro_bias_init: Standard deviation of the turn-on gyro bias (rad/s).
        accel_bias_init: Standard deviation of the turn-on accelerometer bias (m/s²).
    """

    name: str
    rate_hz: float
    gyro_noise_density: float
    accel_noise_density: float
    gyro_bias_random_walk: float
    accel_bias_random_walk: float
    gyro_bias_init: float
    accel_bias_init: float


IMUS: dict[str, ImuSpec] = {
    # VectorNav VN-100/VN-200: 0.0035 °/s/√Hz, 0.14 mg/√Hz.
    "vn100": ImuSpec("vn100", 200.0, 0.0035 * _DEG, 0.14e-3 * _G, 2e-5, 1e-4, 2e-3, 0.02),
    "vn200": ImuSpec("vn200", 200.0, 0.0035 * _DEG, 0.14e-3 * _G, 2e-5, 1e-4, 2e-3, 0.02),
    # Xsens MTi-300: 0.01 °/s/√Hz, 60 µg/√Hz.
    "mti-300": ImuSpec("mti-300", 200.0, 0.01 * _DEG, 60e-6 * _G, 1e-5, 6e-5, 1e-3, 0.01),
    # Bosch BMI088 (MEMS, e.g. inside many small rigs): 0.014 °/s/√Hz, 175 µg/√Hz.
    "bmi088": ImuSpec("bmi088", 200.0, 0.014 * _DEG, 175e-6 * _G, 4e-5, 4e-4, 1e-2, 0.05),
    "ideal": ImuSpec("ideal", 200.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
}
IMU_NAMES = tuple(IMUS)


def get_imu(name: str) -> ImuSpec:
    """The named model; :class:`ConfigError` listing the known names otherwise."""
    if name not in IMUS:
        raise ConfigError(
            f"unknown IMU model {name!r}", fix=f"choose one of: {', '.join(IMU_NAMES)}"
        )
    return IMUS[name]


@dataclass(frozen=True)
class ImuErrors:
    """What the noise model added to the exact readings (all ``[M, 3]``, IMU frame)."""

    gyro_bias_rad_s: np.ndarray
    accel_bias_m_s2: np.ndarray
    gyro_noise_rad_s: np.ndarray
    accel_noise_m_s2: np.ndarray


def corrupt(
    spec: ImuSpec,
    rate_hz: float,
    gyro_true: np.ndarray,
    accel_true: np.ndarray,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, ImuErrors]:
    """Adds turn-on bias, bias random walk and white noise to exact readings ``[M, 3]``.

    Returns:
        Noisy gyro (rad/s), noisy accel (m/s²) and the added errors.
    """
    m, dt = gyro_true.shape[0], 1.0 / rate_hz

    def walk(init: float, rw: float) -> np.ndarray:
        steps = rng.normal(0.0, rw * np.sqrt(dt), size=(m, 3))
        steps[0] = rng.normal(0.0, init, size=3)
        return np.cumsum(steps, axis=0)

    bg = walk(spec.gyro_bias_init, spec.gyro_bias_random_walk)
    ba = walk(spec.accel_bias_init, spec.accel_bias_random_walk)
    ng = rng.normal(0.0, spec.gyro_noise_density * np.sqrt(rate_hz), size=(m, 3))
    na = rng.normal(0.0, spec.accel_noise_density * np.sqrt(rate_hz), size=(m, 3))
    return gyro_true + bg + ng, accel_true + ba + na, ImuErrors(bg, ba, ng, na)
