"""``sensor_msgs/Imu`` topics: streaming collection, unit detection and conversion to SI.

Unit detection (:func:`detect_units`), each with the evidence it used:

* **accelerometer** — the specific-force magnitude of the quietest half-second blocks is gravity:
  ≈ 9.81 means m/s², ≈ 1 means g (accepted within ±25 %). Anything else is reported, not
  guessed.
* **gyroscope** — kinematic check first: when the IMU tilts, gravity turns in the body frame at
  the gyro's rate, ``df/dt ≈ -k (ω × f)`` (plus the derivative of the linear acceleration,
  uncorrelated noise here). The least-squares ``k`` is ≈ 1 for rad/s and ≈ π/180 for deg/s;
  it is trusted when the fit's correlation exceeds 0.3. Without tilting motion (pure yaw, still)
  the magnitude decides: a 99th-percentile rate above 20 (1,150 °/s if it were rad/s) is deg/s.
  Then the noise at rest (blocks whose specific force varies by < 0.08 m/s²): a gyro std above
  0.03 is deg/s (0.03 rad/s = 1.7 °/s of noise at rest is implausible), below 0.005 rad/s.
  Otherwise rad/s (REP 103) is assumed and flagged as unconfirmed.
"""

from __future__ import annotations

from array import array
from dataclasses import asdict, dataclass, field

import numpy as np

from l2calib.data import ImuSamples
from l2calib.errors import DataError
from l2calib.io.bag_reader import Bag, BagMessage, header_stamp_ns
from l2calib.recipe import ImuInput

STANDARD_GRAVITY = 9.80665
DEG = np.pi / 180.0
_KIN_MIN_CORR = 0.3
_DEG_MAGNITUDE = 20.0
_REST_DEG, _REST_RAD = 0.03, 0.005  # gyro std at rest: above -> deg/s, below -> rad/s
_REST_ACCEL_STD = 0.08  # m/s^2: a block this quiet is at rest (no vibration)


@dataclass(frozen=True, eq=False)
class RawImu:
    """IMU messages as stored (units unknown), in arrival order.

    Attributes:
        header_ns: ``[M]`` header stamps.
        record_ns: ``[M]`` record times.
        gyro: ``[M, 3]`` angular velocity as stored.
        accel: ``[M, 3]`` linear acceleration as stored.
    """

    header_ns: np.ndarray
    record_ns: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray

    def __len__(self) -> int:
        return int(self.header_ns.shape[0])


@dataclass
class ImuTopicReader:
    """Collects one Imu topic message by message (use :meth:`feed`, then :meth:`finish`).

    Values go to flat typed buffers (16 bytes of stamps and 48 of values per sample).
    """

    bag: Bag
    topic: str
    _stamps: array = field(default_factory=lambda: array("q"))
    _values: array = field(default_factory=lambda: array("d"))

    def feed(self, message: BagMessage) -> None:
        """Adds one message."""
        m = self.bag.deserialize(message)
        w, a = m.angular_velocity, m.linear_acceleration
        self._stamps.extend((header_stamp_ns(m), message.record_ns))
        self._values.extend((w.x, w.y, w.z, a.x, a.y, a.z))

    def finish(self) -> RawImu:
        """The collected samples."""
        stamps = np.frombuffer(self._stamps, dtype=np.int64).reshape(-1, 2).copy()
        values = np.frombuffer(self._values, dtype=np.float64).reshape(-1, 6).copy()
        return RawImu(stamps[:, 0], stamps[:, 1], values[:, :3], values[:, 3:])


@dataclass(frozen=True)
class ImuUnits:
    """Units of a raw IMU stream and why.

    Attributes:
        gyro_unit: ``rad/s`` or ``deg/s``.
        accel_unit: ``m/s^2`` or ``g``.
        gyro_confirmed: Whether evidence (or the recipe) supports ``gyro_unit``.
        accel_confirmed: Whether evidence (or the recipe) supports ``accel_unit``.
        gyro_evidence, accel_evidence: Human-readable evidence.
        rest_accel_norm: Specific-force magnitude of the quietest blocks, stored units.
        kinematic_scale: Fitted ``k`` of ``df/dt = -k ω × f`` (NaN if not computable).
        kinematic_corr: Correlation of that fit.
        detected: Which of the two units were detected rather than given.
    """

    gyro_unit: str
    accel_unit: str
    gyro_confirmed: bool
    accel_confirmed: bool
    gyro_evidence: str
    accel_evidence: str
    rest_accel_norm: float
    kinematic_scale: float
    kinematic_corr: float
    detected: tuple[str, ...] = ()

    def as_dict(self) -> dict:
        """JSON-serialisable form."""
        d = asdict(self)
        d["detected"] = list(self.detected)
        return {
            k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in d.items()
        }

    @property
    def gyro_scale(self) -> float:
        """Factor to rad/s."""
        return DEG if self.gyro_unit == "deg/s" else 1.0

    @property
    def accel_scale(self) -> float:
        """Factor to m/s²."""
        return STANDARD_GRAVITY if self.accel_unit == "g" else 1.0


def _smooth(x: np.ndarray, k: int) -> np.ndarray:
    if k <= 1:
        return x
    c = np.cumsum(np.vstack([np.zeros((1, x.shape[1])), x]), axis=0)
    return (c[k:] - c[:-k]) / k


def kinematic_gyro_scale(
    stamps_ns: np.ndarray, gyro: np.ndarray, accel: np.ndarray
) -> tuple[float, float]:
    """Fits ``df/dt = -k (ω × f)`` over the stream; returns ``(k, correlation)``.

    Both signals are smoothed over ~50 ms and the derivative is taken across that window; ``k``
    does not depend on the accelerometer's unit.
    """
    if len(stamps_ns) < 20:
        return float("nan"), 0.0
    t = (stamps_ns - stamps_ns[0]) / 1e9
    dt = float(np.median(np.diff(t)))
    if dt <= 0:
        return float("nan"), 0.0
    k = max(1, int(round(0.05 / dt)))
    ts = _smooth(t[:, None], k)[:, 0]
    ws, fs = _smooth(gyro, k), _smooth(accel, k)
    if len(ts) <= 2 * k:
        return float("nan"), 0.0
    span = ts[2 * k :] - ts[: -2 * k]
    fdot = (fs[2 * k :] - fs[: -2 * k]) / span[:, None]
    c = -np.cross(ws[k:-k], fs[k:-k])
    num, den = float(np.sum(fdot * c)), float(np.sum(c * c))
    norm = float(np.sqrt(np.sum(fdot * fdot) * den))
    if den <= 0 or norm <= 0:
        return float("nan"), 0.0
    return num / den, num / norm


def rest_accel_norm(stamps_ns: np.ndarray, accel: np.ndarray) -> float:
    """Median specific-force magnitude over the quietest quarter of half-second blocks."""
    norms = np.linalg.norm(accel, axis=1)
    if norms.size == 0:
        return float("nan")
    dt = float(np.median(np.diff(stamps_ns))) / 1e9 if norms.size > 1 else 0.01
    b = max(1, int(round(0.5 / max(dt, 1e-6))))
    nb = norms.size // b
    if nb < 2:
        return float(np.median(norms))
    blocks = norms[: nb * b].reshape(nb, b)
    quiet = np.argsort(blocks.std(axis=1))[: max(1, nb // 4)]
    return float(np.median(blocks[quiet].mean(axis=1)))


def rest_gyro_std(stamps_ns: np.ndarray, gyro: np.ndarray, accel_m_s2: np.ndarray) -> float:
    """Median per-axis gyro std over half-second blocks at rest (NaN if never at rest).

    A block is at rest if its specific-force std (norm over axes) is below 0.08 m/s², which
    excludes motion and running-motor vibration.
    """
    if len(stamps_ns) < 4:
        return float("nan")
    dt = float(np.median(np.diff(stamps_ns))) / 1e9
    b = max(2, int(round(0.5 / max(dt, 1e-6))))
    nb = len(stamps_ns) // b
    if nb < 1:
        return float("nan")
    a = accel_m_s2[: nb * b].reshape(nb, b, 3)
    g = gyro[: nb * b].reshape(nb, b, 3)
    rest = np.sqrt(a.var(axis=1).sum(axis=1)) < _REST_ACCEL_STD
    if not rest.any():
        return float("nan")
    return float(np.median(g[rest].std(axis=1)))


def rest_gravity(stamps_ns: np.ndarray, accel_m_s2: np.ndarray) -> float:
    """Mean specific-force magnitude over half-second blocks at rest (NaN if never at rest)."""
    if len(stamps_ns) < 4:
        return float("nan")
    dt = float(np.median(np.diff(stamps_ns))) / 1e9
    b = max(2, int(round(0.5 / max(dt, 1e-6))))
    nb = len(stamps_ns) // b
    if nb < 1:
        return float("nan")
    a = accel_m_s2[: nb * b].reshape(nb, b, 3)
    rest = np.sqrt(a.var(axis=1).sum(axis=1)) < _REST_ACCEL_STD
    if not rest.any():
        return float("nan")
    return float(np.median(np.linalg.norm(a[rest].mean(axis=1), axis=1)))


def detect_units(raw: RawImu, cfg: ImuInput) -> ImuUnits:
    """Detects (or confirms the recipe's) gyro and accel units; never raises."""
    order = np.argsort(raw.header_ns, kind="stable")
    st, g, a = raw.header_ns[order], raw.gyro[order], raw.accel[order]
    fin = np.isfinite(g).all(axis=1) & np.isfinite(a).all(axis=1)
    st, g, a = st[fin], g[fin], a[fin]
    detected = []
    # accelerometer
    rest = rest_accel_norm(st, a)
    guess_a = (
        "m/s^2"
        if 0.75 * STANDARD_GRAVITY <= rest <= 1.25 * STANDARD_GRAVITY
        else "g"
        if 0.75 <= rest <= 1.25
        else None
    )
    a_ev = (
        f"specific force of the quietest blocks |a| = {rest:.3g} (gravity: 9.81 in m/s^2, 1.0 in g)"
    )
    if cfg.accel_unit == "auto":
        detected.append("accel_unit")
        accel_unit, a_ok = guess_a or "m/s^2", guess_a is not None
    else:
        accel_unit, a_ok = cfg.accel_unit, guess_a in (None, cfg.accel_unit)
    # gyroscope
    kscale, corr = kinematic_gyro_scale(st, g, a)
    p99 = float(np.percentile(np.linalg.norm(g, axis=1), 99)) if len(g) else 0.0
    guess_g, g_ev = None, ""
    if np.isfinite(kscale) and corr > _KIN_MIN_CORR and kscale > 0:
        guess_g = "rad/s" if kscale > np.sqrt(DEG) else "deg/s"
        g_ev = (
            f"gravity turns in the IMU frame at {kscale:.3g} x the gyro reading "
            f"(1 for rad/s, {DEG:.4f} for deg/s; fit correlation {corr:.2f})"
        )
    elif p99 > _DEG_MAGNITUDE:
        guess_g = "deg/s"
        g_ev = f"99th-percentile |w| = {p99:.3g}, implausible in rad/s"
    elif np.isfinite(
        rest_std := rest_gyro_std(st, g, a * (STANDARD_GRAVITY if accel_unit == "g" else 1.0))
    ) and (rest_std > _REST_DEG or rest_std < _REST_RAD):
        guess_g = "deg/s" if rest_std > _REST_DEG else "rad/s"
        g_ev = (
            f"gyro noise at rest {rest_std:.2g} (std; MEMS/FOG IMUs: 0.0002-0.003 rad/s = "
            "0.01-0.2 deg/s)"
        )
    else:
        g_ev = (
            f"99th-percentile |w| = {p99:.3g} and too little tilting motion "
            f"(fit correlation {corr:.2f}) to tell rad/s from deg/s"
        )
    if cfg.gyro_unit == "auto":
        detected.append("gyro_unit")
        gyro_unit, g_ok = guess_g or "rad/s", guess_g is not None
    else:
        gyro_unit, g_ok = cfg.gyro_unit, guess_g in (None, cfg.gyro_unit)
    return ImuUnits(
        gyro_unit, accel_unit, g_ok, a_ok, g_ev, a_ev, rest, kscale, corr, tuple(detected)
    )


def to_imu_samples(raw: RawImu, units: ImuUnits, where: str) -> tuple[ImuSamples, dict]:
    """Sorts, de-duplicates and converts raw samples to SI :class:`ImuSamples`.

    Returns:
        The samples and counts of what was repaired: ``reordered``, ``duplicates``,
        ``non_finite``.

    Raises:
        DataError: for an empty topic, unset (zero) header stamps, or fewer than two samples.
    """
    if len(raw) == 0:
        raise DataError(f"{where}: no IMU messages", fix="check data.imu.topic")
    zero = int(np.count_nonzero(raw.header_ns == 0))
    if zero > len(raw) // 2:
        raise DataError(
            f"{where}: {zero} of {len(raw)} IMU header stamps are zero",
            fix="the IMU driver does not stamp its messages; fix the driver",
        )
    fin = np.isfinite(raw.gyro).all(axis=1) & np.isfinite(raw.accel).all(axis=1)
    fin &= raw.header_ns > 0
    order = np.argsort(raw.header_ns, kind="stable")
    order = order[fin[order]]
    st = raw.header_ns[order]
    keep = np.concatenate([[True], np.diff(st) > 0]) if st.size else np.zeros(0, bool)
    idx = order[keep]
    if idx.size < 2:
        raise DataError(
            f"{where}: fewer than two usable IMU samples",
            fix="check data.imu.topic and the IMU driver",
        )
    reordered = int(np.count_nonzero(np.diff(raw.header_ns) < 0))
    samples = ImuSamples(
        raw.header_ns[idx], raw.gyro[idx] * units.gyro_scale, raw.accel[idx] * units.accel_scale
    )
    return samples, {
        "reordered": reordered,
        "duplicates": int(np.count_nonzero(~keep)),
        "non_finite": int(np.count_nonzero(~fin)),
    }
