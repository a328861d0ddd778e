"""``gt-file`` reference: a ground-truth trajectory file (TUM, KITTI + times, CSV).

Frames. The file may describe the LiDAR (``body_frame: lidar``), or another frame rigidly
attached to it; then ``T_body_lidar`` (the LiDAR pose in that frame) turns it into the LiDAR
trajectory, ``T_world_lidar = T_world_body · T_body_lidar``:

* ``other`` — e.g. a motion-capture body, a vehicle ``base_link`` or KITTI's camera, with a
  transform known independently of the IMU (survey, CAD, hand-eye). Full poses are trusted.
* ``imu`` — e.g. a GNSS/INS solution or EuRoC's ground truth of the IMU. Here ``T_body_lidar``
  *is* ``T_imu_lidar``, the quantity being calibrated: a reference built from a guess of it would
  make the reward's rotation term pull every candidate back to that guess. By default
  (``constrains: auto``) only positions are used then; they carry the guess's translation error
  (``|δt|``, usually a few cm from CAD) as a bias. Use such a file with a trusted extrinsic (e.g.
  to evaluate), or prefer ``kiss-icp``/``rtk`` for an unbiased calibration.

Clocks. ``time_offset_s`` is added to the file's stamps (``t_lidar = t_file + time_offset_s``).
Each segment must be covered from its first point to its last scan end without gaps longer
than ``max_gap_s``; with ``check_imu`` the file's rotation rate is compared with the gyro
(:mod:`l2calib.references.imu_check`) to catch clock offsets and wrong quaternion order. A shift
found there is read as a LiDAR–IMU offset unless the file describes the IMU
(:mod:`l2calib.references.clock_shift`); with ``train.estimate_time_offset`` it is handed on as
the offset's starting value (``ReferenceTrajectory.time_offset_hint_s``) instead of stopping.
Files are small and read directly, so this source does not use the cache.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence as Seq
from pathlib import Path

import numpy as np
import torch

from l2calib import geometry as geo
from l2calib.data import NS_PER_S, Segment
from l2calib.errors import ConfigError, ReferenceSourceError
from l2calib.interfaces import ReferenceSource, ReferenceTrajectory
from l2calib.io.trajectory_files import read_trajectory
from l2calib.references.clock_shift import attribute_shift, is_shifted
from l2calib.references.imu_check import compare_rotation_rate
from l2calib.references.options import GtFileOptions, TransformSpec
from l2calib.trajectory import Trajectory

log = logging.getLogger("l2calib.references")
NAME = "gt-file"


def transform_matrix(spec: list[list[float]] | TransformSpec, field: str) -> np.ndarray:
    """``[4, 4]`` rigid transform from a 4×4 list or a :class:`TransformSpec`.

    Raises:
        ConfigError: naming ``field`` if the matrix is not a proper rigid transform.
    """
    if isinstance(spec, TransformSpec):
        t = torch.tensor(spec.translation_m, dtype=torch.float64)
        if spec.quat_xyzw is not None:
            R = geo.quat_to_matrix(geo.quat_normalize(torch.tensor(spec.quat_xyzw).double()))
        else:
            rpy = np.radians(spec.rpy_deg or (0.0, 0.0, 0.0))
            R = geo.euler_rpy_to_matrix(torch.tensor(rpy, dtype=torch.float64))
        return geo.make_transform(R, t).numpy()
    T = np.asarray(spec, dtype=np.float64)
    R = T[:3, :3]
    if not np.allclose(T[3], [0, 0, 0, 1]) or np.abs(R.T @ R - np.eye(3)).max() > 1e-4:
        raise ConfigError(
            f"{field} is not a rigid transform (last row {T[3].tolist()}, rotation not "
            "orthonormal)",
            fix="write the 4x4 matrix row by row with last row [0, 0, 0, 1]",
        )
    if np.linalg.det(R) < 0:
        raise ConfigError(f"{field} has a reflection (det R < 0)", fix="check the axis signs")
    return T


def _span(a: int, b: int) -> str:
    return f"[{a / NS_PER_S:.3f}, {b / NS_PER_S:.3f}] s"


class GtFileReference(ReferenceSource):
    """Reference trajectories cut from one ground-truth file.

    Args:
        options: File, format, frames and clock offset.
        estimate_time_offset: ``train.estimate_time_offset``: a LiDAR–IMU shift found by the
            clock check becomes the offset's starting value instead of an error.
        time_offset_bound_s: ``policy.options.time_offset_bound_s`` (s): larger shifts cannot
            be estimated; ``None``: unbounded.
        **_: Other pipeline context (ignored).
    """

    def __init__(
        self,
        options: GtFileOptions,
        estimate_time_offset: bool = False,
        time_offset_bound_s: float | None = 0.2,
        **_: object,
    ) -> None:
        self.options = options
        self.estimate_time_offset = estimate_time_offset
        self.time_offset_bound_s = time_offset_bound_s
        self._traj: Trajectory | None = None
        o = options
        self.constrains = o.constrains
        if self.constrains == "auto":
            self.constrains = "position" if o.body_frame == "imu" else "pose"
        if o.body_frame == "imu":
            log.warning(
                "gt-file: %s describes the IMU; it becomes a LiDAR reference through the given "
                "T_body_lidar = T_imu_lidar, the quantity being calibrated. %s",
                o.path,
                "Only positions are used (they carry that guess's translation error)."
                if self.constrains == "position"
                else "Rotations are used too: the calibration will reproduce that rotation.",
            )

    @property
    def trajectory(self) -> Trajectory:
        """The whole file as a LiDAR trajectory on the LiDAR clock (read once)."""
        if self._traj is None:
            o = self.options
            fmt = None if o.format == "auto" else o.format
            traj = read_trajectory(Path(o.path), fmt, o.times_path, o.body_frame)
            traj = traj.shifted(int(round(o.time_offset_s * NS_PER_S)))
            if o.body_frame != "lidar":
                T = transform_matrix(o.T_body_lidar, "reference.options.T_body_lidar")
                traj = traj.with_body(T, "lidar")
            self._traj = Trajectory(
                traj.stamps_ns, traj.t_world_body, traj.quat_xyzw, "lidar", NAME
            )
        return self._traj

    def _covering(self, seg: Segment) -> Trajectory:
        o, traj = self.options, self.trajectory
        scans = seg.scans
        if not scans:
            raise ReferenceSourceError(f"segment {seg.name} has no LiDAR scan")
        a, b = scans[0].stamp_ns, max(s.end_stamp_ns for s in scans)
        st = traj.stamps_ns
        if st[-1] < a or st[0] > b:
            hint = (seg.start_ns - int(st[0])) / NS_PER_S
            raise ReferenceSourceError(
                f"{o.path} ({_span(st[0], st[-1])} after time_offset_s={o.time_offset_s}) does "
                f"not overlap segment {seg.name} ({_span(a, b)}, LiDAR clock)",
                fix="check that the file belongs to this bag and set reference.options."
                f"time_offset_s (t_lidar = t_file + offset; if both start together: {hint:.3f})",
            )
        if st[0] > a or st[-1] < b:
            raise ReferenceSourceError(
                f"{o.path} covers {_span(st[0], st[-1])} but segment {seg.name} needs "
                f"{_span(a, b)} (first point to last scan end)",
                fix="select segments inside the ground truth's time span, or fix "
                "reference.options.time_offset_s",
            )
        lo = int(np.searchsorted(st, a, side="right")) - 1
        hi = int(np.searchsorted(st, b, side="left"))
        gaps = np.diff(st[lo : hi + 1])
        if gaps.size and gaps.max() > o.max_gap_s * NS_PER_S:
            i = lo + int(np.argmax(gaps))
            raise ReferenceSourceError(
                f"{o.path} has a {gaps.max() / NS_PER_S:.3f} s gap at {st[i] / NS_PER_S:.3f} s "
                f"inside segment {seg.name}",
                fix="choose segments away from the gap or raise reference.options.max_gap_s",
            )
        return traj.slice_time(int(st[lo]), int(st[hi]))

    def _check_imu(self, seg: Segment, ref: Trajectory) -> float | None:
        """Checks the file against the gyro; returns a LiDAR–IMU offset to start from, if any."""
        o = self.options
        res = compare_rotation_rate(ref, seg.imu, seg.start_ns, seg.end_ns)
        if not res.checked:
            log.info("gt-file: too little rotation in %s to check the file's clock", seg.name)
            return None
        where = f"{o.path} in segment {seg.name}"
        if res.best_correlation < 0.5 or not (0.7 < res.scale < 1.4):
            raise ReferenceSourceError(
                f"{where}: the rotation rate of the file's poses does not follow the IMU gyro "
                f"(correlation {res.best_correlation:.2f}, magnitude ratio {res.scale:.2f})",
                fix="check the file's clock (time_offset_s), that the poses are T_world_body of a "
                "body rigidly attached to the sensors, and the quaternion order (qx qy qz qw); "
                "or set reference.options.check_imu: false",
            )
        hint = None
        if is_shifted(res):
            hint = attribute_shift(
                res,
                where,
                o.body_frame,
                o.time_offset_s,
                self.estimate_time_offset,
                self.time_offset_bound_s,
            )
        if res.direction_residual > 0.3:
            raise ReferenceSourceError(
                f"{where}: the file's body rotation rates are not a fixed rotation of the IMU "
                f"gyro's (residual {res.direction_residual:.0%} of the rate): its orientations "
                "do not belong to a body rigidly attached to the IMU",
                fix="check the quaternion order (TUM/CSV: qx qy qz qw) and that the poses are "
                "T_world_body, not T_body_world; or set reference.options.check_imu: false",
            )
        return hint

    def compute(self, segments: Seq[Segment]) -> list[ReferenceTrajectory]:
        """The file's LiDAR poses covering each segment (see module docstring)."""
        out = []
        for seg in segments:
            ref = self._covering(seg)
            hint = None
            if self.options.check_imu and len(seg.imu):
                hint = self._check_imu(seg, ref)
            out.append(ReferenceTrajectory(seg.name, ref, self.constrains, NAME, hint))
        if self.constrains == "position":
            log.warning("gt-file reference is position-only: the reward drops its rotation term")
        return out
