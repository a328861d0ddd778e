"""rtk reference: exact geodesy, lever arm, covariance gating, bags, and bad input."""

from __future__ import annotations

import logging
import os

import numpy as np
import pytest
from ref_helpers import ORIGIN, synth_fixes

from l2calib.alignment import ape
from l2calib.errors import ConfigError, ReferenceSourceError
from l2calib.io.navsat import NavSatFixes
from l2calib.plugins import get_plugin
from l2calib.recipe import DataConfig, recipe_from_dict
from l2calib.references.geodesy import LocalEnu

KISS = {"max_range_m": 60.0}
LEVER = (0.4, -0.25, 0.6)


def build(cache_dir, fixes=None, data=None, sequences=None, **options):
    opts = {"cache_dir": str(cache_dir), "kiss_icp": KISS}
    return get_plugin("l2calib.references", "rtk").build(
        {**opts, **options}, data=data, fixes=fixes, sequences=sequences
    )


def ecef(lat_deg, lon_deg, h):
    """WGS-84 geodetic -> ECEF, written out independently of pymap3d."""
    a, f = 6378137.0, 1 / 298.257223563
    e2 = f * (2 - f)
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    n = a / np.sqrt(1 - e2 * np.sin(lat) ** 2)
    return np.stack(
        [
            (n + h) * np.cos(lat) * np.cos(lon),
            (n + h) * np.cos(lat) * np.sin(lon),
            (n * (1 - e2) + h) * np.sin(lat),
        ],
        axis=-1,
    )


def test_enu_matches_an_independent_ecef_computation(rng):
    o = LocalEnu(-33.9, 151.2, 40.0)
    lat = o.lat0_deg + rng.uniform(-0.1, 0.1, 200)  # up to ~11 km away
    lon = o.lon0_deg + rng.uniform(-0.1, 0.1, 200)
    h = o.h0_m + rng.uniform(-50, 500, 200)
    la, lo = np.radians(o.lat0_deg), np.radians(o.lon0_deg)
    R = np.array(
        [
            [-np.sin(lo), np.cos(lo), 0.0],
            [-np.sin(la) * np.cos(lo), -np.sin(la) * np.sin(lo), np.cos(la)],
            [np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)],
        ]
    )
    expected = (ecef(lat, lon, h) - ecef(o.lat0_deg, o.lon0_deg, o.h0_m)) @ R.T
    enu = o.to_enu(lat, lon, h)
    assert np.abs(enu - expected).max() < 1e-6  # exact, not flat-earth (which errs by metres)
    back = o.to_geodetic(enu)
    assert np.abs(back[0] - lat).max() < 1e-10 and np.abs(back[2] - h).max() < 1e-5
    # one arc-second of latitude at 45 deg is 30.87 m on the ellipsoid
    n = LocalEnu(45.0, 0.0, 0.0).to_enu(np.array([45.0 + 1 / 3600]), np.zeros(1), np.zeros(1))
    assert abs(n[0, 1] - 30.87) < 0.01


@pytest.mark.parametrize("orientation", ["kiss-icp", "ct-lidar"])
def test_lever_arm_is_removed_with_the_lidar_attitude(drive, cache_dir, caplog, orientation):
    fixes = {drive.sequence.name: synth_fixes(drive.run, LEVER, sigma_m=0.005)}
    with caplog.at_level(logging.WARNING, logger="l2calib.references"):
        src = build(
            cache_dir, fixes, sequences=[drive.sequence], lever_arm_m=LEVER,
            orientation=orientation,
        )  # fmt: skip
        ref = src.compute([drive.segment])[0]
    assert "position-only" in caplog.text
    tr = ref.trajectory
    assert ref.constrains == "position" and ref.source == "rtk" and tr.world_frame == "enu"
    scans = drive.segment.scans
    assert tr.stamps_ns[0] <= scans[0].stamp_ns and tr.stamps_ns[-1] >= scans[-1].end_stamp_ns
    err = ape(drive.run.gt_lidar, tr).rmse_t
    raw = get_plugin("l2calib.references", "rtk").build(
        {"orientation": "none", "cache": False}, fixes=fixes
    )
    err_raw = ape(drive.run.gt_lidar, raw.compute([drive.segment])[0].trajectory).rmse_t
    assert err < 0.015 and err < err_raw / 3, (err, err_raw)  # 5 mm noise, 0.76 m lever arm


def test_positions_are_the_fixes_in_the_given_origin(drive, tmp_path):
    fixes = {drive.sequence.name: synth_fixes(drive.run, sigma_m=0.0)}
    origin = (ORIGIN.lat0_deg, ORIGIN.lon0_deg, ORIGIN.h0_m)
    src = build(tmp_path, fixes, orientation="none", origin=origin)
    tr = src.compute([drive.segment])[0].trajectory
    gt = drive.run.gt_lidar.interpolate(tr.stamps_ns)
    assert np.abs(gt.t_world_body - tr.t_world_body).max() < 1e-5  # world = ENU at ORIGIN


def test_fixes_are_gated_by_covariance_and_status(drive, tmp_path, caplog):
    nav = synth_fixes(drive.run, sigma_m=0.01)
    cov = nav.position_covariance_m2.copy()
    cov[::3] *= 100.0  # every third fix reports 10 cm
    status = nav.status.copy()
    status[1::3] = 0  # plain fix (no RTK)
    fields = {k: getattr(nav, k) for k in nav.__dataclass_fields__}
    noisy = NavSatFixes(**{**fields, "position_covariance_m2": cov, "status": status})
    src = build(tmp_path, {drive.sequence.name: noisy}, orientation="none", max_sigma_m=0.05)
    n_all = len(src.compute([drive.segment])[0].trajectory)
    strict = build(
        tmp_path, {drive.sequence.name: noisy}, orientation="none", max_sigma_m=0.05, min_status=2
    )
    n_rtk = len(strict.compute([drive.segment])[0].trajectory)
    n_none = len(
        build(tmp_path, {drive.sequence.name: nav}, orientation="none")
        .compute([drive.segment])[0]
        .trajectory
    )
    assert abs(n_all - n_none * 2 / 3) <= 2 and abs(n_rtk - n_none / 3) <= 2, (n_none, n_all, n_rtk)
    unknown = NavSatFixes(**{**fields, "covariance_type": np.zeros(len(nav), np.uint8)})
    with caplog.at_level(logging.WARNING, logger="l2calib.references"):
        build(tmp_path, {drive.sequence.name: unknown}, orientation="none").compute([drive.segment])
    assert "report no covariance" in caplog.text


def test_no_fix_in_the_segment(drive, tmp_path):
    nav = synth_fixes(drive.run, status=-1)
    with pytest.raises(ReferenceSourceError, match=r"0 usable fix\(es\).*without fix") as err:
        build(tmp_path, {drive.sequence.name: nav}, orientation="none").compute([drive.segment])
    assert "RTK reception" in err.value.fix
    late = synth_fixes(drive.run, clock_offset_s=-100.0)  # on another clock
    with pytest.raises(ReferenceSourceError, match="0 usable fix"):
        build(tmp_path, {drive.sequence.name: late}, orientation="none").compute([drive.segment])
    fixed = build(tmp_path, {drive.sequence.name: late}, orientation="none", time_offset_s=-100)
    assert len(fixed.compute([drive.segment])[0].trajectory) > 20


def test_missing_topic_and_missing_bag(drive, tmp_path):
    with pytest.raises(ReferenceSourceError, match="none is set") as err:
        build(tmp_path, orientation="none").compute([drive.segment])
    assert "data.rtk_topic" in err.value.fix
    with pytest.raises(ReferenceSourceError, match="does not come from a bag") as err:
        build(tmp_path, data=DataConfig(rtk_topic="/fix"), orientation="none").compute(
            [drive.segment]
        )
    assert "bag_path" in err.value.fix


def test_lever_arm_needs_an_attitude_in_the_recipe():
    data = {"reference": {"name": "rtk", "options": {"orientation": "none", "lever_arm_m": LEVER}}}
    with pytest.raises(ConfigError, match="reference.options.*needs the LiDAR attitude"):
        recipe_from_dict(data, "recipe.yaml")


def write_navsat_bag(path, nav: NavSatFixes, topic="/gnss/fix"):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    T = ts.types
    with Writer(path) as w:
        conn = w.add_connection(topic, "sensor_msgs/msg/NavSatFix", typestore=ts)
        for i, s in enumerate(nav.stamps_ns):
            sec, ns = divmod(int(s), 1_000_000_000)
            msg = T["sensor_msgs/msg/NavSatFix"](
                header=T["std_msgs/msg/Header"](
                    seq=i,
                    stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=ns),
                    frame_id="gps",
                ),
                status=T["sensor_msgs/msg/NavSatStatus"](status=int(nav.status[i]), service=1),
                latitude=float(nav.latitude_deg[i]),
                longitude=float(nav.longitude_deg[i]),
                altitude=float(nav.altitude_m[i]),
                position_covariance=nav.position_covariance_m2[i].reshape(9),
                position_covariance_type=int(nav.covariance_type[i]),
            )
            w.write(conn, int(s) + 1000, ts.serialize_ros1(msg, "sensor_msgs/msg/NavSatFix"))
    return path


def test_fixes_from_a_bag_are_cached_per_file(drive, tmp_path, monkeypatch):
    nav = synth_fixes(drive.run, sigma_m=0.0)
    bag = write_navsat_bag(tmp_path / "gnss.bag", nav)
    data = DataConfig(rtk_topic="/gnss/fix")
    cache = tmp_path / "cache"
    ref = build(cache, data=data, orientation="none", bag_path=str(bag)).compute([drive.segment])
    mem = build(cache, {drive.sequence.name: nav}, orientation="none").compute([drive.segment])
    assert np.allclose(ref[0].trajectory.t_world_body, mem[0].trajectory.t_world_body, atol=1e-6)

    def boom(*_):
        raise AssertionError("bag read again")

    monkeypatch.setattr("l2calib.references.rtk_source.read_navsat", boom)
    build(cache, data=data, orientation="none", bag_path=str(bag)).compute([drive.segment])
    os.utime(bag, ns=(0, 10**18))  # the bag changed: another key
    with pytest.raises(AssertionError, match="bag read again"):
        build(cache, data=data, orientation="none", bag_path=str(bag)).compute([drive.segment])
    monkeypatch.undo()
    wrong = build(cache, data=DataConfig(rtk_topic="/imu"), orientation="none", bag_path=str(bag))
    with pytest.raises(ReferenceSourceError, match="rtk: .*/imu") as err:
        wrong.compute([drive.segment])
    assert "/gnss/fix" in str(err.value)
