"""Newton polish of the refined extrinsic: a quadratic model of the reward around the result.

The refinement (:mod:`l2calib.assess.refine`) climbs one axis at a time; where axes are coupled
— rotation with the time offset on a turning rig, the lever arm with rotation — a ridge runs
diagonally and a per-axis climb stops short of its top. This stage fits the full quadratic of
``f = −log(reward)`` around the current extrinsic from one batched call (the centre, ± each axis,
and ±± each pair of axes: 1 + 2n + 2n(n−1) candidates, 73 for six axes, 99 with the offset),
takes the Newton step ``−H⁻¹∇f`` (directions of non-positive curvature dropped, each axis's
step capped at ``max_steps`` stencil widths), and keeps it only where the reward rises. Up to
``rounds`` rounds; it stops at the first step that does not raise the reward.

Measured by ``python -m benchmarks.experiment_polish`` (3 rounds, continuing stored runs;
``benchmarks/results/experiments/polish.json``): hand-held OS1-16 with the true trajectory,
training seeds 0–2, rotation 0.040 / 0.016 / 0.034° → 0.016 / 0.016 / 0.015°, translation
0.70 / 0.28 / 0.63 → 0.56 / 0.32 / 0.53 cm; the +50 ms time-offset recording 0.24° → 0.14°,
1.12 → 1.17 cm; +300 evaluations. Opt-in (``train.polish_rounds``, default 0) until weakly
excited data is measured: there the reward's own peak lies centimetres from the truth, and
climbing it may not help.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from l2calib import geometry as geo
from l2calib.interfaces import Extrinsic

#: Stencil half-widths: rotation (rad), translation (m), time offset (s).
STEPS = (math.radians(0.5),) * 3 + (0.02,) * 3 + (0.001,)


@dataclass
class PolishResult:
    """Outcome of :func:`polish`.

    Attributes:
        extrinsic: The polished extrinsic (the start when no step raised the reward).
        reward: Its reward; ``start_reward`` the start's.
        rounds: Newton steps kept.
        evaluations: Candidates scored.
    """

    extrinsic: Extrinsic
    reward: float
    start_reward: float
    rounds: int
    evaluations: int


def stencil(n: int) -> np.ndarray:
    """``[1 + 2n + 2n(n−1), n]`` perturbations: centre, ± each axis, ±± each pair of axes."""
    h = np.array(STEPS[:n])
    rows = [np.zeros(n)]
    for i in range(n):
        rows += [np.eye(n)[i] * h[i], -np.eye(n)[i] * h[i]]
    for i in range(n):
        for j in range(i + 1, n):
            for si in (1, -1):
                for sj in (1, -1):
                    rows.append(np.eye(n)[i] * si * h[i] + np.eye(n)[j] * sj * h[j])
    return np.array(rows)


def moved(T: torch.Tensor, delta: np.ndarray) -> torch.Tensor:
    """``T · exp(δ)`` per row of ``delta`` (rotation about, translation along the LiDAR axes)."""
    d = torch.as_tensor(np.atleast_2d(delta), dtype=torch.float64)
    step = torch.eye(4, dtype=torch.float64).repeat(d.shape[0], 1, 1)
    step[:, :3, :3] = geo.so3_exp(d[:, :3])
    step[:, :3, 3] = d[:, 3:6]
    return T[None] @ step


def derivatives(f: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Gradient ``[n, ...]`` and Hessian ``[n, n]`` by central differences from ``f``.

    ``f``: values at the :func:`stencil` points, ``[P]`` or ``[P, B]`` (then one gradient per
    column, e.g. per block of data; the Hessian of the columns' sum).
    """
    h = np.array(STEPS[:n])
    scale = h.reshape(-1, *([1] * (f.ndim - 1)))
    grad = (f[1 : 2 * n : 2] - f[2 : 2 * n + 1 : 2]) / (2 * scale)
    total = f if f.ndim == 1 else f.sum(1)
    H = np.diag((total[1 : 2 * n : 2] - 2 * total[0] + total[2 : 2 * n + 1 : 2]) / h**2)
    k = 1 + 2 * n
    for i in range(n):
        for j in range(i + 1, n):
            pp, pm, mp, mm = total[k : k + 4]
            k += 4
            H[i, j] = H[j, i] = (pp - pm - mp + mm) / (4 * h[i] * h[j])
    return grad, H


def newton_step(f: np.ndarray, n: int, max_steps: float) -> np.ndarray:
    """The capped Newton step from ``f`` at the :func:`stencil` points (``[n]``)."""
    h = np.array(STEPS[:n])
    grad, H = derivatives(f, n)
    # In units of the stencil, so that rotation, translation and time compare.
    Hs = H * np.outer(h, h)
    values, vectors = np.linalg.eigh(Hs)
    keep = values > 1e-9 * max(float(np.abs(values).max()), 1e-300)  # curving up only
    inv = (vectors[:, keep] / values[keep]) @ vectors[:, keep].T
    step = -inv @ (grad * h)
    return np.clip(step, -max_steps, max_steps) * h


def polish(
    score: Callable[..., torch.Tensor],
    start: Extrinsic,
    rounds: int,
    max_steps: float = 2.0,
    hold: Callable[[torch.Tensor], torch.Tensor] | None = None,
) -> PolishResult:
    """Newton rounds on ``−log(reward)`` from ``start`` (module docstring).

    Args:
        score: ``score(T [N,4,4], offsets [N] | None) -> [N]`` rewards.
        start: The refined extrinsic; its ``time_offset_s`` (if not ``None``) is a 7th axis.
        rounds: At most this many Newton steps.
        max_steps: Largest move per axis and round, in stencil widths (0.5°, 2 cm, 1 ms).
        hold: Applied to every candidate's ``T`` (the vertical lever-arm hold), or ``None``.
    """
    n = 6 if start.time_offset_s is None else 7
    pattern = stencil(n)
    T, offset = start.T_imu_lidar.detach().to(torch.float64), start.time_offset_s
    best = start_reward = None
    evaluations = kept = 0

    def rewards(candidates: torch.Tensor, deltas: np.ndarray) -> np.ndarray:
        if hold is not None:
            candidates = hold(candidates)
        offsets = None
        if offset is not None:
            offsets = torch.as_tensor(offset + deltas[:, 6], dtype=torch.float64)
        return score(candidates, offsets).detach().numpy().astype(np.float64)

    for _ in range(rounds):
        r = rewards(moved(T, pattern), pattern)
        evaluations += len(pattern)
        best = float(r[0]) if best is None else best
        start_reward = best if start_reward is None else start_reward
        if not np.all(r > 0):
            break  # a candidate whose odometry failed: no smooth model here
        step = newton_step(-np.log(r), n, max_steps)
        T_new = moved(T, step)[0]
        r_new = float(rewards(T_new[None], step[None])[0])
        evaluations += 1
        if not r_new > best:
            break
        T, best, kept = T_new, r_new, kept + 1
        offset = None if offset is None else offset + float(step[6])
    if hold is not None:
        T = hold(T[None])[0]
    result = Extrinsic(T, offset)
    return PolishResult(result, best or 0.0, start_reward or 0.0, kept, evaluations)
