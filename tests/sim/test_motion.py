"""Motion profiles: exact derivatives, still periods, magnitudes per platform, clearance."""

from __future__ import annotations

import numpy as np
import pytest

from l2calib.errors import ConfigError
from l2calib.sim.profiles import build_motion, profile_params
from l2calib.sim.scenes import make_world
from l2calib.sim.signals import ActivityWindow
from l2calib.sim.sweep import check_clearance
from l2calib.sim.world import WORLD_NAMES


def _motion(
    profile: str,
    world: str = "urban",
    seed: int = 0,
    horizon: float = 40.0,
    still=((0.0, 1.0),),
    lever: float = 0.1,
):
    w = make_world(world, seed)
    return w, build_motion(
        w, profile_params(profile), lever, horizon, list(still), np.random.default_rng(seed)
    )


def test_activity_window_is_zero_when_still_and_its_clock_integrates_it():
    win = ActivityWindow([(0.0, 1.0), (6.0, 8.0)], ramp_s=1.0)
    t = np.linspace(0.0, 12.0, 2401)
    w = win(t)
    assert np.all(w[(t <= 1.0) | ((t >= 6.0) & (t <= 8.0))] == 0.0)
    assert np.all(w[(t >= 2.0) & (t <= 5.0)] == 1.0) and np.all(w[t >= 9.0] == 1.0)
    h = 1e-5  # d(clock)/dt == W and dW/dt matches finite differences
    assert np.allclose((win.clock(t + h) - win.clock(t - h)) / (2 * h), w, atol=1e-6)
    assert np.allclose((win(t + h) - win(t - h)) / (2 * h), win(t, 1), atol=1e-4)


def test_activity_window_rejects_too_short_motion():
    with pytest.raises(ConfigError, match="shorter than its"):
        ActivityWindow([(0.0, 1.0), (2.0, 3.0)], ramp_s=1.0)


@pytest.mark.parametrize("profile", ["handheld", "uav", "ugv"])
def test_velocity_acceleration_and_body_rate_are_exact_derivatives(profile):
    _, m = _motion(profile)
    t = np.array([0.5, 1.3, 4.7, 11.1, 23.9, 37.2])
    h = 1e-4
    s0, sp, sm = m.state(t), m.state(t + h), m.state(t - h)
    v_fd = (sp.t_world_imu - sm.t_world_imu) / (2 * h)
    a_fd = (sp.v_world_imu - sm.v_world_imu) / (2 * h)
    dR = (sp.R_world_base - sm.R_world_base) / (2 * h)
    W = np.einsum("nji,njk->nik", s0.R_world_base, dR)  # R^T dR/dt = hat(omega_body)
    w_fd = np.stack([W[:, 2, 1], W[:, 0, 2], W[:, 1, 0]], axis=1)
    # Central differences with h = 1e-4 s are accurate to ~1e-6 for these smooth signals.
    assert np.abs(v_fd - s0.v_world_imu).max() < 1e-5
    assert np.abs(a_fd - s0.a_world_imu).max() < 1e-4
    assert np.abs(w_fd - s0.omega_base).max() < 1e-5


def test_rig_is_exactly_still_during_still_periods():
    _, m = _motion("handheld", still=((0.0, 1.0), (10.0, 12.0)))
    t = np.concatenate([np.linspace(0, 1, 50), np.linspace(10, 12, 50)])
    st = m.state(t)
    assert np.all(st.v_world_imu == 0) and np.all(st.omega_base == 0)
    assert np.all(st.a_world_imu == 0)
    assert np.ptp(st.t_world_imu[:50], axis=0).max() == 0


def _stats(profile: str, seed: int):
    _, m = _motion(profile, seed=seed, horizon=62.0)
    st = m.state(np.arange(2.0, 60.0, 0.01))
    return st, np.linalg.norm(st.omega_base, axis=1)


@pytest.mark.parametrize(("profile", "lo", "hi"), [("handheld", 1.6, 2.6), ("uav", 0.06, 0.3)])
def test_profile_excitation_matches_the_papers_platforms(profile, lo, hi):
    # Paper: handheld ~2.2 rad/s, NTU VIRAL UAV ~0.14 rad/s. 58 s of motion per seed, 3 seeds.
    means = [_stats(profile, seed)[1].mean() for seed in range(3)]
    assert lo < np.mean(means) < hi, means


def test_ugv_is_planar_and_yaw_dominant():
    st, wn = _stats("ugv", 1)
    rpy_rate = np.abs(st.omega_base)
    assert np.ptp(st.t_world_imu[:, 2]) < 0.05  # bounces of at most a few cm
    assert rpy_rate[:, 2].mean() > 3 * rpy_rate[:, :2].mean()
    assert np.abs(st.v_world_imu[:, 2]).max() < 0.2


@pytest.mark.parametrize("world", WORLD_NAMES)
@pytest.mark.parametrize("profile", ["handheld", "uav", "ugv"])
def test_trajectories_keep_clear_of_every_surface(world, profile):
    T = np.eye(4)
    T[:3, 3] = [0.65, -0.372, -0.016]  # the paper's handheld rig: largest lever arm
    w, m = _motion(profile, world=world, seed=2, lever=float(np.linalg.norm(T[:3, 3])))
    assert check_clearance(w, m, T, 40.0) >= w.clearance_m / 2


def test_world_is_reproducible_from_its_seed():
    a, b, c = make_world("urban", 5), make_world("urban", 5), make_world("urban", 6)
    assert np.array_equal(a.vertices, b.vertices)
    assert a.vertices.shape != c.vertices.shape or not np.array_equal(a.vertices, c.vertices)
    with pytest.raises(ConfigError, match="unknown world 'mars'"):
        make_world("mars")
