"""Deterministic polish of the trained extrinsic on the reward (after PPO).

PPO stops on a plateau or on its evaluation budget. On weakly excited data (a drone's gentle
motion) the reward is shallow along the translation axes and the policy's mode can stop a few
centimetres from the reward's optimum even though the data resolves it. This stage climbs the same
reward from the mode, with a handful of batched backend calls:

1. Evaluate ``T · exp(±s·eᵢ)`` for the six axes (rotation about and translation along the LiDAR's
   own axes, as :mod:`l2calib.assess.sensitivity` perturbs) — one call of 12 candidates.
2. Per axis, fit a parabola through ``(−s, r₋), (0, r₀), (+s, r₊)`` and take its vertex (clamped to
   ``±s``) where the reward curves downward; elsewhere step toward the better side if it scored
   higher. Evaluate the combined move.
3. Keep the best of {the move, the best probe point, the current extrinsic}; halve the steps when
   nothing beat the current extrinsic (the optimum is within ±s).

With a time offset (the start's ``time_offset_s`` is not ``None``), the offset is a seventh axis
of the same climb: rotation and offset trade off against each other on a rotating rig (a late IMU
looks like a turned LiDAR), so polishing the rotation with the offset held at PPO's mode leaves
both off.

Every accepted step scored strictly higher on the reward itself, so the result is never worse
than the policy's mode on the training reward. Written here (not scipy.optimize) because each
round must be one batched backend call of many candidates, which scipy's sequential optimisers do
not offer.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from l2calib import geometry as geo
from l2calib.interfaces import Extrinsic

__all__ = ["RefineResult", "refine"]

#: ``score(T [N,4,4]) -> [N]`` rewards; with a time offset ``score(T, offsets [N] s)``.
Scorer = Callable[..., torch.Tensor]


@dataclass
class RefineResult:
    """Outcome of :func:`refine`.

    Attributes:
        extrinsic: The refined :class:`~l2calib.interfaces.Extrinsic` (its ``time_offset_s``
            refined too when the start had one).
        reward: its reward.
        start_reward: reward of the starting extrinsic.
        evaluations: backend candidate evaluations used.
        moved_deg: rotation between start and result (deg).
        moved_m: translation between start and result (m).
        history: per round ``(reward, rotation step deg, translation step m)``.
        moved_offset_s: how far the offset moved (s).
    """

    extrinsic: Extrinsic
    reward: float
    start_reward: float
    evaluations: int
    moved_deg: float
    moved_m: float
    history: list[tuple[float, float, float]] = field(default_factory=list)
    moved_offset_s: float = 0.0

    def summary(self) -> dict[str, Any]:
        """What the refinement did, for ``calibration.yaml`` → ``refine`` (rounded)."""
        return {
            "policy_mode_reward": round(self.start_reward, 6),
            "refined_reward": round(self.reward, 6),
            "moved_deg": round(self.moved_deg, 4),
            "moved_m": round(self.moved_m, 5),
            **(
                {"moved_time_offset_ms": round(1000 * self.moved_offset_s, 3)}
                if self.extrinsic.time_offset_s is not None
                else {}
            ),
            "evaluations": int(self.evaluations),
        }


def _perturb(T: torch.Tensor, xi: torch.Tensor) -> torch.Tensor:
    """``T · exp(ξ)`` ``[N, 4, 4]`` for ``ξ [N, 6]`` = (translation m, rotation rad), LiDAR axes."""
    delta = torch.eye(4, dtype=torch.float64).repeat(xi.shape[0], 1, 1)
    delta[:, :3, :3] = geo.so3_exp(xi[:, 3:])
    delta[:, :3, 3] = xi[:, :3]
    return T[None] @ delta


def _vertex(r0: float, r_plus: np.ndarray, r_minus: np.ndarray) -> np.ndarray:
    """Per-axis move in units of the step: the parabola's vertex, clamped to ``[-1, 1]``."""
    curvature = 2.0 * r0 - r_plus - r_minus  # > 0: the reward peaks near here
    slope = 0.5 * (r_plus - r_minus)
    with np.errstate(divide="ignore", invalid="ignore"):
        vertex = np.where(curvature > 0, slope / curvature, np.sign(slope))
    # Not curving down: move only toward a side that actually scored higher.
    better = np.maximum(r_plus, r_minus) > r0
    vertex = np.where((curvature > 0) | better, vertex, 0.0)
    return np.clip(np.nan_to_num(vertex), -1.0, 1.0)


def refine(
    score: Scorer,
    start: Extrinsic,
    rounds: int = 4,
    rot_step_deg: float = 1.0,
    trans_step_m: float = 0.04,
    start_reward: float | None = None,
    offset_step_s: float = 0.002,
    min_steps: tuple[float, float, float] = (0.001, 0.025, 5e-5),
) -> RefineResult:
    """Climbs the reward from ``start`` (module docstring).

    Args:
        score: Rewards ``[N]`` of extrinsics ``T_imu_lidar [N, 4, 4]`` (one batched call); with
            a time offset ``score(T, offsets [N] s)``.
        start: Where to start. Its ``time_offset_s`` is refined as a seventh axis unless it is
            ``None`` (the extrinsic alone).
        rounds: Probe rounds (each ``12 + 1`` evaluations).
        rot_step_deg: First rotation step (deg); halves when a round finds nothing better.
        trans_step_m: First translation step (m); halves alike.
        start_reward: Reward of ``start`` if already known (else one more evaluation).
        offset_step_s: First time-offset step (s); halves with the others.
        min_steps: ``(translation m, rotation deg, offset s)``: the climb ends before
            ``rounds`` once every step has halved below these (finer than the result's
            accuracy, so further rounds would only spend evaluations).

    Returns:
        The :class:`RefineResult`; its extrinsic is ``start`` if nothing scored higher.
    """
    T0 = start.T_imu_lidar.detach().to(torch.float64)
    offset_s = start.time_offset_s
    timed = offset_s is not None

    def at(T: torch.Tensor, off: float, xi: torch.Tensor) -> torch.Tensor:
        """Rewards of ``[N]`` moves ``xi [N, 6 or 7]`` from ``(T, off)``."""
        Ts = _perturb(T, xi[:, :6])
        if not timed:
            return score(Ts).detach().to(torch.float64)
        return score(Ts, off + xi[:, 6]).detach().to(torch.float64)

    T, off, evals = T0.clone(), float(offset_s or 0.0), 0
    n = 7 if timed else 6
    if start_reward is None:
        start_reward, evals = float(at(T, off, torch.zeros(1, n, dtype=torch.float64))[0]), 1
    r = float(start_reward)
    steps = np.array(
        [trans_step_m] * 3 + [np.radians(rot_step_deg)] * 3 + ([offset_step_s] if timed else [])
    )
    floor = np.array(
        [min_steps[0]] * 3 + [np.radians(min_steps[1])] * 3 + ([min_steps[2]] if timed else [])
    )
    history = []
    for _ in range(rounds):
        if np.all(steps < floor):
            break
        xi = torch.from_numpy(np.concatenate([np.diag(steps), -np.diag(steps)]))
        probe = at(T, off, xi).numpy()
        r_plus, r_minus = probe[:n], probe[n:]
        move = torch.from_numpy(_vertex(r, r_plus, r_minus) * steps)
        i = int(np.argmax(probe))
        options = [(r, T, off), (float(probe[i]), *_step(T, off, xi[i], timed))]
        evals += 2 * n
        if float(move.abs().max()) > 0:
            options.append((float(at(T, off, move[None])[0]), *_step(T, off, move, timed)))
            evals += 1
        best_r, best_T, best_off = max(options, key=lambda o: o[0])
        if best_r > r:
            r, T, off = best_r, best_T, best_off
        else:
            steps = steps / 2.0  # the optimum is within the steps: look closer
        history.append((r, float(np.degrees(steps[3])), float(steps[0])))
    d = geo.transform_inverse(T0) @ T
    return RefineResult(
        extrinsic=Extrinsic(T, float(off) if timed else None),
        reward=r,
        start_reward=float(start_reward),
        evaluations=evals,
        moved_deg=float(np.degrees(float(geo.rotation_angle(d[:3, :3])))),
        moved_m=float(d[:3, 3].norm()),
        history=history,
        moved_offset_s=float(abs(off - float(offset_s))) if timed else 0.0,
    )


def _step(T: torch.Tensor, off: float, xi: torch.Tensor, timed: bool):
    """``(T · exp(xi[:6]), off + xi[6])`` for one move."""
    return _perturb(T, xi[None, :6])[0], off + (float(xi[6]) if timed else 0.0)
