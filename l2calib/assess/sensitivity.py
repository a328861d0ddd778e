"""How sharply the data pins down each axis of the calibrated extrinsic.

The policy's spread after training says how far PPO narrowed its search, not what the data can
resolve (its σ follow the learning-rate schedule and shrink alike on every axis). So after training
we probe the reward directly: the calibrated ``T_imu_lidar`` is perturbed about and along each LiDAR
axis by a ladder of steps, both signs, all in one batched backend call, and per axis we report the
**resolution**: the smallest perturbation that lowers the reward by ``drop_fraction`` of its value
(linear interpolation on the ladder). A flat axis — no step on the ladder lowers the reward that
much — is one the data could not determine; a step that *raises* the reward means the result is
not at the optimum along that axis. Both are named in the warnings.

Perturbations are right-multiplied, ``T_imu_lidar · exp(δ)``: rotations about, and translations
along, the LiDAR's own axes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from l2calib import geometry as geo

__all__ = ["ROTATION_STEPS_DEG", "TRANSLATION_STEPS_M", "AxisResolution", "probe", "resolve"]

AXES = ("x", "y", "z")
#: Probe ladders: fine enough to resolve a good calibration, wide enough to show a flat axis.
ROTATION_STEPS_DEG = (0.25, 1.0, 4.0)
TRANSLATION_STEPS_M = (0.005, 0.02, 0.08, 0.16)


@dataclass
class AxisResolution:
    """Per-axis resolution of the calibration (``inf`` where the reward stays flat).

    Attributes:
        rotation_deg: [3] about LiDAR x, y, z (deg).
        translation_m: [3] along LiDAR x, y, z (m).
        reward: reward of the calibrated extrinsic.
        drops: ``{"rot x": [drop per step], ...}`` mean reward drop over ± each step.
        better: axes where a probe step scored above the calibrated extrinsic (by more than the
            threshold), i.e. the result is not at the reward's optimum there.
    """

    rotation_deg: list[float]
    translation_m: list[float]
    reward: float
    drops: dict[str, list[float]] = field(default_factory=dict)
    better: list[str] = field(default_factory=list)


def probe(T_imu_lidar: np.ndarray | torch.Tensor) -> torch.Tensor:
    """The probe candidates: ``[1 + 2·6·S, 4, 4]`` float64, the calibrated extrinsic first.

    Order: rotation axes x, y, z then translation axes x, y, z; per axis the steps of the ladder;
    per step the signs +, −.
    """
    T = torch.as_tensor(np.asarray(T_imu_lidar), dtype=torch.float64)
    out = [T]
    for kind, steps in (("rot", ROTATION_STEPS_DEG), ("trans", TRANSLATION_STEPS_M)):
        for axis in range(3):
            for step in steps:
                for sign in (1.0, -1.0):
                    delta = torch.eye(4, dtype=torch.float64)
                    if kind == "rot":
                        v = torch.zeros(3, dtype=torch.float64)
                        v[axis] = sign * np.radians(step)
                        delta[:3, :3] = geo.so3_exp(v)
                    else:
                        delta[axis, 3] = sign * step
                    out.append(T @ delta)
    return torch.stack(out)


def _width(steps: tuple[float, ...], drops: np.ndarray, threshold: float) -> float:
    """Smallest step at which ``drops`` reaches ``threshold`` (linear between steps, 0 at 0)."""
    prev_s, prev_d = 0.0, 0.0
    for s, d in zip(steps, drops, strict=True):
        if d >= threshold:
            return prev_s + (s - prev_s) * (threshold - prev_d) / max(d - prev_d, 1e-12)
        prev_s, prev_d = s, max(prev_d, d)
    return float("inf")


def resolve(rewards: torch.Tensor | np.ndarray, drop_fraction: float = 0.005) -> AxisResolution:
    """Turns the rewards of the :func:`probe` candidates into per-axis resolutions.

    Args:
        rewards: ``[1 + 2·6·S]`` rewards in :func:`probe` order.
        drop_fraction: relative reward drop that counts as "the data tells these apart".
    """
    r = np.asarray(rewards, dtype=np.float64).reshape(-1)
    r0 = float(r[0])
    threshold = drop_fraction * max(r0, 1e-9)
    res = AxisResolution([], [], r0)
    i = 1
    for kind, steps in (("rot", ROTATION_STEPS_DEG), ("trans", TRANSLATION_STEPS_M)):
        for axis in AXES:
            pairs = r[i : i + 2 * len(steps)].reshape(len(steps), 2)
            i += 2 * len(steps)
            drops = r0 - pairs.mean(axis=1)
            res.drops[f"{kind} {axis}"] = [round(float(d), 6) for d in drops]
            if float(pairs.max()) > r0 + threshold:
                name = "rotation about" if kind == "rot" else "translation along"
                res.better.append(f"{name} LiDAR {axis}")
            width = _width(steps, drops, threshold)
            (res.rotation_deg if kind == "rot" else res.translation_m).append(width)
    return res


def undetermined(res: AxisResolution, rot_limit_deg: float, trans_limit_m: float) -> list[str]:
    """Human-readable names of the axes the data could not determine (or did not optimise)."""
    out = []
    for a, w in zip(AXES, res.rotation_deg, strict=True):
        if w > rot_limit_deg:
            txt = "flat" if np.isinf(w) else f"{w:.2f} deg"
            out.append(f"rotation about LiDAR {a} (resolution {txt})")
    for a, w in zip(AXES, res.translation_m, strict=True):
        if w > trans_limit_m:
            txt = "flat" if np.isinf(w) else f"{100 * w:.1f} cm"
            out.append(f"translation along LiDAR {a} (resolution {txt})")
    out += [f"{b}: a nearby extrinsic scores higher (not converged)" for b in res.better]
    return out
