"""``rtk`` reference: GNSS/RTK fixes (``sensor_msgs/NavSatFix``) as LiDAR positions in local ENU.

Fixes are read from the segment's bag (``seg.meta["path"]``, as set by ``open_sequences``) on
``reference.options.topic`` or the recipe's ``data.rtk_topic`` (or from ``bag_path``, or handed
in memory as ``fixes={sequence name: NavSatFixes}``). Each is gated by status and by its reported
covariance, converted exactly to ENU (:mod:`l2calib.references.geodesy`; one origin for all
segments) and stamped ``t_lidar = t_fix + time_offset_s``.

The antenna is not at the LiDAR: ``p_lidar = p_antenna - R_world_lidar · t_lidar_antenna`` needs
the LiDAR attitude, which GNSS does not give. With ``orientation: kiss-icp`` (or ``ct-lidar``) the
segment's LiDAR-only odometry (cached) supplies it: its antenna track is aligned to the fixes
(Umeyama, weighted by ``1/σ²``) and its rotations, moved into ENU, correct the lever arm (a 1°
attitude error moves a 0.5 m lever arm by 9 mm) and give backends that start from the reference a
usable attitude. Positions stay the fixes'. The reference is position-only: the reward drops its
rotation term.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from collections.abc import Sequence as Seq
from dataclasses import fields

import numpy as np
import torch

from l2calib import geometry as geo
from l2calib.alignment import umeyama
from l2calib.data import NS_PER_S, Segment, Sequence
from l2calib.errors import L2CalibError, ReferenceSourceError
from l2calib.interfaces import ReferenceSource, ReferenceTrajectory
from l2calib.io.navsat import NavSatFixes, read_navsat
from l2calib.recipe import DataConfig
from l2calib.references.cache import ReferenceCache, cache_key, file_fingerprint
from l2calib.references.ct_lidar_source import CtLidarReference
from l2calib.references.geodesy import LocalEnu
from l2calib.references.kiss_icp_source import KissIcpReference
from l2calib.references.options import RtkOptions
from l2calib.trajectory import Trajectory

log = logging.getLogger("l2calib.references")
NAME = "rtk"
PAD_NS = NS_PER_S  # fixes kept beyond the segment on each side (for interpolation at its edges)


def fix_sigma_m(fixes: NavSatFixes) -> np.ndarray:
    """``[N]`` reported standard deviation (m, largest axis); NaN where the type is unknown."""
    var = np.diagonal(fixes.position_covariance_m2, axis1=1, axis2=2).max(axis=1)
    return np.where(fixes.covariance_type > 0, np.sqrt(np.maximum(var, 0.0)), np.nan)


class RtkReference(ReferenceSource):
    """Position-only references from NavSatFix messages.

    Args:
        options: Topic, lever arm, gating, clock offset, attitude source.
        data: The recipe's ``data`` section (for ``rtk_topic``).
        sequences: Sequences of the segments (for KISS-ICP warm-up scans).
        fixes: Fixes in memory by sequence name (instead of reading bags).
        progress: Progress bars.
    """

    def __init__(
        self,
        options: RtkOptions,
        data: DataConfig | None = None,
        sequences: Seq[Sequence] | None = None,
        fixes: Mapping[str, NavSatFixes] | None = None,
        progress: bool = False,
        **_: object,
    ) -> None:
        self.options = options
        self.topic = options.topic or (data.rtk_topic if data is not None else None)
        self.fixes = dict(fixes or {})
        self.cache = ReferenceCache(options.cache_dir, options.cache)
        self.attitude = None  # the LiDAR-odometry reference that gives the attitude
        if options.orientation != "none":
            odo = options.kiss_icp if options.orientation == "kiss-icp" else options.ct_lidar
            odo = odo.model_copy(  # the attitude run follows this source's cache
                update={
                    "cache_dir": odo.cache_dir or options.cache_dir,
                    "cache": odo.cache and options.cache,
                }
            )
            make = KissIcpReference if options.orientation == "kiss-icp" else CtLidarReference
            self.attitude = make(odo, sequences, progress)
        self._enu: LocalEnu | None = None
        if options.origin is not None:
            self._enu = LocalEnu(*options.origin)

    # ------------------------------------------------------------------ input
    def _read(self, seg: Segment) -> tuple[NavSatFixes, str]:
        if seg.sequence in self.fixes and self.options.bag_path is None:
            return self.fixes[seg.sequence], f"fixes of sequence {seg.sequence}"
        path = self.options.bag_path or seg.meta.get("path")
        if self.topic is None:
            raise ReferenceSourceError(
                "the rtk reference needs a NavSatFix topic, and none is set",
                fix="set data.rtk_topic (or reference.options.topic) to the sensor_msgs/NavSatFix "
                "topic; `l2calib inspect <bag>` lists the topics",
            )
        if not path:
            raise ReferenceSourceError(
                f"segment {seg.name} does not come from a bag, so there are no fixes to read",
                fix="set reference.options.bag_path to the bag holding the NavSatFix topic",
            )
        key = cache_key({"source": "navsat", "bag": file_fingerprint(path), "topic": self.topic})
        names = [f.name for f in fields(NavSatFixes)]

        def read() -> dict[str, np.ndarray]:
            nav = read_navsat(path, self.topic)
            return {n: getattr(nav, n) for n in names}

        arrays, _ = self.cache.get_or_compute(key, read, {"bag": str(path), "topic": self.topic})
        return NavSatFixes(**{n: arrays[n] for n in names}), f"{path}: {self.topic}"

    def _usable(self, nav: NavSatFixes, where: str) -> tuple[np.ndarray, np.ndarray]:
        sigma = fix_sigma_m(nav)
        ok = nav.valid & (nav.status >= self.options.min_status)
        ok &= ~(sigma > self.options.max_sigma_m)  # NaN (unknown covariance) passes
        if ok.any() and np.isnan(sigma[ok]).all():
            log.warning("%s: fixes report no covariance; they are not gated by accuracy", where)
        return ok, sigma

    # ------------------------------------------------------------------ per segment
    def compute_one(self, seg: Segment) -> ReferenceTrajectory:
        """The RTK reference of one segment."""
        o = self.options
        nav, where = self._read(seg)
        ok, sigma = self._usable(nav, where)
        stamps = nav.stamps_ns + int(round(o.time_offset_s * NS_PER_S))
        ok &= np.concatenate([[True], np.diff(stamps) > 0])  # drop repeated stamps (sorted input)
        scans = seg.scans
        a, b = scans[0].stamp_ns, max(s.end_stamp_ns for s in scans)
        inside = (stamps >= a - PAD_NS) & (stamps <= b + PAD_NS)
        use = inside & ok
        if use.sum() < o.min_fixes:
            raise ReferenceSourceError(
                f"{where}: {int(use.sum())} usable fix(es) in segment {seg.name} "
                f"([{a / NS_PER_S:.3f}, {b / NS_PER_S:.3f}] s), {o.min_fixes} needed: "
                f"{int(inside.sum())} message(s) in the window, "
                f"{int((inside & ~nav.valid).sum())} without fix (status -1 or NaN), "
                f"{int((inside & nav.valid & (nav.status < o.min_status)).sum())} below "
                f"min_status {o.min_status}, {int((inside & (sigma > o.max_sigma_m)).sum())} "
                f"with sigma > {o.max_sigma_m} m",
                fix="choose segments with RTK reception, relax reference.options.min_status or "
                "max_sigma_m, or check reference.options.time_offset_s",
            )
        idx = np.flatnonzero(use)
        first = idx[max(int(np.searchsorted(stamps[idx], a, side="right")) - 1, 0)]
        last = idx[min(int(np.searchsorted(stamps[idx], b, side="left")), len(idx) - 1)]
        use &= (np.arange(len(use)) >= first) & (np.arange(len(use)) <= last)  # one fix beyond
        st = stamps[use]
        if st[0] > a or st[-1] < b:
            raise ReferenceSourceError(
                f"{where}: fixes cover [{st[0] / NS_PER_S:.3f}, {st[-1] / NS_PER_S:.3f}] s but "
                f"segment {seg.name} needs [{a / NS_PER_S:.3f}, {b / NS_PER_S:.3f}] s",
                fix="choose segments inside the RTK coverage or fix time_offset_s",
            )
        if self._enu is None:
            i0 = int(np.flatnonzero(ok)[0])
            self._enu = LocalEnu(
                float(nav.latitude_deg[i0]), float(nav.longitude_deg[i0]), float(nav.altitude_m[i0])
            )
        p_ant = self._enu.to_enu(nav.latitude_deg[use], nav.longitude_deg[use], nav.altitude_m[use])
        gaps = np.diff(st) / NS_PER_S
        if gaps.max() > 0.5:
            log.warning("%s: fixes have a %.2f s gap in %s", where, gaps.max(), seg.name)
        if np.median(gaps) > 0.2:
            log.warning(
                "%s: fixes come every %.2f s; set reward.max_gap_s above that",
                where,
                np.median(gaps),
            )
        w = 1.0 / np.square(np.nan_to_num(sigma[use], nan=o.max_sigma_m).clip(1e-3))
        if self.attitude is None:
            quat = np.tile([0.0, 0.0, 0.0, 1.0], (len(st), 1))
            traj = Trajectory(st, p_ant, quat, "lidar", "enu")
        else:
            traj = self._with_attitude(seg, st, p_ant, w, where)
        return ReferenceTrajectory(seg.name, traj, "position", NAME)

    def _with_attitude(
        self, seg: Segment, st: np.ndarray, p_ant: np.ndarray, w: np.ndarray, where: str
    ) -> Trajectory:
        kiss = self.attitude.compute_one(seg).trajectory
        lever = torch.tensor(self.options.lever_arm_m, dtype=torch.float64)
        clamped = np.clip(st, kiss.stamps_ns[0], kiss.stamps_ns[-1])
        uniq, inv = np.unique(clamped, return_inverse=True)
        T_k = kiss.interpolate(uniq, max_gap_s=1.0).matrices()[torch.from_numpy(inv)]
        ant_kiss = T_k[:, :3, 3] + (T_k[:, :3, :3] @ lever)
        dst = torch.from_numpy(p_ant)
        within = torch.from_numpy((st >= kiss.stamps_ns[0]) & (st <= kiss.stamps_ns[-1]))
        R_a, t_a, _ = umeyama(ant_kiss, dst, torch.from_numpy(w) * within)
        resid = (ant_kiss @ R_a.T + t_a - dst).norm(dim=1)[within]
        spread = torch.linalg.svdvals(dst - dst.mean(0)) / np.sqrt(len(st))
        if float(spread[1]) < 0.3:
            log.warning(
                "%s: the path in %s is nearly straight; the attitude about the travel direction "
                "(used for the lever arm) is poorly determined",
                where,
                seg.name,
            )
        rmse = float(resid.square().mean().sqrt())
        if rmse > 0.1 + 3 * float(np.sqrt(1.0 / np.median(w))):
            log.warning(
                "%s: fixes and KISS-ICP disagree by %.3f m RMS in %s (KISS-ICP drift, or a wrong "
                "time_offset_s or lever_arm_m, or multipath); positions still come from the fixes",
                where,
                rmse,
                seg.name,
            )
        R = R_a @ T_k[:, :3, :3]
        pos = dst - (R @ lever)
        return Trajectory(st, pos.numpy(), geo.matrix_to_quat(R).numpy(), "lidar", "enu")

    def compute(self, segments: Seq[Segment]) -> list[ReferenceTrajectory]:
        """One position-only reference per segment (see module docstring)."""
        out = []
        for seg in segments:
            try:
                out.append(self.compute_one(seg))
            except ReferenceSourceError:
                raise
            except L2CalibError as exc:  # e.g. DataError from the bag: keep its fix
                raise ReferenceSourceError(f"rtk: {exc.message}", fix=exc.fix) from None
        log.warning("rtk reference is position-only: the reward drops its rotation term")
        return out
