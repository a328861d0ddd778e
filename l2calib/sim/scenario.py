"""Runs a simulation in memory: :func:`simulate` turns a :class:`SimConfig` into a :class:`SimRun`.

Clocks: the IMU clock is true time ``τ``; LiDAR stamps are ``τ - time_offset_s`` (so
``t_imu = t_lidar + time_offset_s``). ``gt_imu`` is on the IMU clock, ``gt_lidar`` on the LiDAR
clock (compare a LiDAR-only odometry to it directly).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from l2calib.data import NS_PER_S, ImuSamples, InMemoryScans, LidarScan, Sequence
from l2calib.errors import ConfigError
from l2calib.sim.config import SimConfig
from l2calib.sim.imu_model import ImuErrors, ImuSpec, corrupt, get_imu
from l2calib.sim.lidar_models import LidarSpec, get_lidar
from l2calib.sim.motion import Motion
from l2calib.sim.profiles import build_motion, profile_params
from l2calib.sim.rigs import extrinsic_matrix
from l2calib.sim.scenes import make_world
from l2calib.sim.world import World
from l2calib.trajectory import Trajectory

__all__ = ["SimConfig", "SimRun", "simulate"]


@dataclass(eq=False)
class SimRun:
    """A simulated recording with its exact ground truth.

    Attributes:
        config: The resolved configuration (sensor models and extrinsic filled in).
        imu: IMU samples, SI units, IMU clock.
        scans: LiDAR scans, LiDAR frame, LiDAR clock (stamp = earliest point; ``offset_s``
            per point; dropouts and min/max range applied).
        gt_imu: Poses ``T_world_imu`` on the IMU clock (``body_frame="imu"``).
        gt_lidar: Poses ``T_world_lidar`` on the LiDAR clock (``body_frame="lidar"``).
        T_imu_lidar: ``[4, 4]`` ground-truth extrinsic.
        time_offset_s: Ground-truth offset (``t_imu = t_lidar + time_offset_s``).
        world: The world (``world.distance`` checks points against its surfaces).
        motion: The continuous-time trajectory (exact poses and derivatives at any time).
        lidar_spec: The LiDAR model used.
        imu_spec: The IMU model used.
        t0_ns: Absolute IMU-clock stamp of ``τ = 0`` (first IMU sample).
        scan_nominal_ns: ``[S, 2]`` nominal start and end of each sweep (LiDAR clock, ns): first
            and last firing time whether or not they returned (header stamps use these).
        scan_columns: Per scan, ``[P]`` column (spinning) or point index (livox) of each point.
        imu_errors: Biases and noise added to the IMU (``None`` if noise was off).
        stats: Summary numbers (mean |ω|, path length, ...).
    """

    config: SimConfig
    imu: ImuSamples
    scans: list[LidarScan]
    gt_imu: Trajectory
    gt_lidar: Trajectory
    T_imu_lidar: np.ndarray
    time_offset_s: float
    world: World
    motion: Motion
    lidar_spec: LidarSpec
    imu_spec: ImuSpec
    t0_ns: int
    scan_nominal_ns: np.ndarray
    scan_columns: list[np.ndarray]
    imu_errors: ImuErrors | None
    stats: dict[str, Any] = field(default_factory=dict)

    @property
    def offset_ns(self) -> int:
        """Time offset in integer ns."""
        return int(round(self.time_offset_s * NS_PER_S))

    def _tau(self, stamps_ns: np.ndarray, clock: str) -> np.ndarray:
        s = np.asarray(stamps_ns, dtype=np.int64) - self.t0_ns
        if clock == "lidar":
            s = s + self.offset_ns
        elif clock != "imu":
            raise ValueError(f"clock must be 'imu' or 'lidar', got {clock!r}")
        return s.astype(np.float64) / NS_PER_S

    def imu_poses(self, stamps_ns: np.ndarray, clock: str = "imu") -> np.ndarray:
        """Exact ``[N, 4, 4]`` ``T_world_imu`` at ``stamps_ns`` on ``clock`` (``imu``/``lidar``)."""
        st = self.motion.state(self._tau(stamps_ns, clock), order=0)
        return _poses(st.R_world_base @ self.T_imu_lidar[:3, :3].T, st.t_world_imu)

    def lidar_poses(self, stamps_ns: np.ndarray, clock: str = "lidar") -> np.ndarray:
        """Exact ``[N, 4, 4]`` ``T_world_lidar`` at ``stamps_ns`` on ``clock`` (default LiDAR)."""
        return self.imu_poses(stamps_ns, clock) @ self.T_imu_lidar

    def imu_velocity(self, stamps_ns: np.ndarray) -> np.ndarray:
        """Exact ``[N, 3]`` IMU velocity in the world frame (m/s), IMU clock."""
        return self.motion.state(self._tau(stamps_ns, "imu"), order=1).v_world_imu

    def sequence(self, name: str | None = None) -> Sequence:
        """The run as a :class:`~l2calib.data.Sequence` (scans held in memory)."""
        c = self.config
        name = name or f"sim-{c.world.name}-{c.motion.profile}-{c.seed}"
        meta = {
            "source": "l2calib.sim",
            "world": c.world.name,
            "profile": c.motion.profile,
            "lidar": c.lidar.model,
            "imu": c.imu.model,
            "seed": c.seed,
        }
        return Sequence(name, self.imu, InMemoryScans(list(self.scans)), meta)


def _poses(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.zeros((len(R), 4, 4))
    T[:, :3, :3], T[:, :3, 3], T[:, 3, 3] = R, t, 1.0
    return T


def _specs(cfg: SimConfig) -> tuple[LidarSpec, ImuSpec, float]:
    lo = cfg.lidar
    spec = get_lidar(lo.model)
    repl = {
        k: getattr(lo, k)
        for k in (
            "rate_hz",
            "range_noise_m",
            "dropout_prob",
            "spurious_prob",
            "min_range_m",
            "max_range_m",
        )
        if getattr(lo, k) is not None
    }
    if lo.columns is not None and spec.kind == "spinning":
        repl["columns"] = lo.columns
    spec = dataclasses.replace(spec, **repl)
    if spec.min_range_m >= spec.max_range_m:
        raise ConfigError(
            f"lidar.min_range_m ({spec.min_range_m}) must be below lidar.max_range_m "
            f"({spec.max_range_m})"
        )
    imu = get_imu(cfg.imu.model)
    return spec, imu, cfg.imu.rate_hz or imu.rate_hz


def _still_periods(cfg: SimConfig) -> list[tuple[float, float]]:
    still = [tuple(map(float, s)) for s in cfg.motion.still_segments]
    if cfg.motion.still_start_s > 0:
        still.append((0.0, cfg.motion.still_start_s))
    return still


def simulate(config: SimConfig, progress: bool = False) -> SimRun:
    """Simulates IMU samples and motion-distorted LiDAR scans with exact ground truth.

    Args:
        config: Settings (resolved against the rig preset internally).
        progress: Show a rich progress bar over the scans.

    Returns:
        The in-memory :class:`SimRun`.

    Raises:
        ConfigError: for inconsistent settings (rig does not fit the world, ...).
    """
    from l2calib.sim.sweep import check_clearance, imu_readings, sweep_scans, trajectories

    cfg = config.resolved()
    lidar, imu_spec, imu_rate = _specs(cfg)
    T = extrinsic_matrix(cfg.rig.translation_m, cfg.rig.rpy_deg)
    world = make_world(cfg.world.name, cfg.world.seed, path=cfg.world.route)
    rng = np.random.default_rng([cfg.seed, 1])
    lever = float(np.linalg.norm(T[:3, 3]))
    horizon = cfg.duration_s + abs(cfg.rig.time_offset_s) + 1.0
    motion = build_motion(
        world,
        profile_params(cfg.motion.profile, cfg.motion.excitation, cfg.motion.speed_scale),
        lever,
        horizon,
        _still_periods(cfg),
        rng,
    )
    clearance = check_clearance(world, motion, T, cfg.duration_s)
    t0_ns = int(round(cfg.start_time_s * NS_PER_S))
    imu, errors, stats = imu_readings(
        motion, T, imu_spec, imu_rate, cfg, t0_ns, np.random.default_rng([cfg.seed, 2]), corrupt
    )
    gt_imu, gt_lidar = trajectories(motion, T, cfg, t0_ns)
    scans, nominal, columns = sweep_scans(
        world, motion, T, lidar, cfg, t0_ns, np.random.default_rng([cfg.seed, 3]), progress
    )
    stats.update(
        scans=len(scans),
        points=int(sum(len(s) for s in scans)),
        imu_samples=len(imu),
        min_clearance_m=clearance,
        path_length_m=float(np.sum(np.linalg.norm(np.diff(gt_imu.t_world_body, axis=0), axis=1))),
    )
    return SimRun(
        cfg,
        imu,
        scans,
        gt_imu,
        gt_lidar,
        T,
        cfg.rig.time_offset_s,
        world,
        motion,
        lidar,
        imu_spec,
        t0_ns,
        nominal,
        columns,
        errors,
        stats,
    )
