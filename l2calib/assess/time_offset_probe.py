"""How sharply the data pins down the LiDAR–IMU time offset (the 7th axis of the probe).

Like :mod:`l2calib.assess.sensitivity` for the extrinsic: the calibrated offset (``t_imu = t_lidar +
time_offset_s``) is moved by a ladder of steps, both signs, with the calibrated ``T_imu_lidar``
kept, all in one batched backend call, and the **resolution** is the smallest step that lowers
the reward by ``drop_fraction`` of its value. No step doing so means the reward is flat along the
offset: the data (e.g. the slow turns of a UAV or a ground vehicle) could not determine it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from l2calib.assess.sensitivity import _width

#: Probe ladder (s): 1 ms resolves a well-excited hand-held recording; 30 ms shows a flat one.
OFFSET_STEPS_S = (0.001, 0.003, 0.01, 0.03)
#: Resolutions above this (s) name the offset as undetermined.
OFFSET_LIMIT_S = 0.01


@dataclass
class OffsetResolution:
    """Resolution of the time offset.

    Attributes:
        resolution_s: Smallest offset step (s) that lowers the reward by the threshold; ``inf``
            where the reward stays flat over the whole ladder.
        reward: Reward at the calibrated offset.
        drops: Mean reward drop over ± each step of :data:`OFFSET_STEPS_S`.
        better: Whether a probe step scored above the calibrated offset (not converged).
    """

    resolution_s: float
    reward: float
    drops: list[float] = field(default_factory=list)
    better: bool = False

    def undetermined(self) -> list[str]:
        """The offset's entry for ``uncertainty.undetermined`` (empty when it is resolved)."""
        out = []
        if self.resolution_s > OFFSET_LIMIT_S:
            txt = "flat" if np.isinf(self.resolution_s) else f"{1000 * self.resolution_s:.1f} ms"
            out.append(f"time offset (resolution {txt})")
        if self.better:
            out.append("time offset: a nearby offset scores higher (not converged)")
        return out

    def to_dict(self) -> dict[str, object]:
        """``calibration.yaml`` → ``time_offset.resolution_s`` / ``probe_drops``."""
        finite = np.isfinite(self.resolution_s)
        return {
            "resolution_s": round(float(self.resolution_s), 5) if finite else None,
            "probe_steps_s": list(OFFSET_STEPS_S),
            "probe_drops": [round(float(d), 6) for d in self.drops],
        }


def probe_offsets(time_offset_s: float) -> torch.Tensor:
    """``[1 + 2·S]`` float64 candidate offsets (s): the calibrated one first, then ± each step."""
    out = [time_offset_s]
    for step in OFFSET_STEPS_S:
        out += [time_offset_s + step, time_offset_s - step]
    return torch.tensor(out, dtype=torch.float64)


def resolve_offset(
    rewards: torch.Tensor | np.ndarray, drop_fraction: float = 0.005
) -> OffsetResolution:
    """Turns the rewards of the :func:`probe_offsets` candidates into the offset's resolution.

    Args:
        rewards: ``[1 + 2·S]`` rewards in :func:`probe_offsets` order.
        drop_fraction: Relative reward drop that counts as "the data tells these apart".
    """
    r = np.asarray(rewards, dtype=np.float64).reshape(-1)
    r0 = float(r[0])
    threshold = drop_fraction * max(r0, 1e-9)
    pairs = r[1:].reshape(len(OFFSET_STEPS_S), 2)
    drops = r0 - pairs.mean(axis=1)
    return OffsetResolution(
        _width(OFFSET_STEPS_S, drops, threshold),
        r0,
        [float(d) for d in drops],
        bool(pairs.max() > r0 + threshold),
    )


def probe_time_offset(env, T_imu_lidar: torch.Tensor, time_offset_s: float) -> OffsetResolution:
    """Scores the calibrated ``T_imu_lidar [4, 4]`` at the :func:`probe_offsets` offsets.

    Args:
        env: The open training env (see :func:`l2calib.train.env_build.score_batch`).
        T_imu_lidar: ``[4, 4]`` float64 calibrated extrinsic, kept for every candidate.
        time_offset_s: Calibrated offset (s, ``t_imu = t_lidar + time_offset_s``).

    Returns:
        The offset's resolution; ``len(OFFSET_STEPS_S) * 2 + 1`` evaluations.
    """
    from l2calib.train.env_build import score_batch

    offsets = probe_offsets(time_offset_s)
    T = torch.as_tensor(T_imu_lidar, dtype=torch.float64).expand(len(offsets), 4, 4).clone()
    return resolve_offset(score_batch(env, T, offsets).reward.detach().to(torch.float64))


def probe_evaluations() -> int:
    """Odometry evaluations of one :func:`probe_time_offset` call."""
    return 1 + 2 * len(OFFSET_STEPS_S)
