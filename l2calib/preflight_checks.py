"""The rules of ``l2calib inspect``: findings per topic and per LiDAR–IMU pair.

Thresholds (why):

* IMU rate below 100 Hz: LiDAR-inertial odometry propagates between scans with the IMU; fewer
  than ~10 samples per 10 Hz scan degrade deskewing.
* Gravity (measured in still half-second blocks only) off the recipe's value by more than
  0.3 m/s² (3 %): accelerometer scale/unit problem.
* Record time more than 0.5 s after the header stamp (median), or any header stamp in the future
  of its record time by more than 50 ms: the sensor is probably stamped on another clock.
* LiDAR and IMU clocks: a LiDAR message is recorded when its scan ends, so its record-minus-header
  median normally exceeds the IMU's by up to one scan period (0.1 s at 10 Hz) when the header
  stamps the scan start. Only when the difference leaves ``[-0.1 s, scan period + 0.1 s]`` are
  the stamps likely from different clocks (the calibration's time offset cannot absorb that).
* Overlap below 80 % of the shorter stream: much of the data cannot be used.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from l2calib.data import NS_PER_S
from l2calib.recipe import ImuInput

if TYPE_CHECKING:
    from l2calib.io.stamps import StampStats
    from l2calib.preflight_reports import ImuTopicReport, LidarTopicReport

MIN_IMU_RATE_HZ = 100.0
GRAVITY_TOL_M_S2 = 0.3
RECORD_LAG_S, FUTURE_S, CLOCK_MISMATCH_S = 0.5, 0.05, 0.1
MIN_OVERLAP_SHARE = 0.8


@dataclass(frozen=True)
class Issue:
    """One finding: ``severity`` is ``error`` (calibration will fail), ``warning`` or ``info``."""

    severity: str
    where: str
    message: str
    fix: str | None = None

    def __str__(self) -> str:
        text = f"{self.severity}: {self.where}: {self.message}"
        return f"{text} — fix: {self.fix}" if self.fix else text


def _timing(topic: str, st: StampStats, kind: str) -> list[Issue]:
    out = []
    if st.zero_stamps:
        out.append(
            Issue(
                "error",
                topic,
                f"{st.zero_stamps} message(s) have a zero header stamp",
                "the driver does not stamp its messages; fix the driver",
            )
        )
    if st.gaps_ns:
        a, b = max(st.gaps_ns, key=lambda g: g[1] - g[0])
        out.append(
            Issue(
                "warning",
                topic,
                f"{len(st.gaps_ns)} gap(s) longer than {st.gap_threshold_s:.3f} s; longest "
                f"{(b - a) / NS_PER_S:.3f} s at {(a - st.first_ns) / NS_PER_S:.2f} s into the "
                "topic",
                f"data selection skips windows with {kind} gaps; check the driver/recorder for "
                "dropped messages",
            )
        )
    if st.non_monotonic:
        out.append(
            Issue(
                "warning",
                topic,
                f"{st.non_monotonic} message(s) arrive with a stamp earlier than the previous one",
                "they are reordered by stamp; check the driver's time source",
            )
        )
    if st.duplicates:
        out.append(
            Issue(
                "warning",
                topic,
                f"{st.duplicates} duplicate header stamp(s)",
                "duplicates are dropped; check the driver",
            )
        )
    if st.record_minus_header_s is not None:
        med, _ = st.record_minus_header_s
        if med > RECORD_LAG_S or med < -FUTURE_S:
            out.append(
                Issue(
                    "warning",
                    topic,
                    f"record time minus header stamp is {med:+.3f} s (median)",
                    "the header stamps may come from another clock than "
                    "the recorder's (PTP/GPS vs system time); check the driver",
                )
            )
    return out


def check_lidar(rep: LidarTopicReport) -> list[Issue]:
    """Findings for one LiDAR topic."""
    out = _timing(rep.topic, rep.stamps, "LiDAR")
    conv = rep.convention
    if conv is not None:
        if rep.empty_scans and rep.empty_scans >= rep.stamps.count:
            out.append(
                Issue(
                    "error",
                    rep.topic,
                    "every scan is empty after dropping NaN/zero points and the range limits",
                    "check the LiDAR topic and data.lidar.min_range_m/max_range_m",
                )
            )
        elif rep.empty_scans:
            out.append(
                Issue(
                    "warning",
                    rep.topic,
                    f"{rep.empty_scans} empty scan(s) (no valid point)",
                    "they are skipped; check the LiDAR (blocked, or range limits too tight)",
                )
            )
        if rep.nan_share + rep.zero_share > 0.5:
            out.append(
                Issue(
                    "warning",
                    rep.topic,
                    f"{100 * (rep.nan_share + rep.zero_share):.0f} % of points are NaN "
                    "or zero (dropped)",
                    "the LiDAR sees little; check for blockage",
                )
            )
        if conv.foreign_clock:
            out.append(
                Issue(
                    "warning",
                    rep.topic,
                    "per-point times are on another clock than "
                    f"the header stamps ({conv.evidence.split('; ')[-1]})",
                    "point spacing is kept and scans are placed by their header "
                    "stamps; set data.lidar.stamp_position if the header marks the "
                    "scan end",
                )
            )
        if (
            conv.reference == "relative"
            and conv.stamp_position == "start"
            and "stamp_position" in conv.detected
        ):
            out.append(
                Issue(
                    "info",
                    rep.topic,
                    "relative point times >= 0: the header stamp is taken as the scan start",
                    "if the driver stamps the scan end "
                    "but counts times from its start, set data.lidar.stamp_position: "
                    "end",
                )
            )
        if conv.field is None:
            out.append(
                Issue(
                    "warning",
                    rep.topic,
                    "no per-point times: scans are not deskewed",
                    "record per-point times for fast motion",
                )
            )
    return out


def check_imu(rep: ImuTopicReport, cfg: ImuInput) -> list[Issue]:
    """Findings for one IMU topic."""
    out = _timing(rep.topic, rep.stamps, "IMU")
    if rep.stamps.count < 2:
        out.append(Issue("error", rep.topic, "fewer than two IMU messages", "record the IMU"))
        return out
    if 0 < rep.stamps.rate_hz < MIN_IMU_RATE_HZ:
        out.append(
            Issue(
                "warning",
                rep.topic,
                f"IMU rate {rep.stamps.rate_hz:.0f} Hz is low",
                f"use >= {MIN_IMU_RATE_HZ:.0f} Hz for LiDAR-inertial odometry",
            )
        )
    u = rep.units
    if u is None:
        return out
    if not u.accel_confirmed:
        sev = "error" if "accel_unit" in u.detected else "warning"
        out.append(
            Issue(
                sev,
                rep.topic,
                f"accelerometer unit unclear: {u.accel_evidence}",
                "set data.imu.accel_unit (m/s^2 or g); check the IMU driver",
            )
        )
    elif u.accel_unit == "g":
        out.append(
            Issue(
                "warning",
                rep.topic,
                f"accelerometer reads in g ({u.accel_evidence})",
                "l2calib converts it: keep data.imu.accel_unit: g (or auto)",
            )
        )
    if not u.gyro_confirmed:
        out.append(
            Issue(
                "warning",
                rep.topic,
                f"gyro unit not confirmed, assuming {u.gyro_unit}: {u.gyro_evidence}",
                "record some tilting motion, or set data.imu.gyro_unit (rad/s or deg/s)",
            )
        )
    elif u.gyro_unit == "deg/s":
        out.append(
            Issue(
                "warning",
                rep.topic,
                f"gyro reads in deg/s ({u.gyro_evidence})",
                "l2calib converts it: keep data.imu.gyro_unit: deg/s (or auto)",
            )
        )
    if (
        u.accel_confirmed
        and rep.gravity_at_rest
        and abs(rep.gravity_m_s2 - cfg.gravity_m_s2) > GRAVITY_TOL_M_S2
    ):
        out.append(
            Issue(
                "warning",
                rep.topic,
                f"gravity measures {rep.gravity_m_s2:.2f} m/s^2, "
                f"recipe says {cfg.gravity_m_s2:.2f}",
                "check the accelerometer scale or set data.imu.gravity_m_s2",
            )
        )
    return out


def check_pair(lidar: LidarTopicReport, imu: ImuTopicReport) -> tuple[float | None, list[Issue]]:
    """LiDAR–IMU overlap (s) and clock findings."""
    out: list[Issue] = []
    where = f"{lidar.topic} + {imu.topic}"
    l0, l1 = (
        lidar.scan_stamps
        if lidar.scan_stamps != (0, 0)
        else (lidar.stamps.first_ns, lidar.stamps.last_ns)
    )
    i0, i1 = imu.stamps.first_ns, imu.stamps.last_ns
    if lidar.stamps.count == 0 or imu.stamps.count == 0:
        return None, out
    overlap = (min(l1, i1) - max(l0, i0)) / NS_PER_S
    if overlap <= 0:
        out.append(
            Issue(
                "error",
                where,
                f"LiDAR [{l0 / NS_PER_S:.3f}, {l1 / NS_PER_S:.3f}] s and IMU "
                f"[{i0 / NS_PER_S:.3f}, {i1 / NS_PER_S:.3f}] s time ranges do not overlap",
                "both sensors must be stamped on the same clock; check the drivers' time sources "
                "(PTP/GPS vs system time)",
            )
        )
        return overlap, out
    shorter = min(l1 - l0, i1 - i0) / NS_PER_S
    if shorter > 0 and overlap < MIN_OVERLAP_SHARE * shorter:
        out.append(
            Issue(
                "warning",
                where,
                f"LiDAR and IMU overlap for only {overlap:.1f} s of {shorter:.1f} s",
                "check that both were recorded the whole time",
            )
        )
    a, b = lidar.stamps.record_minus_header_s, imu.stamps.record_minus_header_s
    period = _scan_period_s(lidar)
    if (
        a is not None
        and b is not None
        and not (-CLOCK_MISMATCH_S <= a[0] - b[0] <= period + CLOCK_MISMATCH_S)
    ):
        out.append(
            Issue(
                "warning",
                where,
                f"LiDAR and IMU header stamps lag the recorder by "
                f"{a[0]:+.3f} s and {b[0]:+.3f} s (a scan lasts {period:.3f} s, so up to "
                f"{period + CLOCK_MISMATCH_S:.3f} s more for the LiDAR is normal): "
                "different clocks?",
                "stamp both sensors on one clock (PTP, or the host's)",
            )
        )
    return overlap, out


def _scan_period_s(lidar: LidarTopicReport) -> float:
    """One scan's duration (s): from the message rate, else from the per-point times, else 0."""
    if lidar.stamps.rate_hz > 0:
        return 1.0 / lidar.stamps.rate_hz
    if lidar.scan_duration_s == lidar.scan_duration_s:  # not NaN
        return float(lidar.scan_duration_s)
    return 0.0
