"""LiDAR sensor models: firing pattern (directions and times) and return model.

* Spinning LiDARs (Ouster OS1-16/64, Velodyne VLP-16/VLP-32C, Hesai Pandar XT32): ``columns``
  azimuth steps per revolution, all channels of a column fired at the column's time; rotation is
  clockwise seen from above, as on the real sensors. ``columns`` can be reduced for fast tests.
* Livox MID-360: a non-repetitive pattern (4 lines, 200 kpts/s, 360° × [-7°, 52°]) where every
  point has its own time; modelled as a fast azimuth sweep with an incommensurate triangular
  elevation oscillation, so coverage keeps growing over successive scans like the real sensor's.

Returns: range noise, random dropouts, grazing-angle dropouts, a few percent of spurious returns
(dust, mixed pixels, multipath: a range anywhere short of the surface), min/max range, intensity
from the surface reflectivity and incidence angle.

Real sensors are less kind than a column of rays fired at once, and the simulator models what
LiDAR-only odometry meets on them:

* Velodyne and Hesai fire the lasers of a column one after another (``channel_stagger_s`` apart,
  in ``firing_order``), so each point has its own time; their drivers stamp points so.
* Ouster beams of one column fire together but look along slightly different azimuths
  (``beam_azimuth_deg``, as in the sensor's ``beam_intrinsics``); the driver's points carry the
  column's time.

Values are from the vendors' manuals where we know them (VLP-16: 2.304 µs per laser, lasers fired
alternately low and high; Pandar XT32: ~1.5 µs per channel); the Ouster offsets follow the
±4.2° / ±1.4° pattern of an OS1's ``beam_azimuth_angles``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from l2calib.errors import ConfigError

# VLP-32C elevation table (degrees), from the sensor's manual.
_VLP32C = (
    -25.0,
    -15.639,
    -11.31,
    -8.843,
    -7.254,
    -6.148,
    -5.333,
    -4.667,
    -4.0,
    -3.667,
    -3.333,
    -3.0,
    -2.667,
    -2.333,
    -2.0,
    -1.667,
    -1.333,
    -1.0,
    -0.667,
    -0.333,
    0.0,
    0.333,
    0.667,
    1.0,
    1.333,
    1.667,
    2.333,
    3.333,
    4.667,
    7.0,
    10.333,
    15.0,
)


@dataclass(frozen=True)
class LidarSpec:
    """One LiDAR model.

    Attributes:
        name: Model name (``ouster-os1-16`` ...).
        vendor: ``ouster``, ``velodyne``, ``hesai`` or ``livox`` (selects the message layout).
        kind: ``spinning`` or ``livox``.
        elevations_deg: Channel elevations in ring order (spinning only).
        columns: Azimuth steps per revolution (spinning only).
        rate_hz: Scans per second.
        points_per_s: Point rate (livox only).
        fov_deg: ``(min, max)`` elevation (livox only).
        lines: Number of laser lines (livox only).
        min_range_m: Closer returns are dropped.
        max_range_m: Farther returns are dropped.
        range_noise_m: Standard deviation of the range noise (m).
        dropout_prob: Probability that a valid return is lost at random.
        azimuth0_rad: Azimuth of column 0 (rad); columns sweep clockwise from it.
        channel_stagger_s: Time between two successive laser firings within a column (s).
        firing_order: Rings in the order they fire within a column (default: ring order).
        beam_azimuth_deg: Azimuth offset of each ring's beam (deg; default: none).
        spurious_prob: Probability that a return is spurious (a range short of the surface).
    """

    name: str
    vendor: str
    kind: str
    elevations_deg: tuple[float, ...] = ()
    columns: int = 0
    rate_hz: float = 10.0
    points_per_s: int = 0
    fov_deg: tuple[float, float] = (0.0, 0.0)
    lines: int = 0
    min_range_m: float = 0.5
    max_range_m: float = 100.0
    range_noise_m: float = 0.02
    dropout_prob: float = 0.005
    azimuth0_rad: float = 0.0
    channel_stagger_s: float = 0.0
    firing_order: tuple[int, ...] = ()
    beam_azimuth_deg: tuple[float, ...] = ()
    spurious_prob: float = 0.02

    @property
    def channels(self) -> int:
        """Number of rings (spinning) or lines (livox)."""
        return len(self.elevations_deg) if self.kind == "spinning" else self.lines

    @property
    def period_s(self) -> float:
        """Scan period (s)."""
        return 1.0 / self.rate_hz

    def ring_delays_s(self) -> np.ndarray:
        """``[channels]`` firing delay of each ring after its column's time (s)."""
        order = np.asarray(self.firing_order or range(self.channels), dtype=np.int64)
        slot = np.empty(self.channels, dtype=np.int64)
        slot[order] = np.arange(self.channels)
        return slot * self.channel_stagger_s

    def ring_azimuths_rad(self) -> np.ndarray:
        """``[channels]`` azimuth offset of each ring's beam (rad)."""
        if not self.beam_azimuth_deg:
            return np.zeros(self.channels)
        return np.radians(np.resize(np.asarray(self.beam_azimuth_deg), self.channels))


def _alternating(n: int) -> tuple[int, ...]:
    """Rings (sorted by elevation) fired alternately from the low and the middle of the fan.

    A VLP-16 fires its lasers as -15°, 1°, -13°, 3°, …: ring ``r`` of the elevation-sorted fan
    fires in slot ``2r`` for the lower half and ``2(r - n/2) + 1`` for the upper half.
    """
    half = n // 2
    return tuple(r for pair in zip(range(half), range(half, n), strict=True) for r in pair)


#: OS1 beam azimuth offsets (deg), repeated over the rings (``beam_intrinsics``-like).
_OUSTER_AZ = (4.2, 1.4, -1.4, -4.2)


LIDARS: dict[str, LidarSpec] = {
    "ouster-os1-16": LidarSpec(
        "ouster-os1-16",
        "ouster",
        "spinning",
        tuple(np.linspace(16.6, -16.6, 16)),
        1024,
        min_range_m=0.8,
        max_range_m=120.0,
        range_noise_m=0.015,
        azimuth0_rad=np.pi,
        beam_azimuth_deg=_OUSTER_AZ,
    ),
    "ouster-os1-64": LidarSpec(
        "ouster-os1-64",
        "ouster",
        "spinning",
        tuple(np.linspace(22.5, -22.5, 64)),
        1024,
        min_range_m=0.5,
        max_range_m=120.0,
        range_noise_m=0.015,
        azimuth0_rad=np.pi,
        beam_azimuth_deg=_OUSTER_AZ,
    ),
    "velodyne-vlp-16": LidarSpec(
        "velodyne-vlp-16",
        "velodyne",
        "spinning",
        tuple(np.linspace(-15.0, 15.0, 16)),
        1800,
        min_range_m=0.4,
        max_range_m=100.0,
        range_noise_m=0.03,
        channel_stagger_s=2.304e-6,
        firing_order=_alternating(16),
    ),
    "velodyne-vlp-32c": LidarSpec(
        "velodyne-vlp-32c",
        "velodyne",
        "spinning",
        _VLP32C,
        1800,
        min_range_m=0.4,
        max_range_m=200.0,
        range_noise_m=0.03,
        channel_stagger_s=1.152e-6,  # 16 firings of 2.304 µs, two lasers each: ~half per laser
        firing_order=_alternating(32),
    ),
    "hesai-pandar-xt32": LidarSpec(
        "hesai-pandar-xt32",
        "hesai",
        "spinning",
        tuple(np.linspace(15.0, -16.0, 32)),
        2000,
        min_range_m=0.05,
        max_range_m=120.0,
        range_noise_m=0.01,
        channel_stagger_s=1.512e-6,
    ),
    "livox-mid360": LidarSpec(
        "livox-mid360",
        "livox",
        "livox",
        points_per_s=200_000,
        fov_deg=(-7.0, 52.0),
        lines=4,
        min_range_m=0.1,
        max_range_m=70.0,
        range_noise_m=0.02,
    ),
}
LIDAR_NAMES = tuple(LIDARS)


def get_lidar(name: str) -> LidarSpec:
    """The named model; :class:`ConfigError` listing the known names otherwise."""
    if name not in LIDARS:
        raise ConfigError(
            f"unknown LiDAR model {name!r}", fix=f"choose one of: {', '.join(LIDAR_NAMES)}"
        )
    return LIDARS[name]


@dataclass(frozen=True)
class FiringPattern:
    """Rays of one scan in the LiDAR frame.

    Attributes:
        directions: ``[P, 3]`` unit ray directions.
        time_s: ``[P]`` firing time after the scan's nominal start (s).
        ring: ``[P]`` uint16 ring (spinning) or line (livox).
        column: ``[P]`` uint32 column (spinning) or point index within the scan (livox).
        time_index: ``[P]`` index of each ray's firing time in ``unique_times``.
        unique_times: ``[n_times]`` distinct firing times (s).
    """

    directions: np.ndarray
    time_s: np.ndarray
    ring: np.ndarray
    column: np.ndarray
    time_index: np.ndarray
    unique_times: np.ndarray


def column_times_ns(spec: LidarSpec) -> np.ndarray:
    """``[columns]`` int64 firing time of each column after the sweep start (ns)."""
    return np.round(np.arange(spec.columns) * (1e9 / spec.rate_hz) / spec.columns).astype(np.int64)


def spinning_pattern(spec: LidarSpec) -> FiringPattern:
    """Column-major rays of a spinning LiDAR.

    The lasers of a column fire ``spec.ring_delays_s()`` after the column's time (all at once
    when the stagger is 0) and look along the column's azimuth plus ``spec.ring_azimuths_rad()``.
    """
    n_col, n_ring = spec.columns, spec.channels
    az = spec.azimuth0_rad - 2 * np.pi * np.arange(n_col) / n_col  # clockwise
    el = np.radians(np.asarray(spec.elevations_deg))
    az_g, el_g = np.meshgrid(az, el, indexing="ij")  # [col, ring]
    az_g = az_g + spec.ring_azimuths_rad()[None, :]
    dirs = np.stack(
        [np.cos(el_g) * np.cos(az_g), np.cos(el_g) * np.sin(az_g), np.sin(el_g)], -1
    ).reshape(-1, 3)
    col_t = column_times_ns(spec) / 1e9
    cols = np.repeat(np.arange(n_col, dtype=np.uint32), n_ring)
    ring = np.tile(np.arange(n_ring, dtype=np.uint16), n_col)
    time_s = col_t[cols] + spec.ring_delays_s()[ring]
    unique_times, time_index = np.unique(time_s, return_inverse=True)
    return FiringPattern(
        directions=dirs,
        time_s=time_s,
        ring=ring,
        column=cols,
        time_index=time_index.astype(np.int64),
        unique_times=unique_times,
    )


def livox_pattern(spec: LidarSpec, scan_index: int) -> FiringPattern:
    """Rays of scan ``scan_index`` of a Livox MID-360-like non-repetitive pattern.

    The pattern depends on the absolute point index, so successive scans differ.
    """
    n = int(round(spec.points_per_s * spec.period_s))
    k = scan_index * n + np.arange(n, dtype=np.int64)
    t_abs = k / spec.points_per_s
    line = (k % spec.lines).astype(np.uint16)
    # One azimuth revolution per scan; lines spread 90° apart.
    az = -2 * np.pi * (spec.rate_hz * t_abs) + line * (2 * np.pi / spec.lines)
    # Triangular elevation sweep at an irrational frequency ratio: uniform density in elevation,
    # never repeating across scans.
    f_el = spec.rate_hz * 127.0 * (1 + np.sqrt(5)) / 2
    phase = np.mod(f_el * t_abs + line / spec.lines, 1.0)
    tri = 1 - 2 * np.abs(2 * phase - 1)  # in [-1, 1]
    lo, hi = np.radians(spec.fov_deg)
    el = (lo + hi) / 2 + (hi - lo) / 2 * tri
    dirs = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1)
    t_rel = np.arange(n) / spec.points_per_s
    return FiringPattern(
        directions=dirs,
        time_s=t_rel,
        ring=line,
        column=np.arange(n, dtype=np.uint32),
        time_index=np.arange(n, dtype=np.int64),
        unique_times=t_rel,
    )


def returns(
    spec: LidarSpec,
    true_range: np.ndarray,
    cos_incidence: np.ndarray,
    reflectivity: np.ndarray,
    rng: np.random.Generator,
    noise: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Applies the return model to ray-cast hits.

    Args:
        spec: The LiDAR model.
        true_range: ``[P]`` exact range to the surface (inf for no hit).
        cos_incidence: ``[P]`` |cos| of the angle between ray and surface normal.
        reflectivity: ``[P]`` surface reflectivity in ``[0, 1]``.
        rng: Random generator.
        noise: Add range noise and random dropouts (geometric limits always apply).

    Returns:
        ``valid [P] bool``, measured range ``[P]`` and intensity ``[P]`` (0-255 scale).
    """
    valid = np.isfinite(true_range)
    valid &= (true_range >= spec.min_range_m) & (true_range <= spec.max_range_m)
    valid &= cos_incidence > 0.03  # grazing rays return nothing
    meas = true_range.copy()
    if noise:
        valid &= rng.random(true_range.shape) >= spec.dropout_prob
        meas = meas + rng.normal(0.0, spec.range_noise_m, size=meas.shape)
        if spec.spurious_prob > 0:  # dust, mixed pixels, multipath: short of the surface
            spurious = valid & (rng.random(meas.shape) < spec.spurious_prob)
            meas[spurious] = rng.uniform(spec.min_range_m, meas[spurious])
        valid &= meas > spec.min_range_m
    cos = np.clip(cos_incidence, 0.0, 1.0)
    intensity = 255.0 * reflectivity * (0.35 + 0.65 * cos)
    if noise:
        intensity = intensity * rng.uniform(0.9, 1.1, size=intensity.shape)
    return valid, meas, np.clip(intensity, 0.0, 255.0).astype(np.float32)
