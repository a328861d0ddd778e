"""Built-in LiDAR–IMU simulator with exact ground truth.

Procedural worlds (:mod:`~l2calib.sim.world`) are ray-cast with open3d by LiDAR models
(:mod:`~l2calib.sim.lidar_models`) moving along smooth continuous-time trajectories
(:mod:`~l2calib.sim.motion`); the IMU (:mod:`~l2calib.sim.imu_model`) is the exact derivative of the
same trajectory plus noise. :func:`simulate` returns everything in memory; :func:`write_run` writes
a ROS1/ROS2 bag with vendor-faithful messages next to the ground-truth files.

Example:
    >>> from l2calib.sim import SimConfig, simulate
    >>> run = simulate(SimConfig(duration_s=5.0))  # doctest: +SKIP
    >>> segment = run.sequence().segment()  # doctest: +SKIP
"""

from __future__ import annotations

from typing import Any

__all__ = ["SIMULATOR_VERSION", "SimConfig", "SimRun", "simulate", "write_run"]

#: Bumped when simulated data change for the same config and seed; recorded with benchmark rows
#: and in ``scenario.json``. 2 (2026-12-02): Velodyne/Hesai per-laser firing stagger, Ouster beam
#: azimuth offsets, 2 % spurious returns (:mod:`~l2calib.sim.lidar_models`).
SIMULATOR_VERSION = 2

_LAZY = {
    "SimConfig": "l2calib.sim.scenario",
    "SimRun": "l2calib.sim.scenario",
    "simulate": "l2calib.sim.scenario",
    "write_run": "l2calib.sim.outputs",
}


def __getattr__(name: str) -> Any:
    # Lazy re-exports: importing l2calib.sim stays cheap (no open3d / rosbags).
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'l2calib.sim' has no attribute {name!r}")
