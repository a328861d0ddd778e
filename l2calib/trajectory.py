"""Time-stamped pose sequences with int64 nanosecond stamps.

A :class:`Trajectory` holds the poses ``T_world_body`` of one rigid body frame (``body_frame``,
e.g. ``"lidar"`` or ``"imu"``) in one world frame, at strictly increasing stamps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from l2calib import geometry as geo
from l2calib.errors import DataError

NS_PER_S = 1_000_000_000


@dataclass(frozen=True, eq=False)
class Trajectory:
    """Poses ``T_world_body`` at int64 nanosecond stamps.

    Attributes:
        stamps_ns: ``[N]`` int64, strictly increasing.
        t_world_body: ``[N, 3]`` float64 positions of the body origin in the world frame (m).
        quat_xyzw: ``[N, 4]`` float64 unit quaternions ``q_world_body`` (Hamilton, scalar last).
        body_frame: Name of the body frame the poses describe (``"lidar"``, ``"imu"``, ...).
        world_frame: Name of the world frame.
    """

    stamps_ns: np.ndarray
    t_world_body: np.ndarray
    quat_xyzw: np.ndarray
    body_frame: str = "body"
    world_frame: str = "world"

    def __post_init__(self) -> None:
        stamps = np.asarray(self.stamps_ns)
        if stamps.ndim != 1 or not np.issubdtype(stamps.dtype, np.integer):
            raise DataError(
                f"trajectory stamps must be a 1-D integer array of nanoseconds, got "
                f"dtype {stamps.dtype} and shape {stamps.shape}",
                fix="convert seconds with l2calib.trajectory.seconds_to_ns",
            )
        n = stamps.shape[0]
        pos = np.asarray(self.t_world_body, dtype=np.float64)
        quat = np.asarray(self.quat_xyzw, dtype=np.float64)
        if pos.shape != (n, 3) or quat.shape != (n, 4):
            raise DataError(
                f"trajectory arrays disagree: {n} stamps, positions {pos.shape}, "
                f"quaternions {quat.shape} (expected [{n}, 3] and [{n}, 4])"
            )
        if n > 1 and np.any(np.diff(stamps) <= 0):
            bad = int(np.argmax(np.diff(stamps) <= 0))
            raise DataError(
                f"trajectory stamps are not strictly increasing at index {bad + 1} "
                f"({stamps[bad]} ns then {stamps[bad + 1]} ns)",
                fix="sort the poses by time and drop duplicates",
            )
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(quat))):
            raise DataError("trajectory contains NaN or infinite values")
        norms = np.linalg.norm(quat, axis=1)
        if n and np.any(np.abs(norms - 1.0) > 1e-3):
            bad = int(np.argmax(np.abs(norms - 1.0)))
            raise DataError(
                f"quaternion {bad} has norm {norms[bad]:.6f}, not 1",
                fix="normalise the quaternions (check the column order is qx qy qz qw)",
            )
        object.__setattr__(self, "stamps_ns", stamps.astype(np.int64, copy=False))
        object.__setattr__(self, "t_world_body", pos)
        object.__setattr__(self, "quat_xyzw", quat / norms[:, None] if n else quat)

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_matrices(
        cls,
        stamps_ns: np.ndarray,
        T_world_body: np.ndarray | torch.Tensor,
        body_frame: str = "body",
        world_frame: str = "world",
    ) -> Trajectory:
        """Builds a trajectory from ``[N, 4, 4]`` homogeneous poses ``T_world_body``."""
        T = torch.as_tensor(T_world_body, dtype=torch.float64)
        quat = geo.matrix_to_quat(T[:, :3, :3]).numpy()
        return cls(np.asarray(stamps_ns), T[:, :3, 3].numpy().copy(), quat, body_frame, world_frame)

    # ------------------------------------------------------------------ views
    def __len__(self) -> int:
        return int(self.stamps_ns.shape[0])

    @property
    def stamps_s(self) -> np.ndarray:
        """``[N]`` float64 stamps in seconds (lossy for absolute epoch times; prefer ns)."""
        return self.stamps_ns.astype(np.float64) / NS_PER_S

    @property
    def duration_s(self) -> float:
        """Time between first and last pose in seconds."""
        return float(self.stamps_ns[-1] - self.stamps_ns[0]) / NS_PER_S if len(self) else 0.0

    def matrices(self) -> torch.Tensor:
        """``[N, 4, 4]`` float64 torch tensor of ``T_world_body``."""
        q = torch.from_numpy(self.quat_xyzw)
        t = torch.from_numpy(self.t_world_body)
        return geo.transform_from_quat(q, t)

    # ------------------------------------------------------------------ operations
    def sample(self, query_ns: np.ndarray, max_gap_s: float = 0.2) -> tuple[Trajectory, np.ndarray]:
        """Interpolates poses at ``query_ns`` (linear positions, slerp rotations).

        Args:
            query_ns: ``[M]`` int64 query stamps, strictly increasing.
            max_gap_s: A query is only answered when the two poses around it are at most this
                far apart (s); also no extrapolation beyond the first or last pose.

        Returns:
            The trajectory at the answerable queries and a ``[M]`` boolean mask of which queries
            were answerable.
        """
        query = np.asarray(query_ns, dtype=np.int64)
        stamps = self.stamps_ns
        if len(self) < 2:
            raise DataError(f"cannot interpolate a trajectory with {len(self)} pose(s)")
        hi = np.searchsorted(stamps, query, side="left")
        exact = (hi < len(stamps)) & (stamps[np.minimum(hi, len(stamps) - 1)] == query)
        lo = np.where(exact, hi, hi - 1)
        inside = (lo >= 0) & (hi < len(stamps))
        lo_c = np.clip(lo, 0, len(stamps) - 1)
        hi_c = np.clip(hi, 0, len(stamps) - 1)
        gap = stamps[hi_c] - stamps[lo_c]
        valid = inside & (exact | (gap <= int(max_gap_s * NS_PER_S)))
        lo_v, hi_v, q_v = lo_c[valid], hi_c[valid], query[valid]
        span = (stamps[hi_v] - stamps[lo_v]).astype(np.float64)
        tau = np.where(span > 0, (q_v - stamps[lo_v]) / np.where(span > 0, span, 1.0), 0.0)
        pos = self.t_world_body[lo_v] + tau[:, None] * (
            self.t_world_body[hi_v] - self.t_world_body[lo_v]
        )
        quat = geo.quat_slerp(
            torch.from_numpy(self.quat_xyzw[lo_v]),
            torch.from_numpy(self.quat_xyzw[hi_v]),
            torch.from_numpy(tau),
        ).numpy()
        out = Trajectory(q_v, pos, quat, self.body_frame, self.world_frame)
        return out, valid

    def interpolate(self, query_ns: np.ndarray, max_gap_s: float = 0.2) -> Trajectory:
        """Like :meth:`sample` but every query must be answerable, else :class:`DataError`."""
        out, valid = self.sample(query_ns, max_gap_s)
        if not np.all(valid):
            first = int(np.argmin(valid))
            raise DataError(
                f"cannot interpolate the {self.body_frame} trajectory at "
                f"{np.asarray(query_ns)[first] / NS_PER_S:.6f} s: outside "
                f"[{self.stamps_s[0]:.6f}, {self.stamps_s[-1]:.6f}] s or in a gap longer "
                f"than {max_gap_s} s ({int((~valid).sum())} of {len(valid)} queries fail)",
                fix="check that the time ranges overlap or raise the maximum gap",
            )
        return out

    def with_body(self, T_body_other: np.ndarray | torch.Tensor, other_frame: str) -> Trajectory:
        """Trajectory of a frame rigidly attached to the body.

        ``T_world_other = T_world_body @ T_body_other``.
        """
        T = torch.as_tensor(T_body_other, dtype=torch.float64)
        return Trajectory.from_matrices(
            self.stamps_ns, self.matrices() @ T, other_frame, self.world_frame
        )

    def shifted(self, offset_ns: int) -> Trajectory:
        """Same poses with ``offset_ns`` added to every stamp."""
        return Trajectory(
            self.stamps_ns + int(offset_ns),
            self.t_world_body,
            self.quat_xyzw,
            self.body_frame,
            self.world_frame,
        )

    def slice_time(self, start_ns: int, end_ns: int) -> Trajectory:
        """Poses with ``start_ns <= stamp <= end_ns``."""
        keep = (self.stamps_ns >= start_ns) & (self.stamps_ns <= end_ns)
        return Trajectory(
            self.stamps_ns[keep],
            self.t_world_body[keep],
            self.quat_xyzw[keep],
            self.body_frame,
            self.world_frame,
        )


def seconds_to_ns(seconds: np.ndarray | float) -> np.ndarray:
    """Converts float seconds to int64 nanoseconds, rounding to the nearest nanosecond."""
    return np.round(np.asarray(seconds, dtype=np.float64) * NS_PER_S).astype(np.int64)
