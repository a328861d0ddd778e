"""KISS-ICP runner: its poses refer to each scan's last point, and it tracks a simulated drive."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from l2calib import geometry as geo
from l2calib.alignment import ape
from l2calib.errors import DataError, ReferenceSourceError
from l2calib.references.kiss_icp_runner import KissIcpOptions, run_kiss_icp
from l2calib.sim import SimConfig, simulate


def test_kiss_icp_deskew_moves_points_into_the_frame_of_the_latest_point(rng):
    """The documented claim, checked on KISS-ICP's own preprocessor with an exact twist."""
    from kiss_icp.preprocess import Preprocessor

    xi = torch.tensor([0.4, -0.1, 0.05, 0.02, -0.03, 0.3], dtype=torch.float64)  # per sweep
    world = rng.uniform(-20, 20, size=(2000, 3))
    tau = np.sort(rng.uniform(0.0, 1.0, size=2000))
    tau[0], tau[-1] = 0.0, 1.0
    T = geo.se3_exp(torch.from_numpy(tau)[:, None] * xi).numpy()  # sensor pose at each point
    T_inv = np.linalg.inv(T)
    sensor = np.einsum("nij,nj->ni", T_inv[:, :3, :3], world) + T_inv[:, :3, 3]
    delta = geo.se3_exp(xi).numpy()  # KISS's last_delta: the motion over one sweep
    out = Preprocessor(1e3, 0.0, True, 1).preprocess(sensor, tau * 0.1 + 5.0, delta)
    end = np.linalg.inv(T[-1])
    expected = world @ end[:3, :3].T + end[:3, 3]
    assert np.abs(out - expected).max() < 1e-9


@pytest.fixture(scope="module")
def run():
    cfg = SimConfig.model_validate(
        {
            "duration_s": 4.0,
            "seed": 2,
            "world": {"name": "hall"},
            "motion": {"profile": "ugv", "still_start_s": 0.0},
            "lidar": {"model": "ouster-os1-16", "columns": 512},
        }
    )
    return simulate(cfg)


def test_kiss_icp_tracks_a_simulated_drive(run):
    traj = run_kiss_icp(run.scans, KissIcpOptions(max_range_m=60.0))
    assert traj.body_frame == "lidar" and len(traj) == len(run.scans)
    assert np.array_equal(traj.stamps_ns, [s.end_stamp_ns for s in run.scans])
    path = run.stats["path_length_m"]
    assert path > 8.0
    assert ape(run.gt_lidar, traj).rmse_t < 0.01 * path  # < 1 % of ~14 m


def test_kiss_icp_options_are_checked(run):
    with pytest.raises(ReferenceSourceError, match="min_range_m"):
        run_kiss_icp(run.scans, KissIcpOptions(min_range_m=50, max_range_m=10))
    with pytest.raises(DataError, match="at least 2 scans"):
        run_kiss_icp(run.scans[:1])
