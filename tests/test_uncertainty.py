"""The per-axis uncertainty (l2calib.assess.uncertainty) on costs whose answer is known.

Each block of data gets a quadratic cost ``½ (θ − μ_b)ᵀ A (θ − μ_b) + c_b`` with its own
minimum ``μ_b`` (the data's noise): the minimum of the sum is the blocks' mean, its standard
error the spread of the ``μ_b`` over ``sqrt(B)``. The stencil's costs are evaluated exactly as
the odometry's would be, at the points :func:`~l2calib.assess.uncertainty.candidates` moves to.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from l2calib.assess import uncertainty as unc
from l2calib.assess.polish import stencil

STIFF = np.diag([4e4, 4e4, 2e4, 400.0, 400.0, 300.0])  # rad⁻², m⁻² (hand-held-like curvatures)


def block_costs(mu: np.ndarray, A: np.ndarray = STIFF, c: float = 0.0) -> np.ndarray:
    """``[P, B]`` costs of the 6-axis stencil around 0 for block minima ``mu [B, 6]``."""
    d = stencil(6)  # the perturbations candidates() applies, in its order
    diff = d[:, None, :] - mu[None]
    return 0.5 * np.einsum("pbi,ij,pbj->pb", diff, A, diff) + c


def test_candidates_follow_the_stencil():
    T, offsets = unc.candidates(torch.eye(4, dtype=torch.float64), None)
    assert T.shape == (73, 4, 4) and offsets is None
    T, offsets = unc.candidates(torch.eye(4, dtype=torch.float64), 0.01)
    assert T.shape == (99, 4, 4) and offsets.shape == (99,)
    assert torch.allclose(T[0], torch.eye(4, dtype=torch.float64)) and float(offsets[0]) == 0.01


def test_newton_step_and_noise_are_the_blocks_mean_and_its_standard_error():
    rng = np.random.default_rng(0)
    spread = np.array([1e-3, 1e-3, 2e-3, 5e-3, 5e-3, 8e-3])
    mu = np.array([2e-3, 0, 0, 0.01, 0, 0]) + rng.normal(size=(10, 6)) * spread
    u = unc.estimate(block_costs(mu), scans=10**9)  # misfit term negligible
    np.testing.assert_allclose(u.step, mu.mean(0), rtol=1e-6, atol=1e-9)
    from scipy import stats

    expected = stats.t.ppf(0.975, 9) * mu.std(0, ddof=1) / math.sqrt(10)
    np.testing.assert_allclose(u.noise95, expected, rtol=1e-6)
    assert not u.flat.any() and u.blocks == 10
    bound = np.abs(mu.mean(0)) + expected
    np.testing.assert_allclose(u.bound95, bound, rtol=1e-3)  # + misfit ≈ 0


def test_the_minimum_lies_inside_the_bound_in_95_percent_of_draws():
    """Coverage over random data: the true minimum (the μ distribution's centre) vs the bound."""
    rng = np.random.default_rng(1)
    spread = np.array([1e-3, 1e-3, 2e-3, 5e-3, 5e-3, 8e-3])
    inside = []
    for _ in range(200):
        truth = rng.normal(size=6) * spread  # where the result stands off the truth
        mu = truth + rng.normal(size=(8, 6)) * spread
        u = unc.estimate(block_costs(mu), scans=10**9)
        inside += list(np.abs(truth) <= u.bound95)
    assert 0.95 <= np.mean(inside) < 1.0  # |step| + t·σ: at least 95 %, not everything


def test_misfit_grows_with_the_cost_left_at_the_result():
    mu = np.zeros((8, 6)) + np.random.default_rng(2).normal(size=(8, 6)) * 1e-4
    small = unc.estimate(block_costs(mu, c=0.0), scans=200)
    large = unc.estimate(block_costs(mu, c=0.05), scans=200)  # 0.4 over 200 scans
    assert np.all(large.misfit > 10 * np.maximum(small.misfit, 1e-9))
    # sqrt(2 C / S · (H⁻¹)_ii): H = 8 A
    expected = np.sqrt(2 * large.cost / 200 / (8 * np.diag(STIFF)))
    np.testing.assert_allclose(large.misfit, expected, rtol=1e-6)
    # Residuals correlated over τ scans count as S / τ independent ones.
    slow = unc.estimate(block_costs(mu, c=0.05), scans=200, tau=9.0)
    np.testing.assert_allclose(slow.misfit, 3 * expected, rtol=1e-6)
    assert slow.tau == 9.0 and unc.estimate(block_costs(mu), scans=200, tau=0.3).tau == 1.0


def test_the_reference_term_is_the_shift_of_the_minimum_against_its_alternative():
    """Against the alternative every block's minimum moves by ``d``: r = 1.96 |d|, in quadrature."""
    from scipy import stats

    mu = np.random.default_rng(5).normal(size=(8, 6)) * 1e-4
    d = np.array([0, 0, 1e-3, 0.012, -0.004, 0.0])  # rad, m
    plain = unc.estimate(block_costs(mu), scans=10**9)
    u = unc.estimate(block_costs(mu), scans=10**9, alternative_costs=block_costs(mu + d))
    np.testing.assert_array_equal(plain.reference95, np.zeros(6))
    np.testing.assert_allclose(u.reference95, stats.norm.ppf(0.975) * np.abs(d), atol=1e-9)
    rest = plain.bound95 - np.abs(plain.step)
    np.testing.assert_allclose(u.bound95, np.abs(u.step) + np.hypot(rest, u.reference95))
    # the held axis stays out: no reference term on it
    held = unc.estimate(block_costs(mu), 10**9, held_axis=5, alternative_costs=block_costs(mu + d))
    assert held.reference95[5] == 0 and np.isinf(held.bound95[5])


def test_one_drive_from_a_lidar_only_reference_is_named_as_not_covered():
    """The caveat needs a held axis (planar motion), a reference term and one recording."""
    mu = np.random.default_rng(6).normal(size=(8, 6)) * 1e-4
    d = np.array([0, 0, 0, 0.004, 0.008, 0.0])
    drive = unc.estimate(block_costs(mu), 10**9, held_axis=5, alternative_costs=block_costs(mu + d))
    (caveat,) = unc.reference_caveats(drive, drives=1)
    assert "one drive" in caveat and "three drives" in caveat
    assert unc.reference_caveats(drive, drives=3) == []  # several drives average it down
    assert unc.reference_caveats(drive, 1, one_way_share=0.5) == [caveat]  # turns both ways
    (loop,) = unc.reference_caveats(drive, 1, one_way_share=0.98)
    assert loop.startswith(caveat) and "the turns all go one way (98 %" in loop
    exact = unc.estimate(block_costs(mu), 10**9, held_axis=5)  # no second reference estimate
    assert unc.reference_caveats(exact, drives=1) == []
    hand = unc.estimate(block_costs(mu), 10**9, alternative_costs=block_costs(mu + d))
    assert unc.reference_caveats(hand, drives=1) == []  # not planar: no held axis


def _ar1(phi: float, n: int, seed: int) -> np.ndarray:
    rng, x = np.random.default_rng(seed), np.zeros(n)
    for k in range(1, n):
        x[k] = phi * x[k - 1] + rng.normal()
    return x


def test_correlation_time_of_white_and_drifting_residuals():
    # c = r², r = 1 + small noise: white residuals count once, AR(1) ones (1 + φ)/(1 − φ) times.
    white = [(1 + 0.01 * np.random.default_rng(s).normal(size=400)) ** 2 for s in range(3)]
    assert 0.8 <= unc.correlation_time(white) <= 1.3
    drift = [(1 + 0.01 * _ar1(0.8, 2000, s)) ** 2 for s in range(3)]  # τ = 9
    assert 6.5 <= unc.correlation_time(drift) <= 11.5
    assert unc.correlation_time([]) == 1.0 and unc.correlation_time([np.ones(50)]) == 1.0


def test_a_flat_axis_is_named_with_what_would_fix_it():
    A = STIFF.copy()
    A[5, 5] = 0.0  # translation along LiDAR z does not change the cost
    mu = np.random.default_rng(3).normal(size=(6, 6)) * 1e-4
    u = unc.estimate(block_costs(mu, A), scans=300)
    assert u.flat.tolist() == [False] * 5 + [True] and np.isinf(u.bound95[5])
    assert np.all(np.isfinite(u.bound95[:5]))
    names = unc.undetermined(u, 0.5, 0.02, 0.005)
    assert names == [
        "translation along LiDAR z: the reward is flat along it; rotation about the LiDAR's x "
        "and y axes would determine it"
    ]
    held = unc.estimate(block_costs(mu, A), scans=300, held_axis=5)
    assert held.held == [5] and unc.undetermined(held, 0.5, 0.02, 0.005) == []
    assert np.isinf(held.bound95[5]) and np.allclose(held.bound95[:5], u.bound95[:5])
    # a tilted hold leaks a little of the held axis's moves: it is still left out of the fit
    A[5, 5], A[3, 5], A[5, 3] = 1.0, 5.0, 5.0
    leaky = unc.estimate(block_costs(mu, A), scans=300, held_axis=5)
    assert leaky.held == [5] and np.all(np.isfinite(leaky.bound95[:5]))


def test_wide_axes_are_undetermined_with_their_size():
    rng = np.random.default_rng(4)
    spread = np.array([1e-4, 1e-4, 2e-2, 1e-4, 6e-2, 1e-4])  # rot z ~1.1 deg, trans y ~6 cm
    mu = rng.normal(size=(10, 6)) * spread
    u = unc.estimate(block_costs(mu), scans=10**9)
    names = unc.undetermined(u, 0.5, 0.02, 0.005)
    assert [n.split(":")[0] for n in names] == [
        "rotation about LiDAR z",
        "translation along LiDAR y",
    ]
    assert f"±{u.rotation_deg[2]:.2f} deg at 95 % (limit 0.5)" in names[0]
    assert f"±{100 * u.translation_m[1]:.1f} cm at 95 % (limit 2)" in names[1]
    assert unc.undetermined(u, 5.0, 0.5, 0.005) == []  # looser limits: nothing named


def test_blocks_split_each_segment_and_a_short_tail_joins():
    t = np.arange(66) / 10.0  # 6.5 s at 10 Hz: 3 blocks of 2 s, then 0.5 s -> joins block 2
    b = unc.block_index(t, 2.0)
    assert b.max() == 2 and (b == 2).sum() == 26
    assert unc.block_index(np.arange(71) / 10.0, 2.0).max() == 3  # 1 s tail: a block
    assert unc.block_index(np.array([]), 2.0).size == 0
    # A 4 s gap in the scans leaves no empty block (an empty block would count as a zero
    # gradient in the noise estimate).
    gap = unc.block_index(np.r_[np.arange(40) / 10.0, 8.0 + np.arange(20) / 10.0], 2.0)
    assert np.array_equal(np.unique(gap), [0, 1, 2]) and (gap == 2).sum() == 20


@pytest.mark.parametrize("n", [6, 7])
def test_bounds_come_in_the_users_units(n):
    A = np.diag(np.append(np.diag(STIFF), 1e6))[:n, :n]
    mu = np.random.default_rng(5).normal(size=(8, n)) * 1e-3
    d = stencil(n)
    diff = d[:, None, :] - mu[None]
    u = unc.estimate(0.5 * np.einsum("pbi,ij,pbj->pb", diff, A, diff), scans=10**9)
    assert len(u.rotation_deg) == 3 and len(u.translation_m) == 3
    assert u.rotation_deg[0] == pytest.approx(math.degrees(u.bound95[0]))
    assert (u.time_offset_s is None) == (n == 6)
