"""Exact normalising constant of the Bingham distribution on S³, by 1-D quadrature.

The Bingham density on the unit quaternions is ``p(x) = exp(xᵀ M Z Mᵀ x) / N(Z)`` with
``Z = diag(z1, z2, z3, 0)``, ``z ≤ 0``. With Hopf coordinates
``x = (cosθ cosφ1, cosθ sinφ1, sinθ cosφ2, sinθ sinφ2)`` the two azimuths integrate to modified
Bessel functions and, with ``t = cos²θ`` (``s = 1 - t``)::

    N(Z) = 2π² ∫₀¹ e^{a1 t} I0(b1 t) · e^{a2 s} I0(b2 s) dt,
    a1 = (zi + zj)/2, b1 = (zi - zj)/2,  a2 = (zk + 0)/2, b2 = (zk - 0)/2,

for any pairing of the four diagonal entries. We shift all four by their maximum
(``N(Z + cI) = e^c N(Z)``, which also makes positive ``zi`` legal), pair the two most negative
and the remaining one with the zero, so every factor is bounded by 1
(``log I0(x) = log i0e(x) + |x|``). ``N(0) = 2π²``, the area of S³.

The integrand is smooth inside (0, 1) but its features sit at distances ``~1/|z|`` from the ends,
so we use fixed-node tanh-sinh (double-exponential) quadrature, whose nodes cluster doubly
exponentially at the end points; in float64 this gives ≤ 5e-9 relative error over
``z ∈ [-1e6, 0]³`` (checked against scipy's adaptive quadrature in the tests). Because the nodes
are fixed, the result is an ordinary torch expression: autograd gives exact gradients
``∂ log N / ∂zi = E[(miᵀx)²]`` (also available in closed form as :func:`bingham_second_moments`).

No library provides this: scipy has no Bingham normaliser, and the paper's public code
approximates it with a small network (off by up to 2× and saturating); hence this module.
"""

from __future__ import annotations

import math
from functools import lru_cache

import torch
from torch import Tensor

from l2calib.errors import ConfigError

#: log of the area of S³ (2π²), the normaliser of the uniform distribution (z = 0).
LOG_AREA_S3 = math.log(2.0 * math.pi**2)

# Tanh-sinh grid: u ∈ [-U_MAX, U_MAX] with step U_MAX / N_HALF (177 nodes). U_MAX = 3.4 puts
# the outermost nodes at t ≈ 1e-20 from the ends (far below the 1/|z| ≥ 1e-6 feature scale);
# the step h ≈ 0.039 keeps the error ≤ 5e-9 relative for z ∈ [-1e6, 0]³ (≤ 2e-11 with 257
# nodes; 129 nodes give 6e-7), measured against scipy in benchmarks/bench_policies.py.
U_MAX = 3.4
N_HALF = 88


@lru_cache(maxsize=8)
def _tanh_sinh_nodes(device: str) -> tuple[Tensor, Tensor, Tensor]:
    """Nodes ``t``, complements ``1 - t`` (computed without cancellation) and weights on [0, 1]."""
    h = U_MAX / N_HALF
    u = torch.arange(-N_HALF, N_HALF + 1, dtype=torch.float64, device=device) * h
    s = math.pi * torch.sinh(u)
    t = torch.sigmoid(-s)  # t = 1 / (1 + e^{π sinh u})
    one_minus_t = torch.sigmoid(s)
    w = h * math.pi * torch.cosh(u) * t * one_minus_t  # |dt/du| · h
    keep = w > 0  # drop nodes whose weight underflowed
    return t[keep], one_minus_t[keep], w[keep]


def _check(z: Tensor) -> Tensor:
    if z.shape[-1:] != (3,):
        raise ConfigError(
            f"Bingham concentrations must have shape [..., 3], got {tuple(z.shape)}",
            fix="pass the three concentrations z1, z2, z3 (the fourth is fixed at 0)",
        )
    return z.to(torch.float64)


def _broadcast_row(z: Tensor) -> tuple[Tensor, torch.Size] | None:
    """The single row and batch shape of ``z [..., 3]`` if it is one row broadcast (stride 0).

    The actor produces such tensors; the quadrature then runs once instead of per row. Leaves
    that require grad are excluded (their per-row gradient must stay per row).
    """
    nb = z.dim() - 1
    if nb == 0 or (z.is_leaf and z.requires_grad):
        return None
    if all(z.stride(i) == 0 or z.shape[i] == 1 for i in range(nb)):
        return z[(0,) * nb], z.shape[:-1]
    return None


def _sorted_terms(z: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor, Tensor, Tensor]:
    """Sorted, shifted diagonal and the pieces of the integrand at every node.

    The four diagonal entries ``d = (z1, z2, z3, 0)`` are sorted and shifted by their maximum
    ``m`` (``N(d) = e^m N(d - m)``), so any real ``z`` is handled and every factor is ≤ 1.

    Returns ``order`` (the sort permutation of ``d``), ``m`` ``[..., 1]``, ``f`` (integrand
    values ``[..., n]``), the nodes ``t``, ``s``, ``w``, the Bessel arguments ``x1 = b1 t``,
    ``x2 = b2 s`` and ``i0e`` at them (stacked ``[2, ..., n]``, reused by the moments).
    """
    d = torch.cat([z, torch.zeros_like(z[..., :1])], dim=-1)
    ds, order = torch.sort(d, dim=-1)  # d(1) <= d(2) <= d(3) <= d(4) = m
    m = ds[..., 3:4]
    t, s, w = _tanh_sinh_nodes(str(z.device))
    z1, z2, z3 = (ds[..., i : i + 1] - m for i in range(3))  # all <= 0, paired with 0
    x1 = 0.5 * (z1 - z2) * t  # b1 t (<= 0; I0 is even)
    x2 = 0.5 * z3 * s  # b2 s
    i0e1, i0e2 = torch.special.i0e(x1), torch.special.i0e(x2)
    # log[e^{a1 t} I0(b1 t) e^{a2 s} I0(b2 s)] with log I0(x) = log i0e(x) + |x|. The sum is
    # ≤ 0 (a + |b| = max of the pair ≤ 0), so exp never overflows. Keeping a1, a2 and |x|
    # explicit (instead of folding them into max(z) t) keeps autograd exact at ties (z1 = z2,
    # z3 = 0), where max() and |x| have kinks that only cancel analytically.
    log_f = (
        0.5 * (z1 + z2) * t + 0.5 * z3 * s + x1.abs() + x2.abs() + torch.log(i0e1) + torch.log(i0e2)
    )
    return order, m, torch.exp(log_f), t, s, w, torch.stack([x1, x2]), torch.stack([i0e1, i0e2])


def bingham_log_normaliser(z: Tensor) -> Tensor:
    """Exact ``log N(Z)`` of the Bingham distribution on S³ (float64, differentiable).

    Args:
        z: Concentrations ``[..., 3]``, any order (the fourth diagonal entry is 0). The usual
            canonical form is ``z ≤ 0``; positive entries are valid too (the density only
            depends on differences of the diagonal entries; the mode then moves to that axis).

    Returns:
        ``log N`` ``[...]`` in float64, with ``N`` the integral of ``exp(xᵀ M Z Mᵀ x)`` over S³
        w.r.t. its surface measure (``N(0) = 2π²``).
    """
    z = _check(z)
    row = _broadcast_row(z)
    if row is not None:
        return bingham_log_normaliser(row[0]).expand(row[1])
    _, m, f, _, _, w, _, _ = _sorted_terms(z)
    return m[..., 0] + LOG_AREA_S3 + torch.log((f * w).sum(-1))


def bingham_second_moments(z: Tensor, include_fourth: bool = False) -> Tensor:
    """``E[(miᵀx)²]`` for each diagonal entry (``= ∂ log N / ∂zi``), differentiable.

    Uses the analytic derivative of the integrand (``I0' = I1``) under the same quadrature, so
    it is smooth in ``z`` and can itself be differentiated (e.g. for the entropy bonus).

    Args:
        z: Concentrations ``[..., 3]``.
        include_fourth: Also return the moment along the fourth axis (the one with entry 0).

    Returns:
        Second moments ``[..., 3]`` (or ``[..., 4]``); the four sum to 1, each is ``1/4`` at
        ``z = 0``.
    """
    z = _check(z)
    row = _broadcast_row(z)
    if row is not None:
        return bingham_second_moments(row[0], include_fourth).expand(
            *row[1], 4 if include_fourth else 3
        )
    return _moments_from_terms(_sorted_terms(z), include_fourth)


def _moments_from_terms(terms: tuple, include_fourth: bool) -> Tensor:
    order, _, f, t, s, w, x, i0e = terms
    r1 = torch.special.i1e(x[0]) / i0e[0]  # I1/I0 (signed, <= 0)
    r2 = torch.special.i1e(x[1]) / i0e[1]
    fw = f * w
    parts = [t * (1 + r1), t * (1 - r1), s * (1 + r2), s * (1 - r2)]  # 2 ∂ log f / ∂d(i)
    sorted_moments = torch.cat([(fw * p).sum(-1, keepdim=True) for p in parts], -1)
    sorted_moments = sorted_moments / (2 * fw.sum(-1, keepdim=True))
    moments = torch.empty_like(sorted_moments).scatter(-1, order, sorted_moments)
    return moments if include_fourth else moments[..., :3]


def bingham_entropy(z: Tensor) -> Tensor:
    """Differential entropy ``[...]`` (nats, w.r.t. the surface measure of S³) of Bingham(z).

    ``H = log N(Z) - Σ zi E[(miᵀx)²]``; equals ``log 2π²`` for the uniform distribution.
    """
    z = _check(z)
    row = _broadcast_row(z)
    if row is not None:
        return bingham_entropy(row[0]).expand(row[1])
    terms = _sorted_terms(z)  # one quadrature pass for both log N and the moments
    _, m, f, _, _, w, _, _ = terms
    log_n = m[..., 0] + LOG_AREA_S3 + torch.log((f * w).sum(-1))
    return log_n - (z * _moments_from_terms(terms, False)).sum(-1)
