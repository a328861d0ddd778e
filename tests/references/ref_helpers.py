"""Simulated cases and synthetic NavSatFix messages for the reference tests."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from l2calib.data import Segment, Sequence
from l2calib.io.navsat import NavSatFixes
from l2calib.references.geodesy import LocalEnu
from l2calib.sim import SimConfig, SimRun, simulate

ORIGIN = LocalEnu(47.3769, 8.5417, 408.0)  # Zurich, ellipsoidal height


@dataclass
class SimCase:
    run: SimRun
    sequence: Sequence
    segment: Segment


def make_case(cfg: dict, first: int, last: int) -> SimCase:
    run = simulate(SimConfig.model_validate(cfg))
    seq = run.sequence()
    st = seq.scans.stamps_ns
    return SimCase(run, seq, seq.segment(int(st[first]), int(st[last])))


def synth_fixes(
    run: SimRun,
    lever_m=(0.0, 0.0, 0.0),
    rate_hz: float = 10.0,
    sigma_m: float = 0.01,
    seed: int = 0,
    status: int = 2,
    clock_offset_s: float = 0.0,
) -> NavSatFixes:
    """Fixes of an antenna at ``lever_m`` in the LiDAR frame, from the simulator's exact poses.

    Stamps are on the LiDAR clock minus ``clock_offset_s`` (``t_fix = t_lidar - offset``).
    """
    gt = run.gt_lidar
    step = int(1e9 / rate_hz)
    t = np.arange(gt.stamps_ns[0], gt.stamps_ns[-1] + 1, step, dtype=np.int64)
    T = run.lidar_poses(t)
    ant = T[:, :3, 3] + T[:, :3, :3] @ np.asarray(lever_m, dtype=np.float64)
    ant = ant + np.random.default_rng(seed).normal(0.0, sigma_m, ant.shape)
    lat, lon, h = ORIGIN.to_geodetic(ant)
    n = len(t)
    cov = np.tile(np.eye(3) * sigma_m**2, (n, 1, 1))
    return NavSatFixes(
        stamps_ns=t - int(round(clock_offset_s * 1e9)),
        latitude_deg=lat,
        longitude_deg=lon,
        altitude_m=h,
        position_covariance_m2=cov,
        covariance_type=np.full(n, 2, np.uint8),
        status=np.full(n, status, np.int8),
        service=np.ones(n, np.uint16),
    )


def rpe(gt, est, delta_s: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Relative pose errors of ``est`` over ``delta_s``: rotation (deg) and translation (m).

    Unlike the Umeyama-aligned APE, this does not depend on how well positions fix the
    alignment's rotation (poorly, for a short and nearly straight path).
    """
    import torch

    from l2calib import geometry as geo

    g = gt.interpolate(est.stamps_ns).matrices()
    e = est.matrices()
    k = int(np.searchsorted(est.stamps_ns, est.stamps_ns[0] + int(delta_s * 1e9)))
    dg = geo.transform_inverse(g[:-k]) @ g[k:]
    de = geo.transform_inverse(e[:-k]) @ e[k:]
    d = geo.transform_inverse(dg) @ de
    rot = np.degrees(geo.rotation_angle(d[:, :3, :3]).numpy())
    return rot, torch.linalg.norm(d[:, :3, 3], dim=1).numpy()
