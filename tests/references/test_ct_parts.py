"""ct-lidar's parts: line normals, the planes' cache, α noise, one-line planes, retries."""

from __future__ import annotations

import numpy as np

from l2calib.data import NS_PER_S
from l2calib.references.ct_map import VoxelPlaneMap
from l2calib.references.ct_normals import line_normals
from l2calib.references.ct_odometry import CtLidarOdometry, ScanMotion
from l2calib.references.options import CtLidarOptions


def ring_scan(ground_z, step_deg=0.4):
    """8 lines (-15° to -1°, 2° apart) of the ground ``z = ground_z(x, y)`` seen from the origin.

    A ray's hit is where it meets z = -4, moved along the ray to the height there.
    """
    az = np.radians(np.arange(0.0, 360.0, step_deg))
    pts, ring = [], []
    for i, el in enumerate(np.radians(np.arange(-15.0, 0.0, 2.0))):
        c = np.cos(el)
        d = np.stack([c * np.cos(az), c * np.sin(az), np.full(len(az), np.sin(el))], 1)
        p = d * (-4.0 / d[:, 2])[:, None]
        z = ground_z(p[:, 0], p[:, 1])
        p = d * (z / d[:, 2])[:, None]
        pts.append(p)
        ring.append(np.full(len(az), i, np.uint16))
    return np.concatenate(pts), np.concatenate(ring)


def test_ground_rings_metres_apart_get_the_ground_normal():
    pts, ring = ring_scan(lambda x, y: np.full(len(x), -4.0))
    mid = np.flatnonzero((ring > 0) & (ring < 4))  # 18-26 m away, lines 2.3-7 m apart
    n = line_normals(pts, ring, mid)
    ok = np.isfinite(n[:, 0])
    assert ok.mean() > 0.99  # all but where the azimuth wraps round
    assert np.allclose(np.abs(n[ok, 2]), 1.0, atol=1e-3)
    beyond = np.flatnonzero(ring == 6)  # 76 m; the next line is at 229 m: too far to span
    assert np.isnan(line_normals(pts, ring, beyond)).all()


def test_a_curb_between_lines_gives_no_normal():
    """A 15 cm step between the 2nd and 3rd line: their patches bend; beyond it all is flat."""
    pts, ring = ring_scan(lambda x, y: np.where(np.hypot(x, y) > 19.0, -3.85, -4.0))
    straddle = line_normals(pts, ring, np.flatnonzero((ring == 1) | (ring == 2)))
    assert np.isnan(straddle[:, 0]).all()
    beyond = line_normals(pts, ring, np.flatnonzero(ring == 3))
    assert np.isfinite(beyond[:, 0]).mean() > 0.99


def test_query_planes_are_cached_per_cell_and_match_the_surface():
    gx, gy = np.meshgrid(np.linspace(0, 4, 41), np.linspace(0, 4, 41))
    floor = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, 0.5)], axis=1)
    m = VoxelPlaneMap(0.05, 100.0, neighbours=8, cell_m=0.2)
    m.insert(floor)
    q = np.array([[1.01, 1.02, 0.53], [1.05, 1.07, 0.49], [3.0, 3.0, 2.0]])
    planes = m.associate(q, 0.3)
    assert list(planes.index) == [0, 1]  # the third is 1.5 m off the floor: beyond the gate
    assert np.allclose(np.abs(planes.normal), [0, 0, 1], atol=1e-9)
    assert np.allclose(np.abs(planes.offset), 0.5)
    fitted = len(m._now.keys)
    m.associate(q + 0.01, 0.3)  # same cells: no new fit
    assert len(m._now.keys) == fitted


def test_alpha_noise_follows_the_angular_acceleration():
    odo = CtLidarOdometry(CtLidarOptions())
    o = odo.o
    stamps = (np.arange(30) * 0.1 * NS_PER_S).astype(np.int64)
    z = np.zeros(3)

    def motions(rate):
        return [ScanMotion(np.eye(3), z, rate(k), z, z, z) for k in range(30)]

    steady = motions(lambda k: np.array([0.0, 0.0, 0.3]))  # a UAV's slow turn
    swing = motions(lambda k: np.array([0.0, 0.0, 0.5 * k]))  # 5 rad/s² (hand-held)
    assert odo._alpha_noise(steady, stamps, 20) == o.noise_alpha_min_rad_s2
    assert np.isclose(odo._alpha_noise(swing, stamps, 20), o.alpha_noise_gain * 5.0)
    assert odo._alpha_noise(steady, stamps, 1) == o.noise_alpha_rad_s2  # no history: loose


def _planes_for_facing():
    """Three planes seen along +x from the origin: a wall facing the ray (one line), a plane
    holding the ray (one line: a ring's cone tangent), and the same on several lines."""
    from l2calib.references.ct_map import Planes

    world = np.array([[10.0, 0, 0], [10.0, 0, 0], [10.0, 0, 0]])
    normal = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, 0, 1.0]])
    planes = Planes(np.arange(3), normal, np.array([10.0, 0, 0]), np.array([True, True, False]))
    return planes, world, np.zeros((3, 3))


def test_one_line_planes_never_register_and_only_grazing_ones_leave_the_drift_check():
    from l2calib.references.ct_map import facing as _facing

    planes, world, origin = _planes_for_facing()
    drift_check = _facing(planes, world, origin, 8.0)
    assert list(drift_check.index) == [0, 2]  # the fake one-line plane (holds the ray) goes
    registration = _facing(planes, world, origin, 8.0, all_lines=True)
    assert list(registration.index) == [2]  # no one-line plane at all
    assert list(_facing(planes, world, origin, 0.0).index) == [0, 1, 2]  # filter off


def test_a_scan_that_fits_far_worse_is_solved_again_with_a_wider_prior():
    odo = CtLidarOdometry(CtLidarOptions())
    z = np.zeros(3)
    last = ScanMotion(np.eye(3), z, z, z, z, z)
    P = np.eye(18) * 1e-4
    widened = []

    def fake_solve(s, pred, P_pred):  # unit isolation: the retry's bookkeeping only
        wide = P_pred[9, 9] > 1.0  # α's variance after a widened prediction
        widened.append(wide)
        odo.last_inlier_ratio = 0.75 if wide else 0.4  # the usual fit: 0.9 x 0.8 = 0.72
        return pred, P_pred

    odo._solve = fake_solve
    odo.last_inlier_ratio = 0.4  # the first solve's
    first = ScanMotion(np.eye(3), np.ones(3), z, z, z, z)
    m, _ = odo._retry(None, first, P, last, P, 0.1, 8.0, [0.8] * 5)
    assert widened == [True] and odo.retries == 1
    assert np.allclose(m.t_b, 0) and odo.last_inlier_ratio == 0.75  # the retry's solution kept
    odo.last_inlier_ratio = 0.78  # a usual scan: no retry
    m, _ = odo._retry(None, first, P, last, P, 0.1, 8.0, [0.8] * 5)
    assert widened == [True] and np.allclose(m.t_b, 1)
    odo.last_inlier_ratio = 0.4
    odo._solve = lambda s, pred, P_pred: (setattr(odo, "last_inlier_ratio", 0.3), (pred, P_pred))[1]
    m, _ = odo._retry(None, first, P, last, P, 0.1, 8.0, [0.8] * 5)  # the retry fits worse
    assert odo.retries == 2 and np.allclose(m.t_b, 1) and odo.last_inlier_ratio == 0.4


def _scans(first_s, n, dt=0.1):
    """``n`` one-point scans ``dt`` apart from ``first_s`` (only their stamps matter here)."""
    from l2calib.data import LidarScan

    stamps = (np.arange(n) * dt + first_s) * NS_PER_S
    return [LidarScan(int(t), np.zeros((1, 3)), np.zeros(1)) for t in np.round(stamps)]


def test_cold_starts_go_twice_as_far_back_as_far_as_the_warmup_reaches():
    from l2calib.references.ct_lidar_source import cold_starts

    o = CtLidarOptions(margin_s=0.5, cold_starts=4)
    warmup = _scans(10.0, 30)  # 10.0-12.9 s, the segment from 13.0 s
    assert cold_starts(warmup, 13 * NS_PER_S, o) == [25, 20, 10, 0]  # 0.5, 1, 2, 4 (3) s back
    assert cold_starts(warmup[25:], 13 * NS_PER_S, o) == [0]  # the sequence starts 0.5 s before
    assert cold_starts([], 13 * NS_PER_S, o) == [0]  # no warm-up: the segment's first scan


def test_a_start_that_loses_track_early_is_tried_again_earlier(monkeypatch):
    import pytest

    from l2calib.errors import ReferenceLostTrackError
    from l2calib.references import ct_lidar_source

    o = CtLidarOptions(margin_s=0.5, cold_starts=3, cold_start_window_s=4.0)
    warmup, scans = _scans(10.0, 30), _scans(13.0, 10)
    firsts = []

    def fake_run(self, all_scans, on_scan=None):  # unit isolation: which starts are tried
        firsts.append(all_scans[0].stamp_ns / NS_PER_S)
        self.lost_at_s = lost_at.pop(0)
        if self.lost_at_s is not None:
            raise ReferenceLostTrackError("lost", fix="f")
        stamps = np.array([s.stamp_ns for s in all_scans], np.int64)
        return stamps, [ScanMotion(np.eye(3), *([np.zeros(3)] * 5))] * len(all_scans)

    monkeypatch.setattr(CtLidarOdometry, "run", fake_run)
    lost_at = [1.2, None]  # the first start loses track 1.2 s in, the second tracks
    traj = ct_lidar_source.run_segment(scans, warmup, o, "w")
    assert np.allclose(firsts, [12.5, 12.0]) and traj.stamps_ns[0] == scans[0].stamp_ns
    firsts.clear()
    lost_at = [5.0]  # 4.5 s into the segment: past the window, raised at once
    with pytest.raises(ReferenceLostTrackError, match="^lost"):
        ct_lidar_source.run_segment(scans, warmup, o, "w")
    firsts.clear()
    lost_at = [1.0, 1.0, 4.0]  # every start lost: the error says how many were tried
    with pytest.raises(ReferenceLostTrackError, match="start 3 of 3, 2.0 s before w"):
        ct_lidar_source.run_segment(scans, warmup, o, "w")
    assert np.allclose(firsts, [12.5, 12.0, 11.0])
