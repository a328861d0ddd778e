"""Gaussian rotation baseline: the projected-normal density of the unit quaternion it hands out."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy import integrate, stats

from l2calib.errors import ConfigError
from l2calib.geometry import quat_normalize
from l2calib_policies.gaussian import ProjectedNormal, _log_j_minus_half_beta2

F64 = torch.float64
PARAMS = [
    ([0.0, 0.0, 0.0, 0.0], [1.0, 1.0, 1.0, 1.0]),
    ([0.3, -0.2, 0.1, 1.0], [0.5, 0.2, 0.3, 0.4]),
    ([0.7, 0.0, -0.7, 0.1], [0.05, 0.01, 0.02, 0.03]),
]


def _reference_log_density(u: np.ndarray, mu: np.ndarray, sig: np.ndarray) -> float:
    """log ∫₀^∞ r³ N(r u; μ, diag σ²) dr by scipy quadrature (the definition)."""
    peak = max(float(u @ (mu / sig**2)) / float(u @ (u / sig**2)), 0.0)

    def f(r: float) -> float:
        return r**3 * float(np.prod(stats.norm.pdf(r * u, mu, sig)))

    val = sum(
        integrate.quad(f, a, b, epsabs=0, epsrel=1e-12, limit=400)[0]
        for a, b in ((0, peak), (peak, peak + 50 * sig.max()), (peak + 50 * sig.max(), np.inf))
    )
    return math.log(val)


@pytest.mark.parametrize("mu,sig", PARAMS)
def test_log_prob_is_the_projected_normal_density(mu, sig):
    d = ProjectedNormal(torch.tensor(mu, dtype=F64), torch.tensor(sig, dtype=F64))
    gen = torch.Generator().manual_seed(0)
    points = [quat_normalize(torch.randn(4, dtype=F64, generator=gen)) for _ in range(4)]
    if any(mu):
        points += [d.mode, -d.mode]  # the density's peak and its far tail (β ≪ 0)
    for u in points:
        ref = _reference_log_density(u.numpy(), np.array(mu), np.array(sig))
        assert d.log_prob(u).item() == pytest.approx(ref, abs=1e-7 * max(1.0, abs(ref)))


def test_uniform_when_mean_is_zero():
    d = ProjectedNormal(torch.zeros(4, dtype=F64), torch.ones(4, dtype=F64))
    u = quat_normalize(torch.randn(10, 4, dtype=F64))
    assert torch.allclose(d.log_prob(u), torch.full((10,), -math.log(2 * math.pi**2)))


def test_samples_are_consistent_with_density():
    """E_p[1/p(q)] = area(S³) = 2π² holds only if samples and density agree."""
    torch.manual_seed(1)
    d = ProjectedNormal(
        torch.tensor(PARAMS[1][0], dtype=F64), torch.tensor(PARAMS[1][1], dtype=F64)
    )
    q = d.sample((400_000,))
    assert torch.allclose(q.norm(dim=-1), torch.ones(1, dtype=F64), atol=1e-12)
    inv = torch.exp(-d.log_prob(q)) / (2 * math.pi**2)
    assert abs(inv.mean() - 1) < 4 * inv.std() / math.sqrt(inv.numel())


@pytest.mark.parametrize("beta", [-60.0, -20.0, -15.001, -14.999, -7.0, -1e-9, 1e-9, 2.5, 35.0])
def test_log_j_matches_quadrature_on_every_branch(beta):
    peak = max(beta, 0.0) + 3.0 / max(abs(beta), 1.0)

    shift = 0.5 * beta**2 if beta > 0 else 0.0  # keep the integrand representable

    def f(r: float) -> float:  # ρ³ exp(-ρ²/2 + βρ - shift)
        return r**3 * math.exp(-0.5 * r * r + beta * r - shift)

    ref = sum(
        integrate.quad(f, a, b, epsabs=0, epsrel=1e-13, limit=400)[0]
        for a, b in ((0, peak), (peak, peak + 40), (peak + 40, np.inf))
    )
    ref_log = math.log(ref) + shift - 0.5 * beta**2
    ours = _log_j_minus_half_beta2(torch.tensor(beta, dtype=F64)).item()
    assert ours == pytest.approx(ref_log, abs=1e-9)


def test_entropy_estimate_and_gradients():
    torch.manual_seed(2)
    loc = torch.tensor(PARAMS[1][0], dtype=F64, requires_grad=True)
    scale = torch.tensor(PARAMS[1][1], dtype=F64, requires_grad=True)
    d = ProjectedNormal(loc, scale)
    lp = d.log_prob(d.sample((200_000,)))
    assert d.entropy().item() == pytest.approx(-lp.mean().item(), abs=0.05)
    d.entropy().backward()
    assert torch.isfinite(loc.grad).all() and torch.isfinite(scale.grad).all()
    # Shared (broadcast) parameters give the same estimate as the unshared computation.
    shared = ProjectedNormal(loc.detach().expand(3, 4), scale.detach().expand(3, 4))
    unshared = ProjectedNormal(loc.detach().repeat(3, 1), scale.detach().repeat(3, 1))
    assert torch.allclose(shared.entropy(), unshared.entropy(), rtol=1e-12)


def test_rotation_sigma_readout_small_angle():
    sig = 0.01
    d = ProjectedNormal(torch.tensor([0, 0, 0, 1.0], dtype=F64), torch.full((4,), sig, dtype=F64))
    # φ = 2 δq: σ_φ = 2σ per axis.
    assert torch.allclose(d.rotation_sigma_rad(), torch.full((3,), 2 * sig, dtype=F64), rtol=0.03)


def test_bad_shape_is_a_config_error():
    with pytest.raises(ConfigError, match="shape"):
        ProjectedNormal(torch.zeros(3, dtype=F64), torch.ones(3, dtype=F64))
