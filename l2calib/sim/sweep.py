"""Sensor generation: IMU readings, ground-truth trajectories and motion-distorted LiDAR sweeps.

Time bookkeeping is in integer nanoseconds relative to ``t0_ns`` (the first IMU sample); the
physical time ``τ`` of a LiDAR firing is its LiDAR-clock stamp plus the time offset.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from l2calib.data import NS_PER_S, ImuSamples, LidarScan
from l2calib.errors import ConfigError
from l2calib.sim.config import SimConfig
from l2calib.sim.imu_model import ImuErrors, ImuSpec
from l2calib.sim.lidar_models import LidarSpec, livox_pattern, returns, spinning_pattern
from l2calib.sim.motion import Motion
from l2calib.sim.world import World
from l2calib.trajectory import Trajectory


def _grid_ns(rate_hz: float, lo_ns: int, hi_ns: int) -> np.ndarray:
    """Integer-ns stamps ``round(k / rate)`` lying in ``[lo_ns, hi_ns]``."""
    k0 = int(np.ceil(lo_ns * rate_hz / NS_PER_S - 1e-9))
    k1 = int(np.floor(hi_ns * rate_hz / NS_PER_S + 1e-9))
    return np.round(np.arange(k0, k1 + 1) * (NS_PER_S / rate_hz)).astype(np.int64)


def _imu_pose(motion: Motion, T: np.ndarray, tau: np.ndarray, order: int = 0):
    st = motion.state(tau, order)
    return st, st.R_world_base @ T[:3, :3].T


def imu_readings(
    motion: Motion,
    T: np.ndarray,
    spec: ImuSpec,
    rate_hz: float,
    cfg: SimConfig,
    t0_ns: int,
    rng: np.random.Generator,
    corrupt: Callable[..., tuple[np.ndarray, np.ndarray, ImuErrors]],
) -> tuple[ImuSamples, ImuErrors | None, dict]:
    """IMU samples on the IMU clock over ``[0, duration]`` and motion statistics."""
    rel = _grid_ns(rate_hz, 0, int(round(cfg.duration_s * NS_PER_S)))
    tau = rel / NS_PER_S
    gyro, accel, speed, kin = [], [], [], []
    g = np.array([0.0, 0.0, -cfg.gravity_m_s2])
    for chunk in np.array_split(tau, max(len(tau) // 20000, 1)):
        st, R_wi = _imu_pose(motion, T, chunk, order=2)
        gyro.append(st.omega_base @ T[:3, :3].T)  # ω_imu = R_imu_lidar ω_base
        accel.append(np.einsum("nji,nj->ni", R_wi, st.a_world_imu - g))  # R_imu_world (a - g)
        speed.append(np.linalg.norm(st.v_world_imu, axis=1))
        kin.append(np.linalg.norm(st.a_world_imu, axis=1))
    gyro_t, accel_t = np.concatenate(gyro), np.concatenate(accel)
    wnorm = np.linalg.norm(gyro_t, axis=1)
    moving = motion.window(tau) > 0.5
    stats = {
        "mean_abs_omega_rad_s": float(wnorm.mean()),
        "mean_abs_omega_moving_rad_s": float(wnorm[moving].mean()) if moving.any() else 0.0,
        "max_abs_omega_rad_s": float(wnorm.max()),
        "mean_abs_accel_m_s2": float(np.concatenate(kin).mean()),
        "max_abs_accel_m_s2": float(np.concatenate(kin).max()),
        "mean_speed_m_s": float(np.concatenate(speed).mean()),
    }
    errors = None
    if cfg.imu.noise:
        gyro_t, accel_t, errors = corrupt(spec, rate_hz, gyro_t, accel_t, rng)
    return ImuSamples(t0_ns + rel, gyro_t, accel_t), errors, stats


def trajectories(
    motion: Motion, T: np.ndarray, cfg: SimConfig, t0_ns: int
) -> tuple[Trajectory, Trajectory]:
    """Dense ground truth: ``gt_imu`` on the IMU clock, ``gt_lidar`` on the LiDAR clock."""
    dur_ns = int(round(cfg.duration_s * NS_PER_S))
    off_ns = int(round(cfg.rig.time_offset_s * NS_PER_S))
    rel_i = _grid_ns(cfg.gt_rate_hz, 0, dur_ns)
    st, R_wi = _imu_pose(motion, T, rel_i / NS_PER_S)
    T_wi = np.zeros((len(rel_i), 4, 4))
    T_wi[:, :3, :3], T_wi[:, :3, 3], T_wi[:, 3, 3] = R_wi, st.t_world_imu, 1.0
    gt_imu = Trajectory.from_matrices(t0_ns + rel_i, T_wi, "imu")
    rel_l = _grid_ns(cfg.gt_rate_hz, -off_ns, dur_ns - off_ns)
    st, R_wi = _imu_pose(motion, T, (rel_l + off_ns) / NS_PER_S)
    T_wl = np.zeros((len(rel_l), 4, 4))
    T_wl[:, :3, :3], T_wl[:, :3, 3], T_wl[:, 3, 3] = R_wi, st.t_world_imu, 1.0
    gt_lidar = Trajectory.from_matrices(t0_ns + rel_l, T_wl @ T, "lidar")
    return gt_imu, gt_lidar


def check_clearance(world: World, motion: Motion, T: np.ndarray, duration_s: float) -> float:
    """Smallest distance (m) of the IMU or LiDAR origin to any surface, sampled at 20 Hz.

    Raises:
        ConfigError: if the rig comes closer than half the world's clearance.
    """
    tau = np.arange(0.0, duration_s, 0.05)
    st, R_wi = _imu_pose(motion, T, tau)
    lidar = st.t_world_imu + R_wi @ T[:3, 3]
    d = np.minimum(world.distance(st.t_world_imu), world.distance(lidar))
    if d.min() < world.clearance_m / 2:
        i = int(np.argmin(d))
        raise ConfigError(
            f"the simulated rig passes {d[i]:.2f} m from a surface of the {world.name} world at "
            f"t = {tau[i]:.1f} s",
            fix="use another seed, a smaller lever arm or a lower motion excitation",
        )
    return float(d.min())


def sweep_scans(
    world: World,
    motion: Motion,
    T: np.ndarray,
    spec: LidarSpec,
    cfg: SimConfig,
    t0_ns: int,
    rng: np.random.Generator,
    progress: bool = False,
) -> tuple[list[LidarScan], np.ndarray, list[np.ndarray]]:
    """Ray-casts every sweep, each firing from the LiDAR pose at its own time.

    Returns:
        Scans (empty sweeps skipped), ``[S, 2]`` nominal start/end stamps (LiDAR clock, ns) and
        per-scan column indices of the points.
    """
    period_ns = int(round(NS_PER_S / spec.rate_hz))
    off_ns = int(round(cfg.rig.time_offset_s * NS_PER_S))
    dur_ns = int(round(cfg.duration_s * NS_PER_S))
    k_first = int(np.ceil(-off_ns / period_ns))
    k_last = (dur_ns - off_ns - period_ns) // period_ns
    if k_last < k_first:
        raise ConfigError(
            f"duration_s={cfg.duration_s} holds no complete LiDAR sweep",
            fix=f"simulate at least {2 * spec.period_s:.2f} s",
        )
    fixed = spinning_pattern(spec) if spec.kind == "spinning" else None
    R_li = T[:3, :3].T
    lever = R_li @ T[:3, 3]  # LiDAR origin relative to the IMU, in the base (LiDAR) frame
    scans, nominal, columns = [], [], []
    ks = range(k_first, k_last + 1)
    for k in _track(ks, progress, f"sweeping {spec.name}"):
        pat = fixed if fixed is not None else livox_pattern(spec, k - k_first)
        ut_ns = np.round(pat.unique_times * NS_PER_S).astype(np.int64)
        base_ns = k * period_ns
        st = motion.state((base_ns + ut_ns + off_ns) / NS_PER_S, order=0)
        R_wl = st.R_world_base[pat.time_index]
        d_world = np.einsum("pij,pj->pi", R_wl, pat.directions)
        origin = (st.t_world_imu + st.R_world_base @ lever)[pat.time_index]
        rng_true, tri, normal = world.cast(origin, d_world)
        hit = tri >= 0
        cos = np.zeros(len(tri))
        cos[hit] = np.abs(np.einsum("pi,pi->p", normal[hit], d_world[hit]))
        refl = np.where(hit, world.reflectivity[np.maximum(tri, 0)], 0.0)
        valid, meas, intensity = returns(spec, rng_true, cos, refl, rng, noise=cfg.lidar.noise)
        if not valid.any():
            continue
        nominal.append((t0_ns + base_ns + ut_ns[0], t0_ns + base_ns + ut_ns[-1]))
        p_ns = ut_ns[pat.time_index[valid]]
        first = int(p_ns.min())
        scans.append(
            LidarScan(
                stamp_ns=t0_ns + base_ns + first,
                points_lidar=(pat.directions[valid] * meas[valid, None]).astype(np.float32),
                offset_s=(p_ns - first) / NS_PER_S,
                intensity=intensity[valid],
                ring=pat.ring[valid],
            )
        )
        columns.append(pat.column[valid])
    nominal_arr = np.array(nominal, dtype=np.int64).reshape(-1, 2)
    return scans, nominal_arr, columns


def _track(items, progress: bool, label: str):
    if not progress:
        return items
    from rich.progress import track

    return track(items, description=label, transient=False)
