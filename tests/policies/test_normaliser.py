"""Exact Bingham normaliser: against scipy quadrature, closed forms, Monte Carlo, asymptotics."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import torch
from scipy import integrate, special

from l2calib.errors import ConfigError
from l2calib_policies.normaliser import (
    LOG_AREA_S3,
    bingham_entropy,
    bingham_log_normaliser,
    bingham_second_moments,
)

GRID = [0.0, -1e-3, -0.1, -1.0, -10.0, -100.0, -1e3, -1e4, -1e5]


def scipy_log_normaliser(z: tuple[float, float, float]) -> float:
    """Reference: scipy's adaptive QUADPACK on the Hopf-coordinate integral, split at 10^-k."""
    z1, z2, z3 = sorted(z)
    b1, b2 = (z1 - z2) / 2, z3 / 2

    def f(t: float) -> float:
        return math.exp(z2 * t) * special.i0e(b1 * t) * special.i0e(b2 * (1 - t))

    cuts = sorted(
        {0.0, 1.0, *(10.0**k for k in range(-12, 0)), *(1 - 10.0**k for k in range(-12, 0))}
    )
    total = sum(
        integrate.quad(f, a, b, epsabs=0, epsrel=1e-13, limit=200)[0]
        for a, b in zip(cuts[:-1], cuts[1:], strict=True)
    )
    return math.log(2 * math.pi**2 * total)


def test_matches_scipy_adaptive_quadrature_on_grid_with_ties_and_zero():
    zs = list(itertools.combinations_with_replacement(GRID, 3))  # includes ties and z = 0
    ours = bingham_log_normaliser(torch.tensor(zs, dtype=torch.float64)).numpy()
    ref = np.array([scipy_log_normaliser(z) for z in zs])
    rel = np.abs(np.expm1(ours - ref))
    assert rel.max() < 1e-6, (rel.max(), zs[int(rel.argmax())])


def test_matches_scipy_on_random_concentrations(rng):
    z = -(10.0 ** rng.uniform(-4, 5, size=(60, 3)))
    ours = bingham_log_normaliser(torch.tensor(z)).numpy()
    ref = np.array([scipy_log_normaliser(tuple(r)) for r in z])
    assert np.abs(np.expm1(ours - ref)).max() < 1e-6


def test_uniform_is_area_of_s3():
    ln = bingham_log_normaliser(torch.zeros(3, dtype=torch.float64))
    assert ln.item() == pytest.approx(math.log(2 * math.pi**2), rel=1e-14)
    assert LOG_AREA_S3 == pytest.approx(math.log(2 * math.pi**2))


@pytest.mark.parametrize("z", [-0.5, -3.0, -30.0, -300.0, -3e4])
def test_single_concentration_is_confluent_hypergeometric(z):
    # With one non-zero entry, N = 2π² 1F1(1/2; 2; z) (independent closed form).
    ours = bingham_log_normaliser(torch.tensor([0.0, z, 0.0], dtype=torch.float64)).exp().item()
    assert ours / (2 * math.pi**2) == pytest.approx(special.hyp1f1(0.5, 2.0, z), rel=1e-9)


def test_large_concentrations_match_laplace_asymptotics():
    # N ≈ 2 π^{3/2} / sqrt(|z1 z2 z3|) (two antipodal Gaussian peaks), relative error O(1/|z|).
    z = torch.tensor([-1e5, -3e5, -2e5], dtype=torch.float64)
    laplace = math.log(2 * math.pi**1.5 / math.sqrt(abs(z.prod().item())))
    assert bingham_log_normaliser(z).item() == pytest.approx(laplace, abs=1e-4)


def test_monte_carlo_over_uniform_sphere():
    gen = torch.Generator().manual_seed(0)
    x = torch.nn.functional.normalize(torch.randn(2_000_000, 4, generator=gen), dim=-1)
    z = torch.tensor([-1.0, -2.5, -6.0], dtype=torch.float64)
    vals = torch.exp((z * x[:, :3] ** 2).sum(-1))
    mc = 2 * math.pi**2 * vals.mean()
    se = 2 * math.pi**2 * vals.std() / math.sqrt(len(vals))
    assert abs(bingham_log_normaliser(z).exp() - mc) < 4 * se


def test_symmetric_in_the_order_of_z():
    z = torch.tensor([-3.0, -70.0, -0.2], dtype=torch.float64)
    vals = [bingham_log_normaliser(z[list(p)]) for p in itertools.permutations(range(3))]
    assert torch.allclose(torch.stack(vals), vals[0], rtol=0, atol=1e-13)


def test_gradients_match_finite_differences():
    for z0 in ([-0.3, -2.0, -15.0], [-1e3, -1e3, -5.0], [0.0, -40.0, -40.0], [-2e4, -1.0, -3e2]):
        z = torch.tensor(z0, dtype=torch.float64, requires_grad=True)
        # Relative FD step: concentrations span 1e0..1e5.
        eps = 1e-6 * max(1.0, max(abs(v) for v in z0))
        assert torch.autograd.gradcheck(bingham_log_normaliser, (z,), eps=eps, atol=1e-7)


def test_closed_form_moments_equal_autograd_gradient_and_are_differentiable():
    z = torch.tensor(
        [[-0.5, -8.0, -100.0], [0.0, 0.0, 0.0], [-1e5, -2.0, -2.0]],
        dtype=torch.float64,
        requires_grad=True,
    )
    (grad,) = torch.autograd.grad(bingham_log_normaliser(z).sum(), z)
    moments = bingham_second_moments(z)
    assert torch.allclose(moments, grad, rtol=1e-9, atol=1e-14)
    assert torch.allclose(moments[1], torch.full((3,), 0.25, dtype=torch.float64))
    assert torch.autograd.gradcheck(bingham_second_moments, (z[:1].detach().requires_grad_(),))


def test_entropy_of_uniform_and_monotone_in_concentration():
    h0 = bingham_entropy(torch.zeros(3, dtype=torch.float64))
    assert h0.item() == pytest.approx(LOG_AREA_S3, rel=1e-12)
    hs = bingham_entropy(torch.tensor([[-1.0] * 3, [-10.0] * 3, [-100.0] * 3], dtype=torch.float64))
    assert bool((hs.diff() < 0).all()) and bool((hs < h0).all())


def test_bad_shape_is_a_config_error():
    with pytest.raises(ConfigError, match=r"shape \[\.\.\., 3\]"):
        bingham_log_normaliser(torch.zeros(4, dtype=torch.float64))
