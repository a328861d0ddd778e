"""Gaussian rotation baseline (the paper's L2Calib-g) as an honest distribution on S³.

L2Calib-g draws a 4-vector ``w ~ N(μ, diag(σ²))`` and uses ``q = w/|w|`` as the rotation. The
paper's public code scores the *unnormalised* ``w`` with the R⁴ Gaussian density (and hands
``w`` itself to the odometry). Here the action is always the unit quaternion ``q``, and
:meth:`ProjectedNormal.log_prob` is the exact density of ``q`` on S³ w.r.t. the surface measure
(the *projected normal* / angular Gaussian with offset), so it is on the same footing as the
Bingham ``log_prob``::

    p(u) = ∫₀^∞ r³ N(r u; μ, Σ) dr
         = (2π)^-2 |Σ|^-1/2 A^-2 exp(-C/2) J(β),     A = uᵀΣ⁻¹u, B = uᵀΣ⁻¹μ, C = μᵀΣ⁻¹μ,
    J(β) = ∫₀^∞ ρ³ exp(-ρ²/2 + βρ) dρ = √(2π) e^{β²/2} Φ(β) (β³ + 3β) + β² + 2,   β = B/√A.

Unlike the Bingham it is *not* antipodally symmetric: ``p(q) ≠ p(-q)``; the density of the
rotation on SO(3) would be ``p(q) + p(-q)``. We score the sampled ``q`` itself, which is what
the PPO ratio needs. Its entropy has no closed form; :meth:`ProjectedNormal.entropy` is a
Monte-Carlo estimate with fixed common random numbers (smooth and differentiable in μ, σ).
torch/pyro provide the projected normal only for isotropic σ without this density, hence
this module.
"""

from __future__ import annotations

import math
from functools import lru_cache

import torch
from torch import Tensor
from torch.distributions import Distribution

from l2calib.errors import ConfigError
from l2calib.geometry import quat_conjugate, quat_multiply, quat_normalize
from l2calib_policies.bingham import unit_quaternion

_LOG_2PI = math.log(2 * math.pi)
_SQRT_2PI = math.sqrt(2 * math.pi)
_BETA_SERIES = -15.0  # below: asymptotic series (the closed form cancels catastrophically)
ENTROPY_SAMPLES = 1024
_SERIES_COEFS = [(-0.5) ** k * math.factorial(3 + 2 * k) / math.factorial(k) for k in range(12)][
    ::-1
]


@lru_cache(maxsize=4)
def _entropy_noise(device: str) -> Tensor:
    gen = torch.Generator(device=device).manual_seed(20250801)
    return torch.randn(ENTROPY_SAMPLES, 4, dtype=torch.float64, device=device, generator=gen)


def _log_j_minus_half_beta2(beta: Tensor) -> Tensor:
    """``log J(β) - β²/2`` for the projected normal on S³ (stable for all β)."""
    # β >= 0: log(√(2π) Φ(β)(β³+3β) + (β²+2) e^{-β²/2}); no overflow, no cancellation.
    bp = beta.clamp_min(0.0)
    pos = torch.log(
        _SQRT_2PI * torch.special.ndtr(bp) * (bp**3 + 3 * bp)
        + (bp**2 + 2) * torch.exp(-0.5 * bp**2)
    )
    # -15 <= β < 0: √(2π) e^{β²/2} Φ(β) = √(π/2) erfcx(-β/√2); mild cancellation (≲ 1e-9 rel).
    bm = beta.clamp(_BETA_SERIES, 0.0)
    mid_j = math.sqrt(math.pi / 2) * torch.special.erfcx(-bm / math.sqrt(2)) * (bm**3 + 3 * bm)
    mid = torch.log(mid_j + bm**2 + 2) - 0.5 * bm**2
    # β < -15: J = Σ_k (-1/2)^k (3+2k)! / (k! x^{4+2k}), x = -β (terms shrink by ≤ 2k/x²).
    x = (-beta).clamp_min(-_BETA_SERIES)
    inv_x2 = 1.0 / (x * x)
    series = torch.zeros_like(x)
    for coef in _SERIES_COEFS:  # Horner in 1/x²
        series = series * inv_x2 + coef
    low = torch.log(series * inv_x2 * inv_x2) - 0.5 * x * x
    return torch.where(beta >= 0, pos, torch.where(beta >= _BETA_SERIES, mid, low))


class ProjectedNormal(Distribution):
    """Distribution of ``q = w/|w|`` for ``w ~ N(loc, diag(scale²))`` in R⁴, on S³.

    Args:
        loc: Mean ``μ`` ``[..., 4]`` of the 4-D Gaussian (xyzw order, need not be unit).
        scale: Standard deviations ``σ`` ``[..., 4]`` (> 0).
        validate_args: As in :class:`torch.distributions.Distribution`.
    """

    arg_constraints: dict = {}
    support = unit_quaternion
    has_rsample = True

    def __init__(self, loc: Tensor, scale: Tensor, validate_args: bool | None = None) -> None:
        if loc.shape[-1:] != (4,) or scale.shape[-1:] != (4,):
            raise ConfigError(
                f"ProjectedNormal needs loc and scale of shape [..., 4], got "
                f"{tuple(loc.shape)} and {tuple(scale.shape)}",
                fix="pass a 4-D mean and 4 standard deviations",
            )
        batch = torch.broadcast_shapes(loc.shape[:-1], scale.shape[:-1])
        self.loc = loc.to(torch.float64).expand(*batch, 4)
        self.scale = scale.to(torch.float64).expand(*batch, 4)
        super().__init__(batch, torch.Size([4]), validate_args=validate_args)

    def expand(self, batch_shape: torch.Size, _instance=None) -> ProjectedNormal:
        """Broadcasts the parameters to ``batch_shape``."""
        shape = torch.Size(batch_shape)
        return ProjectedNormal(self.loc.expand(*shape, 4), self.scale.expand(*shape, 4), False)

    def rsample(self, sample_shape: torch.Size | tuple[int, ...] = ()) -> Tensor:
        """Reparameterised unit quaternions ``[*sample_shape, *batch, 4]``."""
        shape = self._extended_shape(torch.Size(sample_shape))
        eps = torch.randn(shape, dtype=torch.float64, device=self.loc.device)
        return quat_normalize(self.loc + self.scale * eps)

    def log_prob(self, value: Tensor) -> Tensor:
        """Exact log-density ``[sample, batch]`` of unit quaternions on S³ (not antipodal)."""
        if self._validate_args:
            self._validate_sample(value)
        u = value.to(torch.float64)
        inv_var = self.scale ** (-2)
        a = (u * u * inv_var).sum(-1)
        b = (u * self.loc * inv_var).sum(-1)
        # C - β² = (C·A - B²)/A by Lagrange's identity: no cancellation for concentrated laws.
        um = u[..., :, None] * self.loc[..., None, :]
        cross = (um - um.transpose(-1, -2)) ** 2 * (inv_var[..., :, None] * inv_var[..., None, :])
        d = 0.5 * cross.sum((-1, -2)) / a  # sum over i < j, counted twice
        beta = b / a.sqrt()
        log_norm = -2 * _LOG_2PI - self.scale.log().sum(-1)
        return log_norm - 0.5 * d - 2 * a.log() + _log_j_minus_half_beta2(beta)

    def entropy(self) -> Tensor:
        """Monte-Carlo entropy ``[batch]`` with 1024 fixed common random numbers (nats).

        When the parameters are one row broadcast over the batch (stride 0, as the actor
        produces them), the estimate is computed once and expanded.
        """
        nb = len(self.batch_shape)
        shared = all(
            t.stride()[i] == 0 or t.shape[i] == 1 for t in (self.loc, self.scale) for i in range(nb)
        )
        loc, scale = (
            (self.loc[(0,) * nb], self.scale[(0,) * nb]) if shared else (self.loc, self.scale)
        )
        eps = _entropy_noise(str(loc.device)).reshape(ENTROPY_SAMPLES, *[1] * (loc.dim() - 1), 4)
        q = quat_normalize(loc + scale * eps)
        h = -ProjectedNormal(loc, scale, validate_args=False).log_prob(q).mean(0)
        return h.expand(self.batch_shape) if shared else h

    @property
    def mode(self) -> Tensor:
        """``μ/|μ|`` ``[batch, 4]``: the deterministic action of L2Calib-g.

        The density's maximum coincides with it for isotropic σ and lies close to it otherwise.
        """
        return quat_normalize(self.loc)

    @property
    def deterministic_sample(self) -> Tensor:
        """What TorchRL returns in deterministic mode: ``μ/|μ|``."""
        return self.mode

    def rotation_sigma_rad(self, samples: int = 8192) -> Tensor:
        """Per-body-axis rotation spread ``2·sqrt(E[y_i²])`` ``[batch, 3]`` (rad), ``y = q̂0* ⊗ q``.

        The same statistic as :meth:`Bingham.rotation_sigma_rad` (about the body axes of
        ``q̂0 = μ/|μ|``; ≈ the small-angle σ when concentrated, 1 rad when uniform), estimated
        from ``samples`` fixed common random numbers (≈ 1 % relative error at 8192).
        """
        gen = torch.Generator(device=self.loc.device).manual_seed(7)
        eps = torch.randn(
            samples,
            *self.batch_shape,
            4,
            dtype=torch.float64,
            device=self.loc.device,
            generator=gen,
        )
        q = quat_normalize(self.loc + self.scale * eps)
        y = quat_multiply(quat_conjugate(self.mode), q)
        return 2 * (y[..., :3] ** 2).mean(0).sqrt()
