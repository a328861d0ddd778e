from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from imu_signals import imu_signal
from io_bagkit import PERIOD_NS, T0, Msgs, header_for, vendor_points, write_bag


@dataclass
class Scene:
    path: Path
    truth: list[tuple[np.ndarray, np.ndarray]]  # per scan: valid xyz [P,3], t_ns [P]
    imu: tuple[np.ndarray, np.ndarray, np.ndarray]


def make_scene(
    tmp_path: Path,
    vendor: str = "ouster",
    storage: str = "ros1",
    n_scans: int = 12,
    n_points: int = 300,
    imu_rate: float = 200.0,
    gyro_scale: float = 1.0,
    accel_scale: float = 1.0,
    imu_offset_s: float = 0.0,
    imu_drop: tuple[float, float] | None = None,
    lidar_topic: str = "/points",
    imu_topic: str = "/imu",
    extra: list | None = None,
    empty_scans: tuple[int, ...] = (),
    drop_scans: tuple[int, ...] = (),
    imu_kw: dict | None = None,
    seed: int = 0,
) -> Scene:
    """A tiny bag: ``n_scans`` 10 Hz scans (some NaN and zero points) plus a rotating IMU."""
    rng = np.random.default_rng(seed)
    m = Msgs(storage != "ros1")
    msgs, truth = [], []
    duration = n_scans * PERIOD_NS / 1e9 + 0.3
    st, gyro, acc = imu_signal(
        duration, imu_rate, start_ns=T0 - 100_000_000, seed=seed, **(imu_kw or {})
    )
    st = st + int(imu_offset_s * 1e9)
    keep = np.ones(len(st), bool)
    if imu_drop is not None:
        rel = (st - st[0]) / 1e9
        keep = ~((rel > imu_drop[0]) & (rel < imu_drop[1]))
    for s, g, a in zip(st[keep], gyro[keep], acc[keep], strict=True):
        msgs.append(
            (
                imu_topic,
                "sensor_msgs/msg/Imu",
                s + 1_000_000,
                m.imu(s, g * gyro_scale, a * accel_scale),
            )
        )
    for k in range(n_scans):
        start = T0 + k * PERIOD_NS
        t = start + np.sort(rng.integers(0, PERIOD_NS - 1_000_000, n_points))
        xyz = rng.uniform(-20, 20, (n_points, 3)).astype(np.float32)
        bad = rng.random(n_points) < 0.1
        zero = (rng.random(n_points) < 0.1) & ~bad
        xyz[bad, rng.integers(0, 3)] = np.nan
        xyz[zero] = 0.0
        if k in empty_scans:
            xyz[:] = np.nan
            bad[:] = True
        valid = ~bad & ~zero
        truth.append((xyz[valid], t[valid]))
        ring = (np.arange(n_points) % 16).astype(np.uint16)
        if vendor == "custom":
            base = int(t.min())
            msg = m.livox_custom(base, base, xyz, t - base)
            mtype = "livox_ros_driver/msg/CustomMsg"
        else:
            h = header_for(vendor, t)
            msg = m.cloud(h, vendor_points(vendor, xyz, t, h, ring))
            mtype = "sensor_msgs/msg/PointCloud2"
        if k not in drop_scans:
            msgs.append((lidar_topic, mtype, int(t.max()) + 5_000_000, msg))
    msgs += extra or []
    path = write_bag(tmp_path / f"{vendor}_{storage}", storage, msgs)
    return Scene(path, truth, (st, gyro, acc))
