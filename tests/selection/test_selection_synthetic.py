"""Data selection on synthetic IMU signals (exact rotation + gravity + noise, no simulator)."""

from __future__ import annotations

import numpy as np
import pytest
from imu_signals import imu_signal
from scipy.spatial.transform import Rotation

from l2calib.data import NS_PER_S, ImuSamples, InMemoryScans, LidarScan, Sequence
from l2calib.recipe import SelectionConfig
from l2calib.selection import integrate_gyro, select_windows, window_excitation

PLANAR = dict(
    rot_amp_rad=(0.004, 0.004, 0.0),
    rot_freq_hz=(2.0, 2.6, 0.1),
    yaw_rate_rad_s=0.3,
    acc_amp_m_s2=(1.5, 1.0, 0.6),
)


def sequence(name="seq", duration=90.0, rate=200.0, scan_gap=None, drop=None, **kw) -> Sequence:
    st, g, a = imu_signal(duration, rate, **kw)
    if drop is not None:
        rel = (st - st[0]) / NS_PER_S
        keep = ~((rel > drop[0]) & (rel < drop[1]))
        st, g, a = st[keep], g[keep], a[keep]
    scan_st = np.arange(st[0], st[-1], NS_PER_S // 10)
    if scan_gap is not None:
        rel = (scan_st - st[0]) / NS_PER_S
        scan_st = scan_st[~((rel > scan_gap[0]) & (rel < scan_gap[1]))]
    scans = InMemoryScans([LidarScan(int(s)) for s in scan_st])
    return Sequence(name, ImuSamples(st, g, a), scans)


def rel_s(seq, ns):
    return (ns - seq.start_ns) / NS_PER_S


def test_integrate_gyro_matches_sequential_rotation_products(rng):
    n = 1000
    st = 1_000_000_000 + np.cumsum(rng.integers(2_000_000, 3_000_000, n))
    w = rng.normal(0, 2.0, (n, 3))
    q = integrate_gyro(st, w)
    R = Rotation.identity()
    dt = np.diff(st) / 1e9
    for k in range(1, n):
        R = R * Rotation.from_rotvec(w[k - 1] * dt[k - 1])
        if k % 97 == 0:
            assert (Rotation.from_quat(q[k]) * R.inv()).magnitude() < 1e-9


def test_gravity_does_not_count_as_excitation():
    # Tilting +-0.5 rad with no linear acceleration: the specific force swings by several m/s^2
    # in the IMU frame, but the gravity-free acceleration stays at the noise level.
    seq = sequence(duration=30.0, acc_amp_m_s2=(0.0, 0.0, 0.0), seed=1)
    w = window_excitation(seq, SelectionConfig())
    raw_std = np.sqrt(seq.imu.accel_m_s2.var(axis=0))
    assert raw_std.max() > 2.0
    rms_lin = np.sqrt(np.einsum("wii->wi", w.accel_moment))
    assert rms_lin.max() < 0.08  # noise 0.02 m/s^2 + window-edge integration error
    assert np.sqrt(w.lambda_gyro).min() > 0.1  # the rotation itself is excitation
    still = sequence(duration=30.0, rot_amp_rad=(0, 0, 0), acc_amp_m_s2=(0, 0, 0), seed=2)
    ws = window_excitation(still, SelectionConfig())
    assert not ws.eligible.any() and ws.block_still.all()
    assert np.sqrt(ws.lambda_accel).max() < 0.03 and np.sqrt(ws.lambda_gyro).max() < 0.003


def test_still_segments_are_never_selected():
    still = [(20.0, 35.0), (55.0, 66.0)]
    seq = sequence(still=still, seed=4)
    sel = select_windows([seq], SelectionConfig(budget_s=30.0))
    assert len(sel.chosen) == 3 and sel.total_s == pytest.approx(30.0)
    for c in sel.chosen:
        for a, b in still:
            overlap = min(rel_s(seq, c.end_ns), b) - max(rel_s(seq, c.start_ns), a)
            assert overlap <= 0.5  # motion ramps out over 0.5 s: never a still block
    w = sel.windows["seq"]
    blocks = rel_s(seq, w.block_start_ns[w.block_still])
    assert all(any(a - 1 <= t <= b for a, b in still) for t in blocks)
    assert len(blocks) >= 22


def test_planar_motion_reports_roll_and_pitch_as_weak():
    sel = select_windows([sequence(seed=5, **PLANAR)], SelectionConfig())
    assert sel.weak_axes == ["rotation about x", "rotation about y"]
    assert sel.gyro_rms_rad_s[2] > 0.25 and sel.gyro_rms_rad_s[:2].max() < 0.05
    assert sel.accel_rms_m_s2.min() > 0.3
    hand = select_windows([sequence(seed=6)], SelectionConfig())
    assert hand.weak_axes == [] and min(c.score for c in hand.chosen) > 1.0


def test_selection_fills_the_axes_it_lacks():
    # A: strong roll only; B: weaker pitch only. Two windows: one from each, although every
    # window of A has more total excitation than B's.
    a = sequence("A", duration=40.0, rot_amp_rad=(0.9, 0.0, 0.0), seed=7)
    b = sequence("B", duration=40.0, rot_amp_rad=(0.0, 0.3, 0.0), seed=8)
    sel = select_windows([a, b], SelectionConfig(budget_s=20.0))
    assert sorted(c.sequence for c in sel.chosen) == ["A", "B"]
    trace = lambda w: np.trace(w.gyro_moment, axis1=1, axis2=2)  # noqa: E731
    assert trace(sel.windows["B"]).max() < trace(sel.windows["A"]).min()
    assert [x for x in sel.weak_axes if x.startswith("rotation")] == ["rotation about z"]


def test_windows_with_imu_or_lidar_gaps_are_not_chosen():
    seq = sequence(drop=(40.0, 40.5), scan_gap=(70.0, 70.6), seed=9)
    w = window_excitation(seq, SelectionConfig())
    mid = rel_s(seq, w.start_ns)
    assert w.gap[(mid > 31) & (mid < 40)].all() and w.gap[(mid > 61) & (mid < 70)].all()
    sel = select_windows([seq], SelectionConfig(budget_s=60.0))
    for c in sel.chosen:
        for t in (40.2, 70.3):
            assert not rel_s(seq, c.start_ns) < t < rel_s(seq, c.end_ns)


def test_budget_spans_segments_and_disabled_selection():
    seq = sequence(duration=40.0, seed=10)
    sel = select_windows([seq], SelectionConfig(budget_s=25.0, window_s=5.0, step_s=5.0))
    assert len(sel.chosen) == 5 and sel.total_s == pytest.approx(25.0)
    spans = sel.spans()
    assert sum((b - a) for _, a, b in spans) / NS_PER_S == pytest.approx(25.0)
    segs = sel.segments([seq])
    assert [s.sequence for s in segs] == ["seq"] * len(spans)
    assert all(len(s.scans) >= 45 for s in segs)
    short = select_windows([seq], SelectionConfig(budget_s=4.0))
    assert short.chosen[0].duration_s == pytest.approx(4.0) and "shortened" in short.notes[0]
    off = select_windows([seq], SelectionConfig(enabled=False))
    assert len(off.chosen) == 1 and off.chosen[0].start_ns == seq.start_ns
    assert off.chosen[0].end_ns == seq.end_ns
    json_ready = off.as_dict()
    assert json_ready["chosen"][0]["sequence"] == "seq"


def test_nothing_eligible_reports_every_axis_weak():
    still = sequence(duration=30.0, rot_amp_rad=(0, 0, 0), acc_amp_m_s2=(0, 0, 0), seed=11)
    sel = select_windows([still], SelectionConfig())
    assert sel.chosen == [] and "no eligible window" in sel.notes[0]
    assert len(sel.weak_axes) == 6


def test_a_weak_diagonal_direction_is_named_readably():
    from l2calib.selection.greedy import _weak

    d = np.array([0.87, 0.5, 0.0]) / np.linalg.norm([0.87, 0.5, 0.0])
    moment = np.eye(3) - 0.99 * np.outer(d, d)  # strong on every axis, weak along d
    names, _ = _weak(moment, 0.5, "rotation about")
    assert names == ["rotation about the direction [+0.87, +0.50, +0.00] (IMU frame)"]
