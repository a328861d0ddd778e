"""Coarse-to-fine scoring: the backend scores a part of the data, the same for every candidate."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from l2calib import geometry as geo
from l2calib.interfaces import CandidateStatus
from l2calib.plugins import get_plugin
from l2calib.recipe import TrainConfig
from l2calib.train.coarse import data_fraction
from l2calib_backends.data_fraction import full_plan, plan_windows


def test_windowed_plan_spreads_the_kept_windows_over_the_segment():
    starts = list(range(0, 100, 10))  # 10 windows over 101 scans
    full = full_plan(starts, 101)
    assert full.scans == 100 and full.ends[-1] == 100
    half = plan_windows(starts, 101, 0.5)
    assert half.keep == [1, 3, 5, 7, 9] and half.scans == 50  # every other, not the first half
    assert plan_windows(starts, 101, 0.01).keep == [5]  # one window, from the middle
    assert plan_windows(starts, 101, 1.0) == full


def test_a_continuous_run_keeps_all_its_data():
    """Weakly excited data: no part of a drive ranks candidates like the whole (module doc)."""
    assert plan_windows([0], 201, 0.25) == full_plan([0], 201)
    assert plan_windows([0], 201, 0.01).scans == 200


def _spread(rot_deg: float, trans_m: float):
    from l2calib.interfaces import PolicySpread

    return PolicySpread(torch.full((3,), np.radians(rot_deg)), torch.full((3,), trans_m))


def test_the_fraction_follows_the_widest_spread():
    cfg = TrainConfig(coarse_to_fine=True)
    assert data_fraction(_spread(60.0, 0.5), cfg) == pytest.approx(cfg.coarse_data_fraction)
    assert data_fraction(_spread(1.0, 0.01), cfg) == 1.0
    wide_t = data_fraction(_spread(1.0, 0.1), cfg)  # narrow rotation, translation still wide
    assert cfg.coarse_data_fraction < wide_t < 1.0
    assert data_fraction(_spread(60.0, 0.5), TrainConfig(coarse_to_fine=False)) == 1.0


def test_fine_levels_must_be_below_coarse_ones():
    with pytest.raises(ValueError, match="fine_rotation_sigma_deg"):
        TrainConfig(fine_rotation_sigma_deg=30.0)


def test_backend_scores_on_the_part_and_restores_all(handheld_run, handheld_segment):
    """Candidates keep their order of merit on a quarter of the windows; 1.0 gives back the
    same rewards as before (what the refinement after a coarse training relies on)."""
    from l2calib.reward import trajectory_reward

    seg, ref = handheld_segment
    backend = get_plugin("l2calib.backends", "iekf").build({"window_scans": 10})
    backend.prepare([seg], [ref])
    xis = torch.zeros(3, 6, dtype=torch.float64)
    xis[1, 3] = np.radians(5.0)
    xis[2, 0] = 0.15
    T = torch.from_numpy(handheld_run.T_imu_lidar) @ geo.se3_exp(xis)

    def rewards():
        out = backend.evaluate(T)[0]
        truth = ref.trajectory.interpolate(out.stamps_ns).matrices()
        failed = out.status == int(CandidateStatus.DIVERGED)
        r = trajectory_reward(truth, out.T_world_lidar, out.valid, failed=failed, align="none")
        return out, r.reward

    total = backend.measurements_per_candidate()
    out_all, before = rewards()
    part = backend.use_data_fraction(0.25)
    out_part, coarse = rewards()
    assert 0 < part < 0.5 * total
    scored = out_part.valid.sum(1)
    assert int(scored.max()) <= part and int(scored.min()) > 0  # the same part for each
    assert torch.all(coarse[1:] < coarse[0]), coarse  # the truth still ranks first
    assert backend.use_data_fraction(1.0) == total
    _, again = rewards()
    assert torch.allclose(again, before)
    assert int(out_all.valid.sum(1).max()) == total


def test_a_continuous_backend_answers_that_it_scores_all_of_it(handheld_segment):
    """The trainer counts the share the backend reports, not the fraction it asked for."""
    seg, ref = handheld_segment
    backend = get_plugin("l2calib.backends", "iekf").build({"window_scans": 0})
    backend.prepare([seg], [ref])
    total = backend.measurements_per_candidate()
    assert backend.use_data_fraction(0.25) == total == len(seg.scans) - 1


def test_window_counts_are_decided_over_all_segments():
    from l2calib_backends.data_fraction import window_counts

    assert window_counts([5, 5], 0.3) == [2, 1]  # 3 of 10 windows, not 2 + 2
    assert window_counts([4, 7, 3], 0.25) == [1, 2, 1]
    assert window_counts([1, 1, 1], 0.1) == [1, 1, 1]  # every segment keeps one
    assert window_counts([5, 5], 1.0) == [5, 5]
