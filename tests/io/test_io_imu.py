"""IMU unit detection with evidence, and conversion to SI (synthetic signals, no bags)."""

from __future__ import annotations

import numpy as np
import pytest
from imu_signals import imu_signal

from l2calib.errors import DataError
from l2calib.io.imu_reader import (
    DEG,
    STANDARD_GRAVITY,
    RawImu,
    detect_units,
    kinematic_gyro_scale,
    to_imu_samples,
)
from l2calib.recipe import ImuInput


def raw_imu(gyro_scale=1.0, accel_scale=1.0, **kw):
    st, g, a = imu_signal(kw.pop("duration_s", 20.0), kw.pop("rate_hz", 200.0), **kw)
    return RawImu(st, st + 1_000_000, g * gyro_scale, a * accel_scale), (st, g, a)


@pytest.mark.parametrize(
    ("g_scale", "a_scale", "units"),
    [
        (1.0, 1.0, ("rad/s", "m/s^2")),
        (1 / DEG, 1.0, ("deg/s", "m/s^2")),
        (1.0, 1 / STANDARD_GRAVITY, ("rad/s", "g")),
        (1 / DEG, 1 / STANDARD_GRAVITY, ("deg/s", "g")),
    ],
)
def test_units_detected_from_tilting_motion(g_scale, a_scale, units):
    raw, (_, g, a) = raw_imu(g_scale, a_scale, seed=3)
    u = detect_units(raw, ImuInput())
    assert (u.gyro_unit, u.accel_unit) == units
    assert u.gyro_confirmed and u.accel_confirmed
    assert set(u.detected) == {"gyro_unit", "accel_unit"}
    assert "gravity turns in the IMU frame" in u.gyro_evidence
    samples, repaired = to_imu_samples(raw, u, "bag: /imu")
    np.testing.assert_allclose(samples.gyro_rad_s, g, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(samples.accel_m_s2, a, rtol=1e-12, atol=1e-12)
    assert repaired == {"reordered": 0, "duplicates": 0, "non_finite": 0}


def test_kinematic_scale_is_one_for_rad_s_and_deg_for_deg_s():
    # 10 random motions: the fitted scale stays within 20 % of the truth (the decision
    # boundary is a factor 7.6 away).
    for seed in range(10):
        raw, _ = raw_imu(duration_s=10.0, seed=seed)
        k, corr = kinematic_gyro_scale(raw.header_ns, raw.gyro, raw.accel)
        assert abs(k - 1.0) < 0.2 and corr > 0.5
        k, _ = kinematic_gyro_scale(raw.header_ns, raw.gyro / DEG, raw.accel)
        assert abs(k / DEG - 1.0) < 0.2


def test_planar_yaw_motion_falls_back_to_magnitude_or_rest_noise():
    planar = dict(rot_amp_rad=(0.0, 0.0, 0.0), yaw_rate_rad_s=0.6, duration_s=20.0, seed=1)
    raw, _ = raw_imu(1 / DEG, **planar)  # 34 deg/s readings
    u = detect_units(raw, ImuInput())
    assert u.gyro_unit == "deg/s" and u.gyro_confirmed and "implausible in rad/s" in u.gyro_evidence
    still = dict(
        rot_amp_rad=(0.0, 0.0, 0.0), acc_amp_m_s2=(0.0, 0.0, 0.0), seed=2, noise=(0.0015, 0.01)
    )
    raw, _ = raw_imu(1 / DEG, **still)
    u = detect_units(raw, ImuInput())
    assert u.gyro_unit == "deg/s" and "noise at rest" in u.gyro_evidence
    raw, _ = raw_imu(1.0, **still)
    u = detect_units(raw, ImuInput())
    assert u.gyro_unit == "rad/s" and u.gyro_confirmed


def test_ambiguous_gyro_is_assumed_rad_s_but_unconfirmed():
    still = dict(
        rot_amp_rad=(0.0, 0.0, 0.0), acc_amp_m_s2=(0.0, 0.0, 0.0), seed=2, noise=(0.01, 0.01)
    )  # noisy rad/s IMU or a quiet deg/s one
    raw, _ = raw_imu(1.0, **still)
    u = detect_units(raw, ImuInput())
    assert u.gyro_unit == "rad/s" and not u.gyro_confirmed
    assert "too little tilting motion" in u.gyro_evidence


def test_recipe_units_are_used_and_conflicts_flagged():
    raw, _ = raw_imu(seed=4)
    u = detect_units(raw, ImuInput(gyro_unit="deg/s", accel_unit="g"))
    assert (u.gyro_unit, u.accel_unit, u.detected) == ("deg/s", "g", ())
    assert not u.gyro_confirmed and not u.accel_confirmed


def test_accel_magnitude_that_is_no_gravity_is_unconfirmed():
    raw, _ = raw_imu(accel_scale=0.4, seed=5)  # ~3.9 (moving): neither 9.81 nor 1
    u = detect_units(raw, ImuInput())
    assert not u.accel_confirmed and 3.5 < u.rest_accel_norm < 4.5
    assert f"quietest blocks |a| = {u.rest_accel_norm:.3g}" in u.accel_evidence


def test_stamps_are_sorted_and_duplicates_dropped():
    raw, (st, g, a) = raw_imu(duration_s=2.0, seed=6)
    order = np.arange(len(st))
    order[[10, 11]] = order[[11, 10]]
    dup = np.concatenate([order, [50]])
    bad = RawImu(st[dup], st[dup], g[dup], a[dup])
    bad.gyro[3] = np.nan
    samples, repaired = to_imu_samples(bad, detect_units(bad, ImuInput()), "bag: /imu")
    assert np.all(np.diff(samples.stamps_ns) > 0)
    assert repaired == {"reordered": 2, "duplicates": 1, "non_finite": 1}
    assert len(samples) == len(st) - 1


def test_zero_stamps_are_an_error():
    raw, (st, g, a) = raw_imu(duration_s=1.0)
    zero = RawImu(np.zeros_like(st), st, g, a)
    with pytest.raises(DataError, match="bag: /imu: 201 of 201 IMU header stamps are zero"):
        to_imu_samples(zero, detect_units(raw, ImuInput()), "bag: /imu")
