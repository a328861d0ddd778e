"""ct-lidar roll-back: a scan found lost is undone with the scans before it and solved again."""

from __future__ import annotations

import numpy as np
import pytest

from l2calib.alignment import ape
from l2calib.errors import ReferenceLostTrackError
from l2calib.references.ct_odometry import CtLidarOdometry
from l2calib.references.ct_tracking import TrackingChecks
from l2calib.references.options import CtLidarOptions


def test_a_scan_found_lost_once_is_solved_again_and_the_run_goes_on(swing, monkeypatch):
    """One (fake) loss at scan 12: scans 6-12 are undone, map points included, and solved again."""
    real = TrackingChecks._check_tracking
    seen = []

    born = {}

    def once(self, k, stamps, m):
        seen.append(k)
        born[k, seen.count(k)] = float(self.map.born.max())  # before scan k joins the map
        if k == 12 and seen.count(12) == 1:
            self.unseen = False
            raise ReferenceLostTrackError("fake loss")
        return real(self, k, stamps, m)

    monkeypatch.setattr(TrackingChecks, "_check_tracking", once)
    odo = CtLidarOdometry(CtLidarOptions(max_range_m=100.0, rollback_scans=6))
    scans = swing.segment.scans
    stamps, motions = odo.run(scans)
    assert odo.rollbacks == 1 and len(motions) == len(scans)
    assert seen[: 12 + 7] == [*range(1, 13), *range(6, 13)]  # 6 scans back, then on
    # the undone scans' map points went with them: solving scan 6 again, the map is as it was
    assert born[6, 2] == born[6, 1] < born[12, 1]
    assert np.all(np.isfinite([m.t_b for m in motions]))


def test_scans_no_odometry_can_follow_still_raise_after_the_roll_backs(lost):
    """The roll-back is tried ``rollback_max`` times; scattered scans stay lost and say so."""
    odo = CtLidarOdometry(CtLidarOptions(rollback_max=2))
    with pytest.raises(ReferenceLostTrackError, match="lost track"):
        odo.run(lost.scans)
    assert odo.rollbacks == 2


def test_each_roll_back_draws_a_fresh_sample_independent_of_the_scans_before(swing, monkeypatch):
    """Two fake losses at scan 12: two roll-backs, each with its own sample of scan 12; the
    samples are the same whatever the run's own generator drew before (seeded per scan)."""
    real = TrackingChecks._check_tracking
    real_prepare = CtLidarOdometry._prepare

    def run(skip_draws: int) -> list[np.ndarray]:
        seen, drawn = [], []

        def twice(self, k, stamps, m):
            seen.append(k)
            if k == 12 and seen.count(12) <= 2:
                self.unseen = False
                raise ReferenceLostTrackError("fake loss")
            return real(self, k, stamps, m)

        def prepare(self, scan, density=1.0, rng=None):
            s = real_prepare(self, scan, density, rng)
            if rng is not None and scan is swing.segment.scans[12]:
                drawn.append(s.points)
            return s

        monkeypatch.setattr(TrackingChecks, "_check_tracking", twice)
        monkeypatch.setattr(CtLidarOdometry, "_prepare", prepare)
        odo = CtLidarOdometry(CtLidarOptions(max_range_m=100.0, rollback_scans=6))
        odo.rng.random(skip_draws)  # another history of the run's own generator
        _, motions = odo.run(swing.segment.scans)
        assert odo.rollbacks == 2 and len(motions) == len(swing.segment.scans)
        return drawn

    a, b = run(0), run(5)
    assert len(a) == len(b) == 2
    assert not np.array_equal(a[0], a[1])  # a fresh sample each time
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))


def test_without_roll_back_the_same_scans_raise_at_once(lost):
    odo = CtLidarOdometry(CtLidarOptions(rollback_scans=0))
    with pytest.raises(ReferenceLostTrackError):
        odo.run(lost.scans)
    assert odo.rollbacks == 0


def test_the_rolled_back_run_still_tracks(swing, monkeypatch):
    real = TrackingChecks._check_tracking
    calls = {"n": 0}

    def once(self, k, stamps, m):
        calls["n"] += 1
        if calls["n"] == 15:
            self.unseen = False
            raise ReferenceLostTrackError("fake loss")
        return real(self, k, stamps, m)

    monkeypatch.setattr(TrackingChecks, "_check_tracking", once)
    from l2calib.references.ct_lidar_source import run_segment

    tr = run_segment(swing.segment.scans, [], CtLidarOptions(max_range_m=100.0), "w")
    assert ape(swing.run.gt_lidar, tr).rmse_t < 0.03  # the swing from a cold start: 1.8 cm
