"""Bingham distribution on the unit quaternions S³ (exact normaliser, exact rejection sampler).

Parameterisation (as in the L2Calib paper, with the axes tied to the body frame): a reference
quaternion ``q0`` (xyzw, Hamilton; the mode) and three concentrations ``z = (z1, z2, z3) ≤ 0``,
with ``M = [q0⊗i, q0⊗j, q0⊗k, q0]`` and ``Z = diag(z1, z2, z3, 0)``. Writing ``y = q0* ⊗ x`` (the
right-perturbation of the mode, ``x = q0 ⊗ y``), the density is::

    p(x) = exp(z1 y_x² + z2 y_y² + z3 y_z²) / N(Z)      (w.r.t. the surface measure of S³)

so ``zi`` controls rotations about body axis ``i`` of the rotated frame (for
``R_imu_lidar = R(q0) Exp(φ)``, φ in LiDAR axes): near the mode ``y ≈ (φ/2, 1)`` and
``σ(φi) ≈ sqrt(2/|zi|)`` rad. ``p(x) = p(-x)``. Positive ``zi`` are accepted as well (the
density depends only on differences of ``(z1, z2, z3, 0)``); the mode is then ``q0 ⊗ e_i`` —
this lets a policy move its mode by 180° about a body axis without crossing a region of zero
gradient (see :mod:`l2calib_policies.actors`).

Sampling follows Kent, Ganeiber & Mardia (2013), "A new method to simulate the Bingham and
related distributions in directional data analysis with applications", arXiv:1310.8110: an
angular central Gaussian (ACG) proposal with ``Ω = I + 2A/b``, ``A = max(d) - diag(d)`` for
``d = (z1, z2, z3, 0)`` and ``b`` solving ``Σ 1/(b + 2λi) = 1`` over the four eigenvalues, envelope
``M* = exp(-(q-b)/2) (q/b)^{q/2}`` with ``q = 4``. Every sample is an accepted one: the loop runs
until all are accepted (acceptance is ≥ ~45 % for any z, so it ends after a few rounds).
No maintained PyTorch implementation of this sampler or of the exact normaliser exists (pyro and
torch.distributions have no Bingham), hence this module.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor
from torch.distributions import Distribution, constraints

from l2calib.errors import ConfigError, TrainingError
from l2calib.geometry import quat_canonical, quat_conjugate, quat_multiply, quat_normalize
from l2calib_policies.normaliser import (
    bingham_entropy,
    bingham_log_normaliser,
    bingham_second_moments,
)

_MAX_ROUNDS = 10_000  # a sampler invariant guard: rounds needed are ~log(n)/log(1/0.55) ≈ 25


class _UnitQuaternion(constraints.Constraint):
    """Unit 4-vectors (event_dim 1), with a float64 tolerance."""

    event_dim = 1

    def check(self, value: Tensor) -> Tensor:
        return (value.shape[-1] == 4) & ((value.norm(dim=-1) - 1).abs() < 1e-6)


unit_quaternion = _UnitQuaternion()


def acg_envelope_b(lam4: Tensor, iters: int = 40) -> Tensor:
    """Solves ``Σ_{i=1..4} 1/(b + 2λi) = 1`` for ``b ∈ [1, 4]``, batched.

    Args:
        lam4: Eigenvalues ``λ = max(d) - d ≥ 0`` of ``A`` ``[..., 4]`` (one of them 0), float64.
        iters: Newton iterations. ``g(b)`` is convex and decreasing, so Newton from ``b = 1``
            (where ``g ≥ 0``) increases monotonically to the root; 40 steps reach float64
            precision for any λ ≥ 0.

    Returns:
        ``b`` ``[...]``.
    """
    b = torch.ones_like(lam4[..., 0])
    for _ in range(iters):
        inv = 1.0 / (b[..., None] + 2 * lam4)
        g = inv.sum(-1) - 1
        dg = -(inv * inv).sum(-1)
        b = (b - g / dg).clamp(1.0, 4.0)
    return b


def sample_bingham_body(
    z: Tensor, generator: torch.Generator | None = None
) -> tuple[Tensor, float]:
    """Draws one body-frame sample ``y`` per row of ``z`` with the ACG rejection sampler.

    Args:
        z: Concentrations ``[n, 3]`` (float64, finite, any sign), one row per wanted sample.
        generator: Optional torch generator (default: the global RNG).

    Returns:
        Unit quaternions ``y`` ``[n, 4]`` (xyzw) distributed as ``exp(Σ zi yi²) / N(z)``, and the
        acceptance rate (accepted / proposed) of this call.
    """
    n = z.shape[0]
    d = torch.cat([z, torch.zeros_like(z[:, :1])], dim=-1)
    lam = d.max(dim=-1, keepdim=True).values - d  # A = diag(λ) ≥ 0, one λ = 0
    b = acg_envelope_b(lam)
    omega = 1 + 2 * lam / b[:, None]  # [n, 4]
    inv_sqrt_omega = omega.rsqrt()
    log_m_star = -(4 - b) / 2 + 2 * torch.log(4 / b)  # log of the envelope constant M*
    out = torch.empty(n, 4, dtype=z.dtype, device=z.device)
    pending = torch.arange(n, device=z.device)
    proposed = 0
    for _ in range(_MAX_ROUNDS):
        m = pending.numel()
        if m == 0:
            return out, n / max(proposed, 1)
        proposed += m
        w = torch.randn(m, 4, dtype=z.dtype, device=z.device, generator=generator)
        w = w * inv_sqrt_omega[pending]
        y = w / w.norm(dim=-1, keepdim=True)
        y2 = y * y
        log_bingham = -(lam[pending] * y2).sum(-1)
        log_acg = -2 * torch.log((omega[pending] * y2).sum(-1))
        log_u = torch.log(torch.rand(m, dtype=z.dtype, device=z.device, generator=generator))
        accept = log_u < log_bingham - log_acg - log_m_star[pending]
        out[pending[accept]] = y[accept]
        pending = pending[~accept]
    raise TrainingError(  # pragma: no cover - would need an acceptance rate < 1e-3
        f"Bingham sampler did not finish within {_MAX_ROUNDS} rounds",
        fix="report this as a bug with the concentrations used",
    )


def _axis_permutations() -> Tensor:
    """Axis permutations ``P[k, i]`` between the frames of ``q0`` and of ``q0 ⊗ e_k``.

    For the mode ``q0 ⊗ e_k`` (k = x, y, z, w), ``P[k, i]`` is the coordinate of ``y = q0* ⊗ x``
    whose square is the ``i``-th squared coordinate of ``y' = (q0 ⊗ e_k)* ⊗ x``.
    """
    eye = torch.eye(4, dtype=torch.float64)
    table = torch.empty(4, 4, dtype=torch.long)
    for k in range(4):
        images = quat_multiply(quat_conjugate(eye[k]).expand(4, 4), eye)  # e_k* ⊗ e_j = ±e_π(j)
        table[k, images.abs().argmax(-1)] = torch.arange(4)
    return table


_AXIS_PERMUTATIONS = _axis_permutations()


class Bingham(Distribution):
    """Bingham distribution on S³ with body-axis concentrations.

    Args:
        quat_xyzw: Reference quaternion ``q0`` ``[..., 4]`` (normalised here; gradients flow
            through); the mode when ``z ≤ 0``.
        concentration: ``z`` ``[..., 3]``, float64, finite. ``z ≤ 0`` is the canonical form
            (mode ``q0``; 0 on every axis is the uniform distribution). Positive entries are
            legal: only differences of ``(z1, z2, z3, 0)`` matter, and the mode is then
            ``q0 ⊗ e_k`` for the largest entry ``k`` (see :attr:`mode`).
        validate_args: As in :class:`torch.distributions.Distribution`.

    Events are unit quaternions ``[..., 4]`` (xyzw). ``log_prob`` is w.r.t. the surface measure
    of S³ (area 2π²), so it is directly comparable with the Gaussian baseline's.
    """

    arg_constraints: dict = {}  # checked by hand below (finite z)
    support = unit_quaternion
    has_rsample = False

    def __init__(
        self, quat_xyzw: Tensor, concentration: Tensor, validate_args: bool | None = None
    ) -> None:
        if quat_xyzw.shape[-1:] != (4,) or concentration.shape[-1:] != (3,):
            raise ConfigError(
                f"Bingham needs a quaternion [..., 4] and concentrations [..., 3], got "
                f"{tuple(quat_xyzw.shape)} and {tuple(concentration.shape)}",
                fix="pass an xyzw quaternion and three concentrations (z ≤ 0 is canonical)",
            )
        batch = torch.broadcast_shapes(quat_xyzw.shape[:-1], concentration.shape[:-1])
        self.quat_xyzw = quat_normalize(quat_xyzw.to(torch.float64)).expand(*batch, 4)
        self.concentration = concentration.to(torch.float64).expand(*batch, 3)
        if validate_args is not False and not bool(torch.isfinite(self.concentration).all()):
            raise ConfigError(
                "Bingham concentrations must be finite",
                fix="lower the learning rate or check the rewards for NaN/inf",
            )
        super().__init__(batch, torch.Size([4]), validate_args=validate_args)

    def expand(self, batch_shape: torch.Size, _instance: Bingham | None = None) -> Bingham:
        """Broadcasts the parameters to ``batch_shape``."""
        shape = torch.Size(batch_shape)
        return Bingham(
            self.quat_xyzw.expand(*shape, 4), self.concentration.expand(*shape, 3), False
        )

    # ------------------------------------------------------------------ density
    @property
    def symmetry_axis(self) -> Tensor:
        """``[batch, 4]`` axis ``m₄`` (the reference quaternion) of the reflection symmetry.

        Reflecting a quaternion through it, ``x -> 2 (m₄·x) m₄ - x`` (the relative rotation
        ``δ -> δ⁻¹``), keeps its density.
        """
        return self.quat_xyzw

    def body_coordinates(self, x: Tensor) -> Tensor:
        """``y = q0* ⊗ x`` ``[..., 4]``: the sample relative to the reference ``q0``."""
        return quat_multiply(quat_conjugate(self.quat_xyzw), x)

    def log_normaliser(self) -> Tensor:
        """Exact ``log N(Z)`` ``[batch]``."""
        return bingham_log_normaliser(self.concentration)

    def log_prob(self, value: Tensor) -> Tensor:
        """Log-density ``[sample, batch]`` of unit quaternions ``value [..., 4]``; p(x) = p(-x)."""
        if self._validate_args:
            self._validate_sample(value)
        y = self.body_coordinates(value.to(torch.float64))
        quad = (self.concentration * y[..., :3] ** 2).sum(-1)
        return quad - self.log_normaliser()

    def entropy(self) -> Tensor:
        """Differential entropy ``[batch]`` in nats (w.r.t. the surface measure of S³)."""
        return bingham_entropy(self.concentration)

    # ------------------------------------------------------------------ samples
    @torch.no_grad()
    def sample(self, sample_shape: torch.Size | tuple[int, ...] = ()) -> Tensor:
        """Exact samples ``[*sample_shape, *batch, 4]`` (unit, xyzw) by ACG rejection."""
        shape = self._extended_shape(torch.Size(sample_shape))
        z = self.concentration.detach().expand(*shape[:-1], 3).reshape(-1, 3)
        q0 = self.quat_xyzw.detach().expand(*shape).reshape(-1, 4)
        y, self.last_acceptance_rate = sample_bingham_body(z)
        return quat_multiply(q0, y).reshape(shape)

    def _mode_axis(self) -> Tensor:
        d = torch.cat([self.concentration, torch.zeros_like(self.concentration[..., :1])], -1)
        # Ties prefer the reference (w, index 3): argmax of the reversed order.
        return 3 - d.detach().flip(-1).argmax(-1)

    @property
    def mode(self) -> Tensor:
        """The mode ``[batch, 4]`` with ``w ≥ 0`` (``±`` is the same rotation).

        ``q0`` when ``z ≤ 0``, else ``q0 ⊗ e_k`` for the largest concentration ``k``.
        """
        basis = torch.eye(4, dtype=torch.float64, device=self.quat_xyzw.device)
        return quat_canonical(quat_multiply(self.quat_xyzw, basis[self._mode_axis()]))

    @property
    def deterministic_sample(self) -> Tensor:
        """What TorchRL returns in deterministic mode: the mode."""
        return self.mode

    # ------------------------------------------------------------------ readouts
    def second_moments(self) -> Tensor:
        """``E[y_i²]`` ``[batch, 3]`` along the body axes of ``q0`` (``= ∂ log N / ∂zi``)."""
        return bingham_second_moments(self.concentration)

    def rotation_sigma_rad(self) -> Tensor:
        """Per-body-axis rotation spread ``2·sqrt(E[y'_i²])`` ``[batch, 3]`` in radians.

        ``y' = mode* ⊗ x``, i.e. about the axes of the mode's frame.

        Equals ``sqrt(2/|zi|)`` for concentrated distributions (the small-angle σ of the
        rotation about axis ``i``); 1 rad for the uniform distribution (at most √2 rad).
        """
        moments = bingham_second_moments(self.concentration, include_fourth=True)
        perm = _AXIS_PERMUTATIONS.to(moments.device)[self._mode_axis()][..., :3]
        return 2 * torch.gather(moments, -1, perm).sqrt()


def concentration_from_sigma(sigma_rad: Tensor | float) -> Tensor:
    """Concentration ``z = -2/σ²`` for a small-angle rotation σ (rad) about a body axis."""
    sigma = torch.as_tensor(sigma_rad, dtype=torch.float64)
    return -2.0 / sigma**2


LOG_UNIFORM_DENSITY = -math.log(2 * math.pi**2)
