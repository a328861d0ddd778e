"""Pre-flight checks of a bag (``l2calib inspect``): what is in it and what will go wrong.

:func:`inspect_bag` streams the bag once and reports, per LiDAR / IMU / NavSatFix topic, timing
(rate, span, gaps, non-monotonic stamps, header vs record time), the LiDAR's per-point time
convention and invalid-point share, the IMU's units with evidence, gravity and rotation rates,
and the LiDAR–IMU overlap. Problems become :class:`Issue` objects (error / warning / info) that
say what to change; the detected settings are returned as a recipe ``data`` section. Given the
recipe's ``selection`` section, it also warns when the recording is too short or too still to
calibrate (:mod:`l2calib.preflight_motion`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from l2calib.data import NS_PER_S
from l2calib.errors import DataError
from l2calib.io.bag_reader import IMU_TYPE, LIDAR_TYPES, NAVSAT_TYPE, Bag, TopicInfo
from l2calib.io.imu_reader import (
    ImuTopicReader,
    detect_units,
    rest_accel_norm,
    rest_gravity,
)
from l2calib.io.lidar_scans import LidarTopicReader
from l2calib.io.navsat import STATUS_GBAS_FIX, NavSatTopicReader
from l2calib.io.sequences import IMU_GAP_FACTOR, IMU_MIN_GAP_S, LIDAR_GAP_FACTOR, _track
from l2calib.io.stamps import stamp_stats
from l2calib.preflight_checks import Issue, check_imu, check_lidar, check_pair
from l2calib.preflight_motion import MotionReport, motion_check
from l2calib.preflight_reports import ImuTopicReport, LidarTopicReport, NavSatTopicReport
from l2calib.recipe import DataConfig, SelectionConfig
from l2calib.time_offset_estimate import OffsetEstimate


@dataclass
class BagReport:
    """Everything :func:`inspect_bag` found in one bag."""

    path: str
    storage: str
    duration_s: float
    topics: list[TopicInfo]
    lidar: list[LidarTopicReport] = field(default_factory=list)
    imu: list[ImuTopicReport] = field(default_factory=list)
    navsat: list[NavSatTopicReport] = field(default_factory=list)
    overlap_s: float | None = None
    issues: list[Issue] = field(default_factory=list)
    suggested: dict = field(default_factory=dict)
    motion: MotionReport | None = None
    time_offset: OffsetEstimate | None = None

    @property
    def errors(self) -> list[Issue]:
        """Issues of severity ``error``."""
        return [i for i in self.issues if i.severity == "error"]


def _lidar_report(r: LidarTopicReader, info: TopicInfo) -> LidarTopicReport:
    st = stamp_stats(np.array(r.header_ns), np.array(r.record_ns), LIDAR_GAP_FACTOR)
    rep = LidarTopicReport(info.name, info.msgtype, st)
    rep.convention = r.convention
    if r.convention is not None:
        rep.layout = r.convention.layout
    if r.stats:
        total = max(sum(s.n_total for s in r.stats), 1)
        rep.points_per_scan = float(np.median([s.n_total for s in r.stats]))
        rep.nan_share = sum(s.n_nan for s in r.stats) / total
        rep.zero_share = sum(s.n_zero for s in r.stats) / total
        rep.range_share = sum(s.n_range for s in r.stats) / total
        rep.empty_scans = sum(1 for s in r.stats if s.n_kept == 0)
        lo = [s.rel_min_s for s in r.stats if np.isfinite(s.rel_min_s)]
        hi = [s.rel_max_s for s in r.stats if np.isfinite(s.rel_max_s)]
        if lo:
            rep.rel_time_s = (float(min(lo)), float(max(hi)))
        kept = [s for s in r.stats if s.n_kept > 0]
        if kept:
            rep.scan_duration_s = float(
                np.median([(s.end_ns - s.stamp_ns) / NS_PER_S for s in kept])
            )
            rep.scan_stamps = (min(s.stamp_ns for s in kept), max(s.end_ns for s in kept))
    return rep


def _imu_report(r: ImuTopicReader, data: DataConfig) -> ImuTopicReport:
    raw = r.finish()
    st = stamp_stats(raw.header_ns, raw.record_ns, IMU_GAP_FACTOR, IMU_MIN_GAP_S)
    rep = ImuTopicReport(r.topic, st)
    if len(raw) < 2:
        return rep
    units = detect_units(raw, data.imu)
    rep.units = units
    g = raw.gyro * units.gyro_scale
    a = raw.accel * units.accel_scale
    ok = np.isfinite(g).all(axis=1) & np.isfinite(a).all(axis=1)
    if ok.any():
        order = np.argsort(raw.header_ns[ok], kind="stable")
        st_ok, a_ok = raw.header_ns[ok][order], a[ok][order]
        rest = rest_gravity(st_ok, a_ok)
        rep.gravity_at_rest = bool(np.isfinite(rest))
        rep.gravity_m_s2 = rest if rep.gravity_at_rest else rest_accel_norm(st_ok, a_ok)
        rep.mean_abs_gyro_rad_s = tuple(float(x) for x in np.mean(np.abs(g[ok]), axis=0))
        rep.max_gyro_rad_s = float(np.max(np.linalg.norm(g[ok], axis=1)))
    return rep


def _navsat_report(r: NavSatTopicReader) -> NavSatTopicReport:
    fixes = r.finish()
    st = stamp_stats(fixes.stamps_ns, None, 5.0)
    n = max(len(fixes), 1)
    return NavSatTopicReport(
        r.topic,
        st,
        float(fixes.valid.sum()) / n,
        float(np.count_nonzero(fixes.status == STATUS_GBAS_FIX)) / n,
    )


def _pick(reports: list, wanted: str) -> object | None:
    named = [r for r in reports if r.topic == wanted]
    return named[0] if named else (reports[0] if len(reports) == 1 else None)


def inspect_bag(
    path: str | Path,
    data: DataConfig | None = None,
    progress: bool = False,
    selection: SelectionConfig | None = None,
    time_offset: bool = False,
) -> BagReport:
    """Streams one bag and reports its topics, conventions, units and problems.

    Args:
        path: Bag (ROS1 file, ROS2 directory, ``.db3`` or ``.mcap``).
        data: Recipe ``data`` section: its overrides apply, its topics are preferred.
        progress: Show a rich progress bar.
        selection: Recipe ``selection`` section: with it, the motion is checked against the
            selection's window and thresholds (``report.motion``, warnings when too little).
        time_offset: Also estimate the LiDAR-IMU time offset (``report.time_offset``; a second
            pass over the bag and a few seconds of LiDAR odometry, :mod:`l2calib.preflight_offset`).

    Raises:
        DataError: if the path is not a bag.
        FormatError: if the bag is truncated or corrupt.
    """
    data = data or DataConfig()
    path = Path(path)
    with Bag(path) as bag:
        topics = sorted(bag.topics.values(), key=lambda t: t.name)
        lidar_t = bag.topics_of(LIDAR_TYPES)
        imu_t = bag.topics_of({IMU_TYPE})
        nav_t = bag.topics_of({NAVSAT_TYPE})
        readers: dict = {}
        for t in lidar_t:
            readers[t.name] = LidarTopicReader(bag, t.name, data.lidar, strict=False)
        for t in imu_t:
            readers[t.name] = ImuTopicReader(bag, t.name)
        for t in nav_t:
            readers[t.name] = NavSatTopicReader(bag, t.name)
        total = sum(t.count for t in (*lidar_t, *imu_t, *nav_t))
        for m in _track(bag.messages(readers), total, f"inspecting {path.name}", progress):
            readers[m.topic].feed(m)
        duration = (bag.end_ns - bag.start_ns) / NS_PER_S if total else 0.0
        storage = "ros2" if bag.is_ros2 else "ros1"
    report = BagReport(str(path), storage, duration, topics)
    for t in lidar_t:
        r = readers[t.name]
        r.finish()
        report.lidar.append(_lidar_report(r, t))
        for exc in r.errors:
            report.issues.append(Issue("error", f"{t.name}", exc.message, exc.fix))
    report.imu = [_imu_report(readers[t.name], data) for t in imu_t]
    report.navsat = [_navsat_report(readers[t.name]) for t in nav_t]
    _collect_issues(report, data, lidar_t, imu_t)
    if selection is not None:
        _check_motion(report, readers, data, selection)
    if time_offset and not report.errors:
        from l2calib.preflight_offset import offset_check

        report.time_offset, issues, suggested = offset_check(path, data, report.overlap_s)
        report.issues.extend(issues)
        _sort_issues(report)
        for section, values in suggested.items():
            report.suggested.setdefault(section, {}).update(values)
    return report


def _sort_issues(report: BagReport) -> None:
    order = {"error": 0, "warning": 1, "info": 2}
    report.issues.sort(key=lambda i: order[i.severity])


def _check_motion(
    report: BagReport, readers: dict, data: DataConfig, selection: SelectionConfig
) -> None:
    """Adds the motion numbers and too-short / too-still warnings (if the streams are usable)."""
    lidar, imu = _pick(report.lidar, data.lidar.topic), _pick(report.imu, data.imu.topic)
    if lidar is None or imu is None or imu.units is None or report.errors:
        return
    if lidar.convention is None or not (report.overlap_s or 0) > 0:
        return
    report.motion, issues = motion_check(
        report.path, readers[lidar.topic], readers[imu.topic], imu.units, selection
    )
    report.issues[:0] = issues  # warnings first among warnings: they decide whether to go on
    _sort_issues(report)


def _collect_issues(report: BagReport, data: DataConfig, lidar_t: list, imu_t: list) -> None:
    issues = report.issues
    if not lidar_t:
        issues.append(
            Issue(
                "error",
                report.path,
                "no LiDAR topic (sensor_msgs/PointCloud2 or Livox CustomMsg)",
                "record the LiDAR's point cloud topic",
            )
        )
    if not imu_t:
        issues.append(
            Issue("error", report.path, "no sensor_msgs/Imu topic", "record the IMU topic")
        )
    for rep in report.lidar:
        issues.extend(check_lidar(rep))
    for rep in report.imu:
        issues.extend(check_imu(rep, data.imu))
    for rep in report.navsat:
        if rep.fix_share == 0:
            issues.append(
                Issue(
                    "warning",
                    rep.topic,
                    "no valid GNSS fix in this topic",
                    "the rtk reference needs fixes; record with reception",
                )
            )
    for cfg_part, kinds, setting in (
        (data.lidar, lidar_t, "data.lidar.topic"),
        (data.imu, imu_t, "data.imu.topic"),
    ):
        names = [t.name for t in kinds]
        if "topic" in cfg_part.model_fields_set and cfg_part.topic not in names:
            found = {t.name: t.msgtype for t in report.topics}
            what = (
                f"has type {found[cfg_part.topic]}"
                if cfg_part.topic in found
                else "is not in the bag"
            )
            hint = f"set {setting} to one of: {', '.join(names)}" if names else "record it"
            issues.append(Issue("error", report.path, f"{setting} {cfg_part.topic!r} {what}", hint))
    for kind, reps, setting in (
        ("LiDAR", report.lidar, "data.lidar.topic"),
        ("IMU", report.imu, "data.imu.topic"),
    ):
        wanted = data.lidar.topic if kind == "LiDAR" else data.imu.topic
        if len(reps) > 1 and not any(r.topic == wanted for r in reps):
            names = ", ".join(r.topic for r in reps)
            issues.append(
                Issue(
                    "info",
                    report.path,
                    f"several {kind} topics: {names}",
                    f"choose one with {setting}",
                )
            )
    lidar, imu = _pick(report.lidar, data.lidar.topic), _pick(report.imu, data.imu.topic)
    if lidar is not None and imu is not None:
        report.overlap_s, pair_issues = check_pair(lidar, imu)
        issues.extend(pair_issues)
    report.suggested = _suggest(lidar, imu, report.navsat)
    order = {"error": 0, "warning": 1, "info": 2}
    issues.sort(key=lambda i: order[i.severity])


def _suggest(lidar, imu, navsat) -> dict:
    out: dict = {}
    if lidar is not None:
        out["lidar"] = {"topic": lidar.topic}
        if lidar.convention is not None:
            out["lidar"].update(lidar.convention.recipe_settings())
    if imu is not None:
        out["imu"] = {"topic": imu.topic}
        if imu.units is not None:
            out["imu"].update(gyro_unit=imu.units.gyro_unit, accel_unit=imu.units.accel_unit)
    if len(navsat) == 1 and navsat[0].fix_share > 0:
        out["rtk_topic"] = navsat[0].topic
    return {"data": out} if out else {}


def raise_on_errors(report: BagReport) -> None:
    """Raises :class:`DataError` summarising the report's errors (if any)."""
    errs = report.errors
    if errs:
        raise DataError(
            f"{report.path}: {len(errs)} problem(s): "
            + "; ".join(f"{e.where}: {e.message}" for e in errs),
            fix=errs[0].fix,
        )
