"""Holding the lever arm's vertical component where planar motion cannot determine it.

On a ground vehicle's drive nearly all rotation is about the vertical, so the component of the
IMU → LiDAR translation along the vertical leaves the reward flat (:mod:`l2calib.selection.
planar`). Left in the search, PPO's mean wanders along it (its spread never narrows, so PPO also
never hands over): a ground-vehicle run with the LiDAR-only reference ended 2.85 m off along z
(``benchmarks/results/experiments/ugv_before_hold.json``; its 13–17 cm in x / y came mostly from
the shared reference map over several runs, fixed since: ``docs/references.md``).

:class:`VerticalHold` replaces that component of every candidate before the odometry runs, so the
reward, the refinement, the probe and the written result all see the held value: the prior's
(``policy.prior``, e.g. from a drawing) or, without a prior, 0 m — named in the output as not
estimated, never passed off as a measurement. ``train.hold_vertical_translation`` chooses:
``auto`` (hold on planar motion), ``on`` (always hold, e.g. with a prior from a drawing), ``off``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch

from l2calib.selection.planar import PlanarMotion, planar_motion


@dataclass(frozen=True)
class VerticalHold:
    """The vertical lever-arm component every candidate is given.

    Attributes:
        axis_imu: The held direction, a unit vector in the IMU frame ``(x, y, z)``: the data's
            dominant rotation axis (signed up; :mod:`l2calib.selection.planar`).
        value_m: The held value of ``t_imu_lidar · axis_imu`` (m).
        source: ``"prior"`` (policy.prior) or ``"none"`` (no prior: 0 m, not a measurement).
        motion: What the IMU said about the motion (:class:`PlanarMotion`).
    """

    axis_imu: tuple[float, float, float]
    value_m: float
    source: str
    motion: PlanarMotion

    def _axis(self, like: torch.Tensor) -> torch.Tensor:
        return torch.tensor(self.axis_imu, dtype=like.dtype, device=like.device)

    def apply(self, T_imu_lidar: torch.Tensor) -> torch.Tensor:
        """Candidates ``[..., 4, 4]`` with their vertical translation set to ``value_m``."""
        u = self._axis(T_imu_lidar)
        t = T_imu_lidar[..., :3, 3]
        out = T_imu_lidar.clone()
        out[..., :3, 3] = t + (self.value_m - t @ u)[..., None] * u
        return out

    def spread(self, sigma_m: torch.Tensor) -> torch.Tensor:
        """Per-IMU-axis σ ``[3]`` (m) of the translations scored, from the policy's ``[3]``.

        The policy's spread along the held direction never narrows (the reward cannot grade
        it); what the odometry sees is the projection ``P Σ P`` with ``P = I − u uᵀ``.
        """
        u = self._axis(sigma_m)
        P = torch.eye(3, dtype=sigma_m.dtype) - torch.outer(u, u)
        cov = P @ torch.diag(sigma_m**2) @ P
        return torch.sqrt(torch.clamp(torch.diagonal(cov), min=0.0))

    def policy_spread(self, spread: Any) -> Any:
        """A :class:`~l2calib.interfaces.PolicySpread` with :meth:`spread` as translation σ."""
        return replace(spread, translation_sigma_m=self.spread(spread.translation_sigma_m))

    def describe(self) -> str:
        """The output's entry under ``uncertainty.undetermined``."""
        axis = ", ".join(f"{v:+.2f}" for v in self.axis_imu)
        where = (
            "policy.prior's value"
            if self.source == "prior"
            else "no prior was given, so this is NOT a measurement: measure the height "
            "difference from a drawing and set policy.prior"
        )
        return (
            f"translation along the rotation axis [{axis}] (IMU frame; the vertical): not "
            f"estimated, held at "
            f"{100 * self.value_m:.1f} cm ({where}); planar motion cannot determine it "
            f"({self.motion.describe()}); driving over ramps or kerbs, or tilting the rig, "
            "would"
        )

    def to_dict(self) -> dict[str, Any]:
        """``calibration.yaml`` → ``vertical_hold``."""
        return {
            "axis_imu": [round(float(v), 5) for v in self.axis_imu],
            "value_m": round(float(self.value_m), 5),
            "source": self.source,
            "yaw_share": round(self.motion.yaw_share, 4),
            "tilt_from_vertical_deg": round(self.motion.tilt_deg, 2),
            "off_axis_rms_rad_s": round(self.motion.off_axis_rms_rad_s, 4),
            "meaning": "t_imu_lidar . axis_imu is held at value_m, not estimated",
        }


def decide_hold(train: Any, prior: Any | None, imus: list[Any]) -> VerticalHold | None:
    """Whether (and where) to hold the vertical lever arm for this data.

    Args:
        train: The recipe's ``train`` (``hold_vertical_translation``, ``planar_min_yaw_share``).
        prior: The recipe's ``policy.prior`` or ``None``.
        imus: IMU samples of the data calibrated on (the selected segments').

    Returns:
        The hold, or ``None`` (``off``; or ``auto`` on motion that is not planar).
    """
    mode = train.hold_vertical_translation
    if mode == "off":
        return None
    motion = planar_motion(imus)
    if mode == "auto" and not motion.planar(train.planar_min_yaw_share):
        return None
    axis = motion.axis_imu
    value, source = 0.0, "none"
    if prior is not None:
        value, source = float(np.dot(np.asarray(prior.translation_m, dtype=float), axis)), "prior"
    return VerticalHold(tuple(float(v) for v in axis), value, source, motion)


#: Training settings for planar motion, unless the recipe sets them: 8 rounds of the Newton
#: polish from a quarter-width stencil. Rotation and lever-arm errors compensate along a ridge
#: of the planar reward that the per-axis refinement stops on (issue 27, docs/backends.md); on
#: "ugv all" (three drives, gt reference, training seeds 0-2) x / y went from 2.43 / 1.01,
#: 0.99 / 0.30, 1.76 / 0.97 cm and 0.19-0.77 deg to 0.07 / 1.56, 0.95 / 0.71, 0.76 / 0.66 cm and
#: 0.34, 0.07, 0.02 deg, for 816 more evaluations.
PLANAR_TRAIN: dict[str, Any] = {
    "polish_rounds": 8,
    "polish_first_scale": 0.25,
}
#: Also when PPO's rotation starts uniform (a restart, ``train.rotation_from_rates: off``, a
#: ``policy.prior``, or rates that do not fit): PPO runs its budget (no hand-over) and the
#: refinement climbs 6 rounds. From a uniform start with the default hand-over, PPO handed over
#: after 78 iterations on the simulator's ground vehicle and the refinement left 1.32 deg (gt
#: reference, training seed 0; a scratch run, not stored); with these settings the same seed gave
#: 0.23 deg. Started at the rate rotation (:mod:`l2calib.train.rotation_start`) PPO keeps the
#: default hand-over: on "ugv all" (training seeds 1, 2) it handed over after 25 and 14
#: iterations at x / y 1.44 / 0.21 cm and 0.068 / 0.120 deg with 1,948 / 1,596 evaluations
#: (the budget's settings: 0.95 / 0.71 and 0.76 / 0.66 cm, 0.07 / 0.02 deg with 5,759); with
#: the translation start too, after one iteration (seed 1: 0.89 / 0.29 cm, 0.037 deg, 1,180)
#: (``benchmarks/results/experiments/speed_starts.json``).
PLANAR_UNIFORM_START: dict[str, Any] = {
    "handover_rotation_sigma_deg": None,
    "refine_rounds": 6,
}


#: Started at the rate rotation, the policy is born narrower than the hand-over's 2.5 deg / 20 cm
#: and handed over after one PPO iteration with its time offset's σ still at the start's 20 ms:
#: on 20 s of three drives from the LiDAR alone ("ugv all ct-lidar") the refinement then climbed a
#: ridge of offset, yaw and lateral lever arm (training seed 2: -5.5 ms, 0.64 deg, 5.9 cm). Waiting
#: for the offset's σ <= 10 ms (half the start; five times the refinement's first offset step)
#: PPO ran 8-14 iterations and seeds 0-2 came out at x / y 0.88 / 0.83, 1.01 / 2.05,
#: 1.01 / 2.03 cm, 0.09-0.12 deg, 1,404-1,596 evaluations against 1,180
#: (``benchmarks/results/experiments/handover_time_offset.json``, docs/backends.md).
PLANAR_RATE_START: dict[str, Any] = {
    "handover_time_offset_sigma_s": 0.01,
}


def planar_train_settings(train: Any, rate_start: bool = False) -> tuple[Any, dict[str, Any]]:
    """``train`` with the planar settings where the recipe left them at their defaults.

    Args:
        train: The recipe's ``train``.
        rate_start: PPO's rotation starts at the rate rotation (else uniform, or at a prior):
            :data:`PLANAR_TRAIN` and :data:`PLANAR_RATE_START`; otherwise
            :data:`PLANAR_UNIFORM_START` (no hand-over) and :data:`PLANAR_TRAIN`.

    Returns:
        The settings to train with, and what was changed (empty when the recipe set them all).
    """
    wanted = (
        {**PLANAR_TRAIN, **PLANAR_RATE_START}
        if rate_start
        else {**PLANAR_UNIFORM_START, **PLANAR_TRAIN}
    )
    changed = {k: v for k, v in wanted.items() if k not in train.model_fields_set}
    return train.model_copy(update=changed), changed
