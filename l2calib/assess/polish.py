"""Newton polish of the refined extrinsic: a quadratic model of the reward around the result.

The refinement (:mod:`l2calib.assess.refine`) climbs one axis at a time; where axes are coupled
— rotation with the time offset on a turning rig, the lever arm with rotation — a ridge runs
diagonally and a per-axis climb stops short of its top. This stage fits the full quadratic of
``f = −log(reward)`` around the current extrinsic from one batched call (the centre, ± each axis,
and ±± each pair of axes: 1 + 2n + 2n(n−1) candidates, 73 for six axes, 99 with the offset),
takes the Newton step ``−H⁻¹∇f`` (directions of non-positive curvature dropped, each axis's
step capped at ``max_steps`` stencil widths) and scores ¼, ½ and all of it in one more call.
The best of those and of the stencil's own points is kept where it raises the reward. The
paper's reward is not quadratic at its peak (``−log r`` is the square root of mean absolute
errors: a cusp), so a stencil much wider than the peak models it badly; a round that finds
nothing better halves the stencil, down to ⅛ of its first widths (0.06°, 2.5 mm, 0.125 ms).
Up to ``rounds`` rounds.

Measured by ``python -m benchmarks.experiment_polish`` (3 rounds, continuing stored runs;
``benchmarks/results/experiments/polish.json``): hand-held OS1-16 with the true trajectory,
training seeds 0–2, rotation 0.040 / 0.016 / 0.034° → 0.016 / 0.016 / 0.015°, translation
0.70 / 0.28 / 0.63 → 0.56 / 0.32 / 0.53 cm; the +50 ms time-offset recording 0.24° → 0.14°,
1.12 → 1.17 cm; +300 evaluations. On planar motion (a ground vehicle) 8 rounds from a quarter
stencil are the default (:data:`l2calib.train.vertical_hold.PLANAR_TRAIN`: x / y 0.07–0.95 /
0.66–1.56 cm over three training seeds, against 0.99–2.43 / 0.30–1.01 cm without); elsewhere
opt-in (``train.polish_rounds``, default 0) until measured in full calibrations.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from l2calib import geometry as geo
from l2calib.interfaces import Extrinsic

#: Stencil half-widths: rotation (rad), translation (m), time offset (s).
STEPS = (math.radians(0.5),) * 3 + (0.02,) * 3 + (0.001,)
#: Fractions of the Newton step scored in one batch (the step is capped at ``max_steps``).
LINE_FRACTIONS = (0.25, 0.5, 1.0)
#: The stencil halves after a round that found nothing better, down to this fraction of STEPS.
MIN_SCALE = 1 / 8


@dataclass
class PolishResult:
    """Outcome of :func:`polish`.

    Attributes:
        extrinsic: The polished extrinsic (the start when no step raised the reward).
        reward: Its reward; ``start_reward`` the start's.
        rounds: Rounds whose move was kept.
        evaluations: Candidates scored.
    """

    extrinsic: Extrinsic
    reward: float
    start_reward: float
    rounds: int
    evaluations: int

    def summary(self) -> dict[str, Any]:
        """What the polish did, for ``calibration.yaml`` → ``polish`` (rounded)."""
        return {
            "start_reward": round(self.start_reward, 6),
            "polished_reward": round(self.reward, 6),
            "rounds_kept": int(self.rounds),
            "evaluations": int(self.evaluations),
        }


def stencil(n: int, scale: float = 1.0) -> np.ndarray:
    """``[1 + 2n + 2n(n−1), n]`` perturbations: centre, ± each axis, ±± each pair of axes.

    ``scale`` multiplies the half-widths :data:`STEPS`.
    """
    h = np.array(STEPS[:n]) * scale
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


def derivatives(f: np.ndarray, n: int, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Gradient ``[n, ...]`` and Hessian ``[n, n]`` by central differences from ``f``.

    ``f``: values at the :func:`stencil` points (of the same ``scale``), ``[P]`` or ``[P, B]``
    (then one gradient per column, e.g. per block of data; the Hessian of the columns' sum).
    """
    h = np.array(STEPS[:n]) * scale
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


def newton_step(f: np.ndarray, n: int, max_steps: float, scale: float = 1.0) -> np.ndarray:
    """The capped Newton step from ``f`` at the :func:`stencil` points (``[n]``)."""
    h = np.array(STEPS[:n]) * scale
    grad, H = derivatives(f, n, scale)
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
    first_scale: float = 1.0,
) -> PolishResult:
    """Newton rounds on ``−log(reward)`` from ``start`` (module docstring).

    Args:
        score: ``score(T [N,4,4], offsets [N] | None) -> [N]`` rewards.
        start: The refined extrinsic; its ``time_offset_s`` (if not ``None``) is a 7th axis.
        rounds: At most this many rounds (stencils fitted; each ``P + 3`` candidates).
        max_steps: Largest move per axis and round, in widths of the current stencil.
        hold: Applied to every candidate's ``T`` (the vertical lever-arm hold), or ``None``.
        first_scale: The first stencil's widths as a fraction of :data:`STEPS`.
    """
    n = 6 if start.time_offset_s is None else 7
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

    scale = first_scale
    for _ in range(rounds):
        pattern = stencil(n, scale)
        r = rewards(moved(T, pattern), pattern)
        evaluations += len(pattern)
        best = float(r[0]) if best is None else best
        start_reward = best if start_reward is None else start_reward
        if not np.all(r > 0):
            break  # a candidate whose odometry failed: no smooth model here
        step = newton_step(-np.log(r), n, max_steps, scale)
        line = np.outer(LINE_FRACTIONS, step)  # the model's scale is rarely right: search it
        r_line = rewards(moved(T, line), line)
        evaluations += len(line)
        # The best of the line and the stencil's own points (each one a scored candidate).
        tried = np.concatenate([line, pattern[1:]])
        scores = np.concatenate([r_line, r[1:]])
        k = int(np.argmax(scores))
        if not scores[k] > best:
            scale /= 2  # the reward's peak is sharper than the stencil: look closer
            if scale < MIN_SCALE * first_scale:
                break
            continue
        T, best, kept = moved(T, tried[k])[0], float(scores[k]), kept + 1
        offset = None if offset is None else offset + float(tried[k][6])
    if hold is not None:
        T = hold(T[None])[0]
    result = Extrinsic(T, offset)
    return PolishResult(result, best or 0.0, start_reward or 0.0, kept, evaluations)
