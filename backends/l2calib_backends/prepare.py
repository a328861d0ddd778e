"""One-off preparation of segments for the IEKF: downsampled scans as padded tensors.

Everything here is independent of the candidate extrinsic, so it runs once per calibration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from l2calib.data import LidarScan, Segment
from l2calib.errors import BackendError
from l2calib.references.ct_map import voxel_keys, voxel_pick
from l2calib_backends.propagation import ImuTensors

NS = 1e-9


@dataclass(frozen=True)
class ScanTensors:
    """Padded per-scan points.

    ``points [N, m, 3]`` (LiDAR frame), ``dt_end [N, m]`` (s before the scan end),
    ``mask [N, m]`` and ``ranges [N, m]`` (m).
    """

    points: Tensor
    dt_end: Tensor
    mask: Tensor
    ranges: Tensor


@dataclass(frozen=True)
class PreparedSegment:
    """A segment ready for filtering.

    Attributes:
        name: Segment name.
        start_ns: Time origin of the segment-relative float seconds used inside the filter.
        end_stamps_ns: ``[N]`` scan end stamps (ns, LiDAR clock).
        end_t: ``[N]`` the same in segment-relative seconds.
        imu: IMU samples in segment-relative seconds (IMU clock).
        update: Points used in the measurement update.
        insert: Denser points inserted into per-candidate maps (odometry mode).
    """

    name: str
    start_ns: int
    end_stamps_ns: np.ndarray
    end_t: Tensor
    imu: ImuTensors
    update: ScanTensors
    insert: ScanTensors


def voxel_means(points: np.ndarray, voxel_m: float, *values: np.ndarray) -> list[np.ndarray]:
    """The mean of ``points`` ``[N, 3]`` and of each ``values`` ``[N, ...]`` per voxel.

    As PCL's ``VoxelGrid`` (FAST-LIO's downsampling): one point per occupied voxel, the
    centroid of its points, with their mean time where a time is among ``values``.
    """
    _, inv, counts = np.unique(voxel_keys(points, voxel_m), return_inverse=True, return_counts=True)
    out = []
    for v in (points, *values):
        flat = v.reshape(len(v), -1)
        sums = np.zeros((len(counts), flat.shape[1]))
        np.add.at(sums, inv.ravel(), flat)
        out.append((sums / counts[:, None]).reshape((len(counts), *v.shape[1:])))
    return out


def _voxel_subsample(
    scan: LidarScan,
    voxel: float,
    limit: int,
    rng: np.random.Generator,
    r_min: float,
    r_max: float,
    voxel_point: str,
) -> tuple[np.ndarray, np.ndarray]:
    pts = np.asarray(scan.points_lidar, dtype=np.float64)
    off = np.asarray(scan.offset_s, dtype=np.float64)
    rng_m = np.linalg.norm(pts, axis=1)
    keep = np.isfinite(rng_m) & (rng_m >= r_min) & (rng_m <= r_max)
    pts, off = pts[keep], off[keep]
    if len(pts) == 0:
        return pts, off
    if voxel_point == "centroid":
        pts, off = voxel_means(pts, voxel, off)
        first = np.argsort(off, kind="stable")
    else:
        first = voxel_pick(pts, voxel, rng if voxel_point == "random" else None)
    if len(first) > limit:
        first = rng.choice(first, size=limit, replace=False)
    first.sort()
    return pts[first], off[first]


def _pad(items: list[tuple[np.ndarray, np.ndarray]], ends: np.ndarray, m: int) -> ScanTensors:
    n = len(items)
    points = np.zeros((n, m, 3))
    dt_end = np.zeros((n, m))
    mask = np.zeros((n, m), dtype=bool)
    for i, (p, off) in enumerate(items):
        k = min(len(p), m)
        points[i, :k] = p[:k]
        dt_end[i, :k] = np.maximum(ends[i] - off[:k], 0.0)
        mask[i, :k] = True
    ranges = np.linalg.norm(points, axis=-1)
    return ScanTensors(
        torch.from_numpy(points),
        torch.from_numpy(dt_end),
        torch.from_numpy(mask),
        torch.from_numpy(ranges),
    )


def prepare_segment(
    seg: Segment,
    scan_voxel_m: float,
    points_per_scan: int,
    map_points_per_scan: int,
    min_range_m: float,
    max_range_m: float,
    seed: int,
    voxel_point: str = "earliest",
) -> PreparedSegment:
    """Downsamples the scans of ``seg`` and packs scans and IMU into tensors.

    ``voxel_point``: what each voxel keeps — ``earliest`` (the first point fired), ``random``
    (a random point, seeded) or ``centroid`` (the mean of its points and of their times).
    """
    scans = seg.scans
    if len(scans) < 3:
        raise BackendError(
            f"segment {seg.name} has {len(scans)} LiDAR scans; the odometry needs at least 3",
            fix="use longer segments (selection.window_s) or check the LiDAR topic",
        )
    if len(seg.imu) < 10:
        raise BackendError(f"segment {seg.name} has only {len(seg.imu)} IMU samples")
    rng = np.random.default_rng(seed)
    ends_rel = np.array([float(np.max(s.offset_s)) if len(s) else 0.0 for s in scans])
    end_stamps = np.array([s.end_stamp_ns for s in scans], dtype=np.int64)
    upd, ins = [], []
    for scan in scans:
        upd.append(
            _voxel_subsample(
                scan, scan_voxel_m, points_per_scan, rng, min_range_m, max_range_m, voxel_point
            )
        )
        ins.append(
            _voxel_subsample(
                scan,
                scan_voxel_m / 2,
                map_points_per_scan,
                rng,
                min_range_m,
                max_range_m,
                voxel_point,
            )
        )
    start_ns = int(seg.start_ns)
    imu_t = (seg.imu.stamps_ns - start_ns).astype(np.float64) * NS
    end_t = (end_stamps - start_ns).astype(np.float64) * NS
    if imu_t[0] > end_t[0] or imu_t[-1] < end_t[-1]:
        raise BackendError(
            f"segment {seg.name}: IMU samples [{imu_t[0]:.3f}, {imu_t[-1]:.3f}] s do not cover "
            f"the scans [{end_t[0]:.3f}, {end_t[-1]:.3f}] s",
            fix="cut segments inside the IMU's time range",
        )
    imu = ImuTensors(
        torch.from_numpy(imu_t),
        torch.from_numpy(seg.imu.gyro_rad_s.copy()),
        torch.from_numpy(seg.imu.accel_m_s2.copy()),
    )
    return PreparedSegment(
        name=seg.name,
        start_ns=start_ns,
        end_stamps_ns=end_stamps,
        end_t=torch.from_numpy(end_t),
        imu=imu,
        update=_pad(upd, ends_rel, points_per_scan),
        insert=_pad(ins, ends_rel, map_points_per_scan),
    )
