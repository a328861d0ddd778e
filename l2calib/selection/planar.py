"""Planar, yaw-dominant motion (a ground vehicle) from the IMU alone.

A lever arm ``r`` (IMU → LiDAR) shows in the IMU's specific force only through the rig's
rotation: ``ω × (ω × r) + ω̇ × r``. When the rig turns about one axis ``u`` only (a car driving on
flat ground turns about the vertical), the part of ``r`` along ``u`` drops out of both terms, and
nothing else in a LiDAR-inertial odometry grades it: the LiDAR's trajectory moves by a constant
vertical offset, which the reward's alignment removes. That component is then not determined by
the data, and a search left free along it wanders (and drags the coupled axes with it).

:func:`planar_motion` finds the data's dominant rotation axis ``u`` (the principal eigenvector
of ``Σ ω ωᵀ`` over the turning samples, in the IMU frame) and the share of the rotation about it,
``λ_max / trace`` (= ``Σ (ω·u)² / Σ |ω|²``). ``u`` is what planar motion leaves undetermined,
whichever way the IMU is mounted; "up" (the mean specific force, gravity once the vehicle's
accelerations average out) only names it and signs it. On the simulator's 40 s runs the ground
vehicle (gently sloped ground, suspension sway) gives 0.998 (its axis 0.1–0.3° from the IMU's
z), the drone, which tilts to accelerate, 0.83–0.92, hand-held rigs 0.40–0.43;
``train.planar_min_yaw_share`` (0.97) sits between the first two
(``benchmarks/results/experiments/planar_shares.json``).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from l2calib.data import ImuSamples

#: Samples turning slower than this (rad/s) carry no rotation to judge (still, or noise).
MIN_RATE_RAD_S = 0.02
#: A turn, not sway: the rate about the dominant axis above which a sample counts as turning
#: for :attr:`PlanarMotion.one_way_share` (rad/s; 5.7 deg/s).
TURN_RATE_RAD_S = 0.1
#: Below this many turning samples the motion is not judged (too little rotation).
MIN_TURNING_SAMPLES = 100
#: From this :attr:`PlanarMotion.one_way_share` on, the turns count as all going one way (a
#: loop): ``inspect`` and the one-drive LiDAR-only caveat then say so.
ONE_WAY_SHARE = 0.9


@dataclass(frozen=True)
class PlanarMotion:
    """How much of the data's rotation is about the vertical.

    Attributes:
        axis_imu: ``[3]`` unit vector, the dominant rotation axis in the IMU frame, signed to
            point up (the side of the mean specific force).
        yaw_share: ``Σ (ω·axis)² / Σ |ω|²`` over the turning samples, in ``[0, 1]``.
        off_axis_rms_rad_s: RMS angular rate about the axes orthogonal to it (rad/s).
        turning_samples: IMU samples with ``|ω|`` above :data:`MIN_RATE_RAD_S`.
        tilt_deg: Angle between the axis and "up" (deg): about 0 for a vehicle on level
            ground, the mean slope on a hillside.
        one_way_share: ``|Σ ω·axis| / Σ |ω·axis|`` over the samples turning about the axis
            faster than :data:`TURN_RATE_RAD_S` (turns, not sway): 1 when every turn goes the
            same way (a loop), about 0 when the turns go both ways equally (a figure-8).
    """

    axis_imu: np.ndarray
    yaw_share: float
    off_axis_rms_rad_s: float
    turning_samples: int
    tilt_deg: float = 0.0
    one_way_share: float = 0.0

    def planar(self, min_yaw_share: float) -> bool:
        """Whether the motion is yaw-dominant enough to leave the vertical lever arm flat."""
        return self.turning_samples >= MIN_TURNING_SAMPLES and self.yaw_share >= min_yaw_share

    def describe(self) -> str:
        """One line for the user: the share and the off-axis rate."""
        return (
            f"{100 * self.yaw_share:.1f} % of the rotation is about one axis, "
            f"{self.tilt_deg:.1f} deg from the vertical (rate about the others "
            f"{self.off_axis_rms_rad_s:.3f} rad/s RMS)"
        )


def planar_motion(imus: Iterable[ImuSamples]) -> PlanarMotion:
    """Measures the dominant rotation axis and its share over all the given IMU samples.

    Args:
        imus: IMU samples of the data to judge (e.g. the selected segments'), IMU frame.

    Returns:
        A :class:`PlanarMotion`; with no turning sample its ``yaw_share`` is 0 and its axis
        "up".
    """
    gyro = [np.asarray(s.gyro_rad_s, dtype=np.float64) for s in imus]
    accel = [np.asarray(s.accel_m_s2, dtype=np.float64) for s in imus]
    w = np.concatenate(gyro) if gyro else np.zeros((0, 3))
    f = np.concatenate(accel) if accel else np.zeros((0, 3))
    mean_f = f.mean(axis=0) if len(f) else np.array([0.0, 0.0, 1.0])
    norm = float(np.linalg.norm(mean_f))
    up = mean_f / norm if norm > 0 else np.array([0.0, 0.0, 1.0])
    turning = w[np.linalg.norm(w, axis=1) > MIN_RATE_RAD_S]
    if len(turning) == 0:
        return PlanarMotion(up, 0.0, 0.0, 0)
    evals, evecs = np.linalg.eigh(turning.T @ turning)  # ascending
    axis = evecs[:, 2] if evecs[:, 2] @ up >= 0 else -evecs[:, 2]
    about = turning @ axis
    off = turning - about[:, None] * axis[None]
    turns = about[np.abs(about) > TURN_RATE_RAD_S]
    one_way = float(abs(turns.sum()) / np.abs(turns).sum()) if len(turns) else 0.0
    return PlanarMotion(
        axis_imu=axis,
        yaw_share=float(evals[2] / max(float(evals.sum()), 1e-300)),
        off_axis_rms_rad_s=float(np.sqrt(np.mean(np.sum(off**2, axis=1)))),
        turning_samples=int(len(turning)),
        tilt_deg=float(np.degrees(np.arccos(np.clip(axis @ up, -1.0, 1.0)))),
        one_way_share=one_way,
    )


def planar_selection(selection: Any, min_yaw_share: float, imus: Iterable[ImuSamples]):
    """The selection settings for this data: widened on planar motion (a ground vehicle).

    A hand-held budget (tens of seconds in short windows) keeps too few of a drive's turns, and
    the turns are what determine the horizontal lever arm (module docstring); so on planar,
    yaw-dominant motion the budget becomes at least ``selection.planar_budget_s`` and the
    windows at least ``selection.planar_window_s`` long.

    Args:
        selection: The recipe's ``selection`` (:class:`~l2calib.recipe.SelectionConfig`).
        min_yaw_share: ``train.planar_min_yaw_share``.
        imus: IMU samples of all the recordings (IMU frame).

    Returns:
        The settings to select with, and a note for the user (``None`` when unchanged).
    """
    if selection.planar_budget_s is None:
        return selection, None
    motion = planar_motion(imus)
    if not motion.planar(min_yaw_share):
        return selection, None
    budget = max(selection.budget_s, selection.planar_budget_s)
    window = max(selection.window_s, selection.planar_window_s)
    if (budget, window) == (selection.budget_s, selection.window_s):
        return selection, None
    note = (
        f"planar, yaw-dominant motion ({motion.describe()}): the selection keeps up to "
        f"{budget:g} s in windows of {window:g} s (recipe: {selection.budget_s:g} s, "
        f"{selection.window_s:g} s), since a drive's few turns are what determine the "
        "horizontal lever arm (selection.planar_budget_s, planar_window_s; null keeps the "
        "recipe's)"
    )
    return selection.model_copy(update={"budget_s": budget, "window_s": window}), note
