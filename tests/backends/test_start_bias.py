"""The filters' start biases: least squares of the segment's IMU against the reference motion."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from l2calib_backends.initialise import initial_states, reference_motion
from l2calib_backends.prepare import prepare_segment
from l2calib_backends.start_bias import chunk_bounds

SIGMAS = dict.fromkeys(("rot", "pos", "vel", "bg", "ba", "grav"), 0.1)


def _start(run, segment, estimate: str, T=None, offsets=None):
    seg, ref = segment
    prepared = prepare_segment(seg, 0.5, 250, 1500, 1.0, 100.0, 0)
    motion = reference_motion(prepared, ref.trajectory, [0], estimate)
    T = torch.from_numpy(run.T_imu_lidar)[None] if T is None else T
    return initial_states(motion, T, SIGMAS, offsets), prepared


def _true_biases(run, prepared):
    """Mean simulated turn-on + random-walk biases over the segment's IMU samples."""
    t_rel = (run.imu.stamps_ns - run.t0_ns) * 1e-9
    seg_t = (prepared.start_ns - run.t0_ns) * 1e-9 + prepared.imu.t.numpy()
    inside = (t_rel >= seg_t[0]) & (t_rel <= seg_t[-1])
    errors = run.imu_errors
    return errors.gyro_bias_rad_s[inside].mean(0), errors.accel_bias_m_s2[inside].mean(0)


def test_chunks_cover_the_samples_inside_the_margins():
    t = torch.arange(0, 4.0, 0.005, dtype=torch.float64)
    bounds = chunk_bounds(t, 0.5)
    assert bounds[0] == 0 and bounds[-1] == len(t) - 1 and len(bounds) == 9
    inner = chunk_bounds(t, 0.5, margin_s=0.05)
    assert t[inner[0]] >= 0.05 and t[inner[-1]] <= t[-1] - 0.05 and len(inner) == 9
    short = torch.arange(0, 0.02, 0.005, dtype=torch.float64)  # shorter than the margins
    assert chunk_bounds(short, 0.5, margin_s=0.05).tolist() == [len(short) - 1]  # no chunk


def test_estimated_start_biases_match_the_simulated_ones(handheld_run, handheld_segment):
    """Hand-held motion turns the IMU about every axis: gravity and both biases separate.

    Catches a sign or frame error in either bias (they would then be off by about twice the
    simulated bias, 0.002 rad/s and 0.02 m/s² of σ), and a gravity that kept the bias.
    """
    state, prepared = _start(handheld_run, handheld_segment, "estimate")
    bg_true, ba_true = _true_biases(handheld_run, prepared)
    assert np.abs(bg_true).max() > 5e-4 and np.abs(ba_true).max() > 0.01  # biases to find
    np.testing.assert_allclose(state.bg[0].numpy(), bg_true, atol=2e-4)
    np.testing.assert_allclose(state.ba[0].numpy(), ba_true, atol=8e-3)
    assert abs(float(state.g[0].norm()) - handheld_run.config.gravity_m_s2) < 8e-3


def test_zero_start_biases_when_asked(handheld_run, handheld_segment):
    state, _ = _start(handheld_run, handheld_segment, "zero")
    assert not state.bg.any() and not state.ba.any()


def test_a_wrong_rotation_gives_a_different_gyro_bias(handheld_run, handheld_segment):
    """The gyro bias is what the candidate's rotation leaves of the gyro: it depends on it."""
    from l2calib import geometry as geo

    T = torch.from_numpy(handheld_run.T_imu_lidar)[None].repeat(2, 1, 1)
    T[1, :3, :3] = T[1, :3, :3] @ geo.so3_exp(torch.tensor([0.0, 0.0, 0.05], dtype=T.dtype))
    state, _ = _start(handheld_run, handheld_segment, "gyro", T)
    assert float((state.bg[1] - state.bg[0]).norm()) > 1e-3


@pytest.mark.parametrize("offset_s", [0.0, 0.02])
def test_a_time_offset_reads_the_imu_at_its_own_clock(sim, offset_s):
    """With the true offset given, the estimate is as good as on a recording without one."""
    run = sim("handheld", 8.0, rig={"time_offset_s": offset_s})
    from l2calib.interfaces import ReferenceTrajectory

    seq = run.sequence()
    seg = seq.segment(seq.start_ns + 1_500_000_000, seq.end_ns - 500_000_000)
    offsets = torch.tensor([offset_s], dtype=torch.float64)
    state, prepared = _start(run, (seg, ReferenceTrajectory(seg.name, run.gt_lidar)), "estimate",
                             offsets=offsets)  # fmt: skip
    bg_true, ba_true = _true_biases(run, prepared)
    np.testing.assert_allclose(state.bg[0].numpy(), bg_true, atol=2e-4)
    np.testing.assert_allclose(state.ba[0].numpy(), ba_true, atol=8e-3)


def test_implausible_biases_are_not_used(handheld_run, handheld_segment):
    """A candidate 30° off gets biases far beyond the priors (they fit its wrong rotation, not
    the IMU): it starts with zero biases and the mean-force gravity, as without the estimate,
    so that the estimate does not help wrong candidates to fit."""
    from l2calib import geometry as geo

    T = torch.from_numpy(handheld_run.T_imu_lidar)[None].repeat(2, 1, 1)
    T[1, :3, :3] = T[1, :3, :3] @ geo.so3_exp(torch.tensor([0.0, 0.5, 0.0], dtype=T.dtype))
    seg, ref = handheld_segment
    prepared = prepare_segment(seg, 0.5, 250, 1500, 1.0, 100.0, 0)
    sigmas = dict(SIGMAS, bg=0.01, ba=0.1)  # the hand-held start priors
    est = initial_states(reference_motion(prepared, ref.trajectory, [0], "estimate"), T, sigmas)
    zero = initial_states(reference_motion(prepared, ref.trajectory, [0], "zero"), T, sigmas)
    assert est.ba[0].abs().max() > 0.005  # the true candidate's estimate is used
    assert not est.bg[1].any() and not est.ba[1].any()
    assert torch.equal(est.g[1], zero.g[1])
