"""The per-axis uncertainty stage at a calibrated result, and the axes the data left undetermined.

:func:`bounds_at_result` runs :mod:`l2calib.assess.uncertainty`'s stencil on the open training
env (or any scoring env of the same data) and adds what the bounds are known not to cover;
:func:`undetermined_axes` turns the bounds (or, with the stage off, the resolution probe and the
selection) into the axes a calibration names as undetermined. Called by
:func:`l2calib.training.train_policy` after the refinement and by
:mod:`benchmarks.bench_uncertainty` on stored results.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["bounds_at_result", "estimate_axis_uncertainty", "undetermined_axes"]


def undetermined_axes(
    resolution: Any,
    selection: Any | None,
    axis_uncertainty: Any | None = None,
    limits: Any | None = None,
    rot_limit_deg: float = 1.0,
    trans_limit_m: float = 0.05,
) -> list[str]:
    """Axes the data could not determine.

    With the per-axis uncertainty (:mod:`l2calib.assess.uncertainty`): axes whose 95 % bound
    exceeds ``limits`` (``train.uncertainty``) or along which the reward is flat, and axes where
    the resolution probe found a better extrinsic nearby. Without it (``train.uncertainty.
    enabled: false``): the resolution probe's flat or wide axes and the selection's weakly
    excited ones, as before.
    """
    from l2calib.assess import sensitivity, uncertainty

    if axis_uncertainty is None:
        out = sensitivity.undetermined(resolution, rot_limit_deg, trans_limit_m)
        if selection is not None:
            out += [f"weakly excited: {w}" for w in selection.weak_axes]
        return out
    out = uncertainty.undetermined(
        axis_uncertainty, limits.rotation_limit_deg, limits.translation_limit_m,
        limits.time_offset_limit_ms / 1000,
    )  # fmt: skip
    better = [f"{b}: a nearby extrinsic scores higher (not converged)" for b in resolution.better]
    return out + better


def estimate_axis_uncertainty(env, T_imu_lidar, estimated_offset_s, hold, config):
    """Per-axis 95 % bounds at the result (:mod:`l2calib.assess.uncertainty`) on the open env.

    Args:
        env: The open training env (or any scoring env of the same data).
        T_imu_lidar: ``[4, 4]`` the calibrated extrinsic.
        estimated_offset_s: The estimated time offset (s), a seventh axis; ``None`` when it was
            not estimated (a held or known offset is the env's own).
        hold: The vertical lever-arm hold, or ``None``.
        config: ``train.uncertainty`` (block length and the limits recorded with the bounds).

    Returns:
        The :class:`~l2calib.assess.uncertainty.AxisUncertainty` (``evaluations``: odometry
        runs it took).
    """
    from l2calib.assess import uncertainty
    from l2calib.train.env_build import block_costs

    T, offsets = uncertainty.candidates(T_imu_lidar, estimated_offset_s)
    costs = block_costs(env, T, offsets, config.block_s)
    held_axis = None
    if hold is not None:  # the LiDAR axis nearest the held (vertical) direction
        up_lidar = np.asarray(T_imu_lidar, dtype=np.float64)[:3, :3].T @ np.asarray(hold.axis_imu)
        held_axis = 3 + int(np.argmax(np.abs(up_lidar)))
    tau = uncertainty.correlation_time(costs.centre)  # the stencil's first candidate: the result
    out = uncertainty.estimate(
        costs.costs, costs.scans, held_axis=held_axis, tau=tau,
        alternative_costs=costs.alternative,
    )  # fmt: skip
    out.evaluations = int(T.shape[0])
    out.limits = (
        config.rotation_limit_deg,
        config.translation_limit_m,
        config.time_offset_limit_ms / 1000,
    )
    return out


def bounds_at_result(env, T_imu_lidar, estimated_offset_s, hold, config, segments):
    """:func:`estimate_axis_uncertainty` with its caveats set (what the bounds do not cover).

    Args:
        env: The open training env (or any scoring env of the same data).
        T_imu_lidar: ``[4, 4]`` the calibrated extrinsic.
        estimated_offset_s: The estimated time offset (s), or ``None`` (not estimated).
        hold: The vertical lever-arm hold, or ``None``.
        config: ``train.uncertainty``.
        segments: The selected segments (``sequence``: the recording each comes from).

    Returns:
        The :class:`~l2calib.assess.uncertainty.AxisUncertainty`, ``caveats`` set
        (:func:`~l2calib.assess.uncertainty.reference_caveats`).
    """
    from l2calib.assess import uncertainty

    out = estimate_axis_uncertainty(env, T_imu_lidar, estimated_offset_s, hold, config)
    drives = len({seg.sequence for seg in segments})
    one_way = None if hold is None else hold.motion.one_way_share
    out.caveats = uncertainty.reference_caveats(out, drives, one_way)
    return out
