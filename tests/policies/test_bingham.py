"""Bingham distribution: sampler against the exact density, entropy, symmetry, body axes."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy import integrate, special, stats

from l2calib.errors import ConfigError
from l2calib.geometry import quat_normalize, quat_to_matrix, so3_log
from l2calib_policies.bingham import Bingham, acg_envelope_b, concentration_from_sigma

F64 = torch.float64
CASES = [
    (0.0, 0.0, 0.0),
    (-1.0, -5.0, -20.0),
    (-100.0, -100.0, -1e4),
    (-1e5, -3.0, 0.0),
    (-2e3, -50.0, -0.5),
    (40.0, -3.0, 0.0),  # positive entries: the mode moves to q0 ⊗ i
    (300.0, 280.0, 310.0),
]


def _random_mode(seed: int) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    return quat_normalize(torch.randn(4, dtype=F64, generator=gen))


def _pair_cdf(z: tuple[float, float, float], pair: tuple[int, int], t_sorted: np.ndarray):
    """CDF of t = y_i² + y_j² under Bingham(z) (exact 1-D marginal from the Hopf integral)."""
    k = ({0, 1, 2} - set(pair)).pop()
    zi, zj, zk = z[pair[0]], z[pair[1]], z[k]
    a1, b1, a2, b2 = (zi + zj) / 2, (zi - zj) / 2, zk / 2, zk / 2

    def g(t: float) -> float:  # integrand scaled so that it is ≤ 1
        s = 1 - t
        log = a1 * t + abs(b1 * t) + a2 * s + abs(b2 * s) - max(zi, zj, zk, 0.0)
        return math.exp(log) * special.i0e(b1 * t) * special.i0e(b2 * s)

    pts = np.concatenate([[0.0], t_sorted, [1.0]])
    pieces = np.array(
        [
            integrate.quad(g, a, b, epsabs=0, epsrel=1e-10)[0]
            for a, b in zip(pts[:-1], pts[1:], strict=True)
        ]
    )
    cum = np.cumsum(pieces)
    return cum[:-1] / cum[-1]


@pytest.mark.parametrize("z", CASES)
def test_sample_second_moments_match_normaliser_gradient(z):
    torch.manual_seed(1)
    d = Bingham(_random_mode(0), torch.tensor(z, dtype=F64))
    y = d.body_coordinates(d.sample((120_000,)))
    empirical = (y[:, :3] ** 2).mean(0)
    zt = torch.tensor(z, dtype=F64, requires_grad=True)
    (grad,) = torch.autograd.grad(Bingham(_random_mode(0), zt).log_normaliser(), zt)
    assert torch.allclose(empirical, grad, rtol=0.02, atol=0), (empirical, grad)
    assert torch.allclose(d.second_moments(), grad, rtol=1e-9)


@pytest.mark.parametrize("z", CASES)
def test_goodness_of_fit_of_exact_marginals(z):
    """KS test of t = y_i² + y_j² against its exact CDF, for the three pairings of axes."""
    torch.manual_seed(2)
    d = Bingham(_random_mode(1), torch.tensor(z, dtype=F64))
    y = d.body_coordinates(d.sample((6000,))).numpy()
    for pair in ((0, 1), (0, 2), (1, 2)):
        t = np.sort(y[:, pair[0]] ** 2 + y[:, pair[1]] ** 2)
        pit = _pair_cdf(z, pair, t)
        p = stats.kstest(pit, "uniform").pvalue
        assert p > 1e-3, (z, pair, p)


def test_goodness_of_fit_test_has_power():
    # Samples from z, CDF of a distribution with 15 % different concentrations: must reject.
    torch.manual_seed(3)
    z = (-40.0, -200.0, -5.0)
    y = Bingham(_random_mode(2), torch.tensor(z, dtype=F64)).sample((6000,))
    y = Bingham(_random_mode(2), torch.tensor(z, dtype=F64)).body_coordinates(y).numpy()
    t = np.sort(y[:, 0] ** 2 + y[:, 1] ** 2)
    wrong = tuple(1.15 * v for v in z)
    assert stats.kstest(_pair_cdf(wrong, (0, 1), t), "uniform").pvalue < 1e-6


@pytest.mark.parametrize("z", CASES[1:])
def test_entropy_matches_monte_carlo(z):
    torch.manual_seed(4)
    d = Bingham(_random_mode(3), torch.tensor(z, dtype=F64))
    lp = d.log_prob(d.sample((100_000,)))
    se = lp.std() / math.sqrt(lp.numel())
    assert abs(d.entropy() + lp.mean()) < 4 * se + 1e-9


def test_density_is_normalised_over_the_sphere():
    gen = torch.Generator().manual_seed(5)
    u = quat_normalize(torch.randn(1_000_000, 4, dtype=F64, generator=gen))
    d = Bingham(_random_mode(4), torch.tensor([-2.0, -0.5, -8.0], dtype=F64))
    p = d.log_prob(u).exp() * 2 * math.pi**2
    assert abs(p.mean() - 1) < 4 * p.std() / math.sqrt(p.numel())


def test_antipodal_symmetry():
    torch.manual_seed(6)
    d = Bingham(_random_mode(5), torch.tensor([-30.0, -4.0, -0.5], dtype=F64))
    x = d.sample((20_000,))
    assert torch.allclose(d.log_prob(x), d.log_prob(-x), rtol=0, atol=1e-12)
    # The sampler itself is symmetric: both hemispheres around the mode are hit equally.
    frac = (d.body_coordinates(x)[:, 3] > 0).double().mean().item()
    assert abs(frac - 0.5) < 4 * math.sqrt(0.25 / 20_000)


def test_concentrations_act_on_body_axes():
    """R = R0 Exp(φ): φ (body/LiDAR axes) has σ_i = sqrt(2/|z_i|) for concentrated axes."""
    torch.manual_seed(7)
    q0 = _random_mode(6)
    sig = torch.tensor([0.005, 0.05, 0.02], dtype=F64)
    d = Bingham(q0, concentration_from_sigma(sig))
    R = quat_to_matrix(d.sample((100_000,)))
    phi = so3_log(quat_to_matrix(q0).T @ R)
    assert torch.allclose(phi.std(0), sig, rtol=0.03)
    assert torch.allclose(d.rotation_sigma_rad(), sig, rtol=0.02)
    assert torch.allclose(phi.mean(0), torch.zeros(3, dtype=F64), atol=3e-3 * sig.max())


def test_positive_concentrations_move_the_mode_to_a_body_axis():
    torch.manual_seed(10)
    q0 = _random_mode(11)
    z = torch.tensor([-5.0, 3000.0, 2500.0], dtype=F64)  # largest entry: body y
    d = Bingham(q0, z)
    j = torch.tensor([0.0, 1.0, 0.0, 0.0], dtype=F64)
    from l2calib.geometry import quat_canonical, quat_multiply

    assert torch.allclose(d.mode, quat_canonical(quat_multiply(q0, j)), atol=1e-12)
    # Same law as the canonical form (z - 3000 on the shifted axes, about the new mode).
    x = d.sample((100_000,))
    phi = so3_log(quat_to_matrix(d.mode).T @ quat_to_matrix(x))
    assert torch.allclose(phi.std(0), d.rotation_sigma_rad(), rtol=0.03)
    # y' = j* ⊗ y = (-y_z, -y_w, y_x, y_y): the mode's x, y, z axes carry the entries of body
    # z, w, x, i.e. effective concentrations 2500 - 3000, 0 - 3000, -5 - 3000.
    expected = torch.tensor([500.0, 3000.0, 3005.0], dtype=F64)
    assert torch.allclose(d.rotation_sigma_rad(), (2 / expected).sqrt(), rtol=0.01)


def test_batched_parameters_are_used_per_element():
    torch.manual_seed(8)
    z = torch.tensor([[-1.0, -10.0, -100.0], [-500.0, -0.0, -5.0]], dtype=F64)
    q0 = torch.stack([_random_mode(7), _random_mode(8)])
    d = Bingham(q0, z)
    x = d.sample((100_000,))
    assert x.shape == (100_000, 2, 4)
    assert torch.allclose(x.norm(dim=-1), torch.ones(1, dtype=F64), atol=1e-12)
    m = (d.body_coordinates(x)[..., :3] ** 2).mean(0)
    assert torch.allclose(m, d.second_moments(), rtol=0.02)
    assert d.log_prob(x).shape == (100_000, 2)


@pytest.mark.parametrize("z", CASES)
def test_acceptance_rate_and_envelope(z):
    torch.manual_seed(9)
    d = Bingham(_random_mode(9), torch.tensor(z, dtype=F64))
    d.sample((20_000,))
    assert 0.4 < d.last_acceptance_rate <= 1.0
    if z == (0.0, 0.0, 0.0):
        assert d.last_acceptance_rate == 1.0
    d = torch.tensor([*z, 0.0], dtype=F64)
    lam = d.max() - d
    b = acg_envelope_b(lam)
    assert (1 / (b + 2 * lam)).sum() == pytest.approx(1.0, abs=1e-12)


def test_mode_and_deterministic_sample():
    q0 = _random_mode(10)
    d = Bingham(-q0 * 3, torch.tensor([-1.0, -2.0, -3.0], dtype=F64))
    assert d.mode[3] >= 0
    assert torch.allclose(d.mode.abs(), q0.abs(), atol=1e-12)
    assert torch.equal(d.deterministic_sample, d.mode)


def test_invalid_parameters_are_config_errors():
    with pytest.raises(ConfigError, match="must be finite"):
        Bingham(_random_mode(0), torch.tensor([float("nan"), -1.0, -1.0], dtype=F64))
    with pytest.raises(ConfigError, match=r"quaternion \[\.\.\., 4\]"):
        Bingham(torch.ones(3, dtype=F64), torch.zeros(3, dtype=F64))
    # torchrl turns torch's default argument validation off on import; ask for it explicitly.
    d = Bingham(_random_mode(0), torch.zeros(3, dtype=F64), validate_args=True)
    with pytest.raises(ValueError, match="support"):
        d.log_prob(torch.ones(4, dtype=F64))
