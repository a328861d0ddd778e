"""PointCloud2 decoding corner cases and time-convention detection / overrides (no bag files)."""

from __future__ import annotations

import numpy as np
import pytest
from io_bagkit import PERIOD_NS, T0, Msgs

from l2calib.errors import DataError, FormatError
from l2calib.io.lidar_conventions import TimeConvention, detect_convention, point_times_ns
from l2calib.io.lidar_scans import to_scan
from l2calib.io.pointcloud import RawCloud, decode_pointcloud2, raw_from_pointcloud2
from l2calib.recipe import LidarInput

M = Msgs(ros2=False)


def cloud_of(dtype, n=50, rng=None, **kw):
    rng = rng or np.random.default_rng(0)
    pts = np.zeros(n, dtype=dtype)
    for name in pts.dtype.names:
        sub = pts.dtype.fields[name][0]
        shape = (n,) + sub.shape
        pts[name] = rng.uniform(1, 100, shape).astype(sub.base)
    return pts, M.cloud(T0, pts, **kw)


@pytest.mark.parametrize("code", ["i1", "u1", "i2", "u2", "i4", "u4", "f4", "f8"])
def test_every_pointfield_datatype_decodes(code):
    dt = np.dtype(
        {
            "names": ["x", "y", "z", "v"],
            "formats": ["f4", "f4", "f4", code],
            "offsets": [0, 4, 8, 12],
            "itemsize": 24,
        }
    )  # padded point_step
    pts, msg = cloud_of(dt)
    out = decode_pointcloud2(msg, "test")
    np.testing.assert_array_equal(out["v"], pts["v"])
    np.testing.assert_array_equal(out["x"], pts["x"])


def test_big_endian_organised_padded_rows_and_count_fields():
    dt = np.dtype(
        {
            "names": ["x", "y", "z", "t", "rgb"],
            "formats": [">f4", ">f4", ">f4", ">u4", (">u2", (3,))],
            "offsets": [0, 4, 8, 12, 16],
            "itemsize": 24,
        }
    )
    pts, msg = cloud_of(dt, n=48, height=4, row_pad=8, bigendian=True)
    raw = raw_from_pointcloud2(msg, T0, "t", "test")
    np.testing.assert_array_equal(raw.xyz[:, 1], pts["y"].astype(np.float32))
    np.testing.assert_array_equal(raw.time_raw, pts["t"].astype(np.int64))
    assert raw.time_dtype == "u4" and len(raw) == 48


def test_truncated_cloud_and_bad_layouts_are_format_errors():
    dt = np.dtype(
        {"names": ["x", "y", "z"], "formats": ["f4"] * 3, "offsets": [0, 4, 8], "itemsize": 16}
    )
    _, msg = cloud_of(dt)
    msg.data = msg.data[:-5]
    with pytest.raises(FormatError, match="need 800"):
        decode_pointcloud2(msg, "bag: /points")
    _, msg = cloud_of(dt)
    msg.fields[2].datatype = 9
    with pytest.raises(FormatError, match="field 'z' has unknown PointField datatype 9"):
        decode_pointcloud2(msg, "bag: /points")
    _, msg = cloud_of(dt)
    msg.fields[2].offset = 14
    with pytest.raises(FormatError, match="ends past point_step 16"):
        decode_pointcloud2(msg, "bag: /points")
    _, msg = cloud_of(dt)
    with pytest.raises(FormatError, match="no field 'time'.*fields: x, y, z"):
        raw_from_pointcloud2(msg, T0, "time", "bag: /points")


def raw(header_ns, t, xyz=None, field="t", dtype="u4"):
    n = len(t)
    xyz = np.ones((n, 3), np.float32) if xyz is None else xyz
    kind = np.int64 if dtype[0] in "iu" else np.float64
    return RawCloud(
        header_ns, xyz, np.asarray(t).astype(kind), field, dtype, None, None, ("x", "y", "z", field)
    )


def scans_with(values_fn, dtype="f8", n_scans=5, field="time"):
    out = []
    for k in range(n_scans):
        h = T0 + k * PERIOD_NS
        out.append(raw(h, values_fn(h), field=field, dtype=dtype))
    return out


REL = np.linspace(0, 0.099, 40)


@pytest.mark.parametrize(
    ("values", "dtype", "expect"),
    [
        (lambda h: REL * 1e3, "f4", ("ms", "relative", "start")),
        (lambda h: REL * 1e6, "u4", ("us", "relative", "start")),
        (lambda h: REL - 0.099, "f4", ("s", "relative", "end")),
        (lambda h: h / 1e9 + REL - 0.099, "f8", ("s", "absolute", "end")),
        (lambda h: h / 1e6 + REL * 1e3, "f8", ("ms", "absolute", "start")),
    ],
)
def test_detects_unit_reference_and_stamp_position(values, dtype, expect):
    conv = detect_convention(scans_with(values, dtype), LidarInput(), "bag: /points")
    assert (conv.unit, conv.reference, conv.stamp_position) == expect
    assert not conv.foreign_clock


def test_absolute_times_on_another_clock_are_placed_by_the_header():
    scans = scans_with(lambda h: (h - T0) / 1e9 + 1234.5 + REL)  # device clock since boot
    conv = detect_convention(scans, LidarInput(time_reference="absolute"), "bag: /points")
    assert conv.foreign_clock and "another clock" in conv.evidence
    t = point_times_ns(scans[2], conv)
    assert t.min() == scans[2].header_ns
    assert abs((t.max() - t.min()) / 1e9 - 0.099) < 1e-6


def test_stamp_position_override_against_the_sign_shifts_to_the_header():
    c = raw(T0, REL * 1e9)
    end = TimeConvention("t", "ns", "relative", "end")
    start = TimeConvention("t", "ns", "relative", "start")
    assert point_times_ns(c, end).max() == T0  # offsets from scan start, header at end
    assert point_times_ns(c, start).min() == T0
    cneg = raw(T0, (REL - 0.099) * 1e9, dtype="i4")
    assert point_times_ns(cneg, start).min() == T0
    assert point_times_ns(cneg, end).max() == T0


def test_unit_that_fits_no_period_and_constant_times_are_errors():
    with pytest.raises(DataError, match="fits no unit.*fix: set data.lidar.time_unit"):
        detect_convention(scans_with(lambda h: REL * 3e4), LidarInput(), "bag: /points")
    with pytest.raises(DataError, match="same value for every point"):
        detect_convention(scans_with(lambda h: np.zeros(40)), LidarInput(), "bag: /points")


def test_overrides_win_over_detection():
    cfg = LidarInput(time_unit="us", time_reference="relative", stamp_position="end")
    conv = detect_convention(scans_with(lambda h: REL * 1e6, "u4"), cfg, "bag: /points")
    assert (conv.unit, conv.reference, conv.stamp_position, conv.detected) == (
        "us",
        "relative",
        "end",
        (),
    )


def test_nan_zero_and_out_of_range_points_are_dropped_with_their_times():
    xyz = np.array(
        [[1, 0, 0], [np.nan, 1, 1], [0, 0, 0], [200, 0, 0], [0.1, 0, 0], [3, 4, 0]], np.float32
    )
    t = np.array([10, 0, 20, 30, 40, 50]) * 1_000_000
    scan, stats = to_scan(
        raw(T0, t, xyz), TimeConvention("t", "ns", "relative", "start"), 0.5, 120.0
    )
    np.testing.assert_array_equal(scan.points_lidar, xyz[[0, 5]])
    assert scan.stamp_ns == T0 + 10_000_000
    np.testing.assert_allclose(scan.offset_s, [0.0, 0.04])
    assert (stats.n_nan, stats.n_zero, stats.n_range, stats.n_kept) == (1, 1, 2, 2)
    empty, stats = to_scan(raw(T0, t[:3], xyz[1:4]), TimeConvention("t"), 0.5, 120.0)
    assert empty is None and stats.n_kept == 0
