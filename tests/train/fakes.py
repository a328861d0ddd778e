"""A fake odometry backend for unit-testing the environment and the trainer (not a LIO).

Each candidate's LiDAR trajectory is the reference moved by the candidate's error relative to
a hidden true extrinsic: ``T_est(t) = T_ref(t) · T_true⁻¹ · T_candidate``, so the reward peaks
at the truth and the whole loop runs in milliseconds.
"""

from __future__ import annotations

import numpy as np
import torch

from l2calib.data import ImuSamples, InMemoryScans, LidarScan, Sequence
from l2calib.interfaces import (
    CandidateStatus,
    CandidateTrajectories,
    OdometryBackend,
    ReferenceTrajectory,
)
from l2calib.trajectory import Trajectory

T_TRUE = torch.tensor(
    [[0.0, -1.0, 0.0, 0.10], [-1.0, 0.0, 0.0, -0.05], [0.0, 0.0, -1.0, 0.08], [0, 0, 0, 1.0]],
    dtype=torch.float64,
)


class FakeBackend(OdometryBackend):
    outputs_in_reference_frame = True

    def __init__(self, *_, delay_s: float = 0.0, **__) -> None:
        self.refs: list[ReferenceTrajectory] = []
        self.delay_s = delay_s  # a slow odometry, e.g. to kill a worker mid-batch

    def prepare(self, segments, references) -> None:
        self.refs = list(references)

    def evaluate(self, T_imu_lidar, time_offset_s=None):
        if self.delay_s:
            import time

            time.sleep(self.delay_s)
        out = []
        delta = torch.linalg.inv(T_TRUE) @ T_imu_lidar
        for ref in self.refs:
            traj = ref.trajectory
            T_ref = traj.matrices()[1:]
            est = T_ref[None] @ delta[:, None]
            K, N = est.shape[:2]
            out.append(
                CandidateTrajectories(
                    ref.segment,
                    traj.stamps_ns[1:],
                    est,
                    torch.ones(K, N, dtype=torch.bool),
                    torch.full((K,), int(CandidateStatus.OK)),
                )
            )
        return out


def reference(name: str, n: int = 50, seed: int = 0) -> ReferenceTrajectory:
    """A wiggly reference trajectory (rotating, so rotation errors are visible)."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 5, n)
    from scipy.spatial.transform import Rotation

    rot = Rotation.from_rotvec(np.column_stack([np.sin(t), np.cos(1.3 * t), 0.5 * t]))
    pos = np.column_stack([t, np.sin(t), 0.1 * t]) + rng.normal(scale=0.0, size=(n, 3))
    traj = Trajectory(1_000_000_000 + (t * 1e9).astype(np.int64), pos, rot.as_quat(), "lidar")
    return ReferenceTrajectory(name, traj)


def tiny_sequence(name: str) -> Sequence:
    """A sequence with a few empty scans (the fake backend does not read them)."""
    stamps = 1_000_000_000 + np.arange(0, 5_000_000_000, 5_000_000, dtype=np.int64)
    imu = ImuSamples(stamps, np.zeros((len(stamps), 3)), np.tile([0, 0, 9.81], (len(stamps), 1)))
    scans = [LidarScan(int(s)) for s in stamps[::20]]
    return Sequence(name, imu, InMemoryScans(scans))
