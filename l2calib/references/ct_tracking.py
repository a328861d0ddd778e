"""When the ct-lidar odometry has lost track: the checks behind ``ReferenceLostTrackError``.

A mixin of :class:`~l2calib.references.ct_odometry.CtLidarOdometry` (kept apart to keep that
module small): it reads the odometry's options ``o``, its ``map`` and the last solve's
``last_inlier_ratio``, and keeps the counters ``_poor``, ``_drift``, ``_unverified_since``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from l2calib.data import NS_PER_S
from l2calib.errors import ReferenceLostTrackError
from l2calib.references.ct_map import facing
from l2calib.references.ct_motion import ScanMotion


class TrackingChecks:
    """The drift and lost-track checks of the odometry (see :meth:`_check_tracking`)."""

    o: Any  # CtLidarOptions
    map: Any  # VoxelPlaneMap
    last_inlier_ratio: float
    last_old_residual: float
    last_old_info: float
    lost_at_s: float | None
    unseen: bool
    _poor: int
    _drift: int
    _unverified_since: float | None

    def _old_residual(self, s: Any, m: ScanMotion, now_s: float) -> tuple[float, float]:  # s: _Scan
        """How the scan fits the old map: median distance (m) and weakest information.

        Old: map points born ``lost_map_age_s`` or longer ago. The median is over the scan's
        points that find a plane there (NaN when fewer than ``lost_old_points``); the information
        is the smallest eigenvalue of ``Σ n nᵀ`` over those within 10 cm of their plane: how many
        points pin the scan's position along its least constrained direction (NaN before the map
        is old enough).

        A drift shows here: the recent map drifts along with the poses that built it, so the scan
        fits it well (the inlier ratio stays high), but the old map stays where it was; unless
        the old map does not constrain the direction of the drift (a street canyon along its
        axis, a UAV's height above unseen ground), which the information shows.
        """
        o = self.o
        nan = float("nan")
        before = np.floor(2 * (now_s - o.lost_map_age_s)) / 2  # the old tree lives 0.5 s
        if before < 0:
            return nan, nan
        R, t = m.poses(s.tau)
        world = np.einsum("nij,nj->ni", R, s.points) + t
        planes = self.map.associate_older(world, o.max_correspondence_m, before)
        planes = facing(planes, world, t, o.min_incidence_deg)
        r = np.einsum("ni,ni->n", planes.normal, world[planes.index]) - planes.offset
        n = planes.normal[np.abs(r) < 0.1]
        info = float(np.linalg.eigvalsh(n.T @ n)[0])
        if len(planes.index) < o.lost_old_points:
            return nan, info
        return float(np.median(np.abs(r))), info

    def _check_tracking(self, k: int, stamps: np.ndarray, m: ScanMotion) -> None:
        """Raises when the odometry has lost track, instead of returning a wrong reference.

        Lost, for ``lost_scans`` scans in a row: fewer than ``lost_inlier_ratio`` of the
        registration points on a map plane (``lost_young_inlier_ratio`` in the first
        ``lost_grace_scans``, while the map is young and much of each scan new), or a median
        distance above ``lost_old_residual_m`` to the planes of the map points older than
        ``lost_map_age_s`` (a drift); for ``lost_unverified_s``, an old map that pins the scan's
        position along some direction by fewer than ``lost_old_info`` points (a drift there
        would go unseen); at once, a body rate / speed no rig reaches.
        """
        o = self.o
        young = k <= o.lost_grace_scans
        poor = self.last_inlier_ratio < (
            o.lost_young_inlier_ratio if young else o.lost_inlier_ratio
        )
        self._poor = self._poor + 1 if poor else 0
        drift = self.last_old_residual > o.lost_old_residual_m  # False for NaN
        self._drift = self._drift + 1 if drift else 0
        when = (stamps[k] - stamps[0]) / NS_PER_S
        if not self.last_old_info < o.lost_old_info:  # verified, or NaN: not checked yet
            self._unverified_since = None
        elif self._unverified_since is None:
            self._unverified_since = when
        unverified = self._unverified_since is not None
        unseen = unverified and when - self._unverified_since >= o.lost_unverified_s
        absurd = np.linalg.norm(m.omega) > o.max_rate_rad_s or np.linalg.norm(m.v) > o.max_speed_m_s
        lost = max(self._poor, self._drift) >= o.lost_scans or unseen
        self.unseen = bool(unseen)
        if lost or absurd or not np.all(np.isfinite(m.t_b)):
            self.lost_at_s = float(when)
            raise ReferenceLostTrackError(
                f"ct-lidar lost track {when:.1f} s into the run (scan {k}: "
                f"{100 * self.last_inlier_ratio:.0f} % of the points on the map, "
                f"{100 * self.last_old_residual:.1f} cm median off the map of "
                f"{o.lost_map_age_s:g} s before, which pins it by {self.last_old_info:.0f} points "
                f"along its weakest direction, body rate "
                f"{np.linalg.norm(m.omega):.1f} rad/s, speed {np.linalg.norm(m.v):.1f} m/s)",
                fix="the scene may not pin a LiDAR-only odometry (a long corridor, an open "
                "field, a LiDAR facing the sky) or the motion outran it: record where the LiDAR "
                "sees structure on several sides, or use a gt-file or rtk reference "
                "(docs/references.md lists where ct-lidar was measured)",
            )
