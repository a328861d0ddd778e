"""Continuous-time LiDAR-only odometry: the ``ct-lidar`` reference's engine.

Every scan gets its own smooth motion, seen by every one of its points (no constant-velocity
deskew from the previous scan, which a hand-swung rig at 15 rad/s² breaks)::

    R(τ) = R_b · Exp(τ ω + τ² α)        t(τ) = t_b + τ v + τ² a        τ = point time − scan start

``R_b, t_b`` (``T_world_lidar`` at the scan's first point), body rate ``ω`` (rad/s), ``α``
(rad/s², half the angular acceleration), world velocity ``v`` (m/s) and ``a`` (m/s², half the
acceleration): 18 parameters per scan, solved by Levenberg–Marquardt on point-to-plane distances
to a local voxel map (:mod:`l2calib.references.ct_map`), with priors that the scan starts where
and how the previous scan's motion ended (continuity). Where the map has no plane because a
sparse LiDAR draws the surface as lines metres apart, the scan's own lines give the normal
(:mod:`l2calib.references.ct_normals`). α's process noise follows the recent angular
acceleration (:meth:`CtLidarOdometry._alpha_noise`). After a scan converges, its points are
moved into the world by their own poses and added to the map.

The first scan has no map and no motion of its own: scans 0 and 1 are taken to share one
constant velocity, found by iterated deskewing (:meth:`CtLidarOdometry._bootstrap`).

Where it cannot follow (a scene that does not pin every direction: a long corridor, an open
field; a motion beyond its prior) it loses track; that is detected
(:meth:`CtLidarOdometry._check_tracking`) and raised, never returned as a reference. Measured
cases (the 40 s rig matrix of 16- to 128-beam LiDARs, degenerate worlds, cold starts) and what
was tried: ``docs/references.md``.

Written here rather than taken from a library: KISS-ICP (the ``kiss-icp`` reference) is the
well-kept LiDAR odometry, but its constant-velocity deskew is the failure being fixed, and no
maintained Python package offers per-scan continuous-time registration.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from l2calib.data import NS_PER_S, LidarScan
from l2calib.errors import ReferenceLostTrackError, ReferenceSourceError
from l2calib.references.ct_map import Planes, VoxelPlaneMap, facing, voxel_subsample
from l2calib.references.ct_motion import ScanMotion, prior_residual, right_jacobian
from l2calib.references.ct_normals import line_normals
from l2calib.references.ct_tracking import TrackingChecks
from l2calib.references.options import CtLidarOptions

log = logging.getLogger(__name__)
#: The INFO message of each roll-back (benchmarks count the records carrying it).
ROLLBACK_LOG = "ct-lidar: scan %d found lost; scans %d-%d solved again (roll-back %d of at most %d)"

__all__ = ["CtLidarOdometry", "ScanMotion", "right_jacobian"]


@dataclass
class _Scan:
    points: np.ndarray  # [N, 3] registration sample (LiDAR frame)
    tau: np.ndarray  # [N] s after the scan start
    map_points: np.ndarray  # [M, 3] map-voxel sample
    map_tau: np.ndarray
    map_line: np.ndarray | None = None  # [M] scan line (ring) of each, None unknown
    normal: np.ndarray | None = None  # [N, 3] scan-line normals (LiDAR frame), NaN unknown


class CtLidarOdometry(TrackingChecks):
    """Runs the continuous-time odometry over consecutive scans (module docstring).

    Scan to scan it is an iterated Kalman filter on the 18-parameter motion: the prediction is
    the previous motion carried to the next scan start (:meth:`ScanMotion.propagate`) with its
    covariance plus process noise (random walks of every block), and the
    update is the Levenberg–Marquardt solve of prior plus point-to-plane terms. The full covariance
    matters: with diagonal priors the start position and the velocity trade against each other
    from scan to scan and oscillate.
    """

    def __init__(self, options: CtLidarOptions) -> None:
        o = options
        self.o = o
        self.map = self._new_map()
        self.rng = np.random.default_rng(o.seed)
        # ``auto`` left unresolved (the odometry used on its own, not through the reference
        # source, which resolves it with the IMU's planar check): the general values.
        noise_rot_deg, noise_rate_rad_s = o.motion_noise(planar=False)
        q = np.repeat(
            [
                np.radians(noise_rot_deg),
                o.noise_pos_m,
                noise_rate_rad_s,
                o.noise_alpha_rad_s2,
                o.noise_velocity_m_s,
                o.noise_accel_m_s2,
            ],
            3,
        )
        self.q_density = q**2  # per second
        # Scan 0's start is the world frame (no pose uncertainty); its motion is unknown.
        p0 = np.repeat(
            [
                1e-6,
                1e-6,
                o.initial_rate_rad_s,
                o.initial_alpha_rad_s2,
                o.initial_velocity_m_s,
                o.initial_accel_m_s2,
            ],
            3,
        )
        self.P0 = np.diag(p0**2)
        self.retries = 0  # scans solved again with a wider prior (see _retry)
        self.rollbacks = 0  # scans undone and solved again with a denser sample (_forward)
        self.unseen = False  # lost because the scene stopped pinning the scan (_check_tracking)
        self.lost_at_s: float | None = None  # where track was lost, s after the first scan

    def _new_map(self) -> VoxelPlaneMap:
        o = self.o
        return VoxelPlaneMap(
            o.map_voxel_m,
            o.map_radius_m,
            o.neighbours,
            o.max_plane_rms_m,
            o.min_spread_ratio,
            o.plane_radius_m,
            o.plane_cell_m,
        )

    def _prepare(
        self, scan: LidarScan, density: float = 1.0, rng: np.random.Generator | None = None
    ) -> _Scan:
        """The scan's registration and map samples (``density`` times denser registration).

        ``rng`` draws the samples; by default the run's own generator, which draws every scan's
        samples in turn (so a scan's sample depends on the scans prepared before it).
        """
        o = self.o
        rng = self.rng if rng is None else rng
        p = np.asarray(scan.points_lidar, np.float64)
        tau = np.asarray(scan.offset_s, np.float64)
        ring = scan.ring if o.line_match_m > 0 else None
        r = np.linalg.norm(p, axis=1)
        keep = np.isfinite(r) & (r >= o.min_range_m) & (r <= o.max_range_m)
        p, tau, r = p[keep], tau[keep], r[keep]
        ring = None if ring is None else np.asarray(ring)[keep]
        if o.isolated_ratio > 0 and len(p) > 1:
            # Spurious returns (dust, mixed pixels) lie in free space, away from every other
            # return; each would also take a voxel of its own in the samples and the map.
            near, _ = cKDTree(p).query(p, k=2, workers=-1)  # all cores: the same answer
            keep = near[:, 1] <= np.maximum(o.isolated_ratio * r, o.isolated_min_m)
            p, tau = p[keep], tau[keep]
            ring = None if ring is None else ring[keep]
        reg = voxel_subsample(p, o.scan_voxel_m / density ** (1 / 3), rng)
        if len(reg) > o.max_points * density:
            reg = np.sort(rng.choice(reg, int(o.max_points * density), replace=False))
        mp = voxel_subsample(p, o.map_voxel_m, rng)
        normal = None if ring is None else line_normals(p, ring, reg)
        line = None if ring is None else ring[mp]
        return _Scan(p[reg], tau[reg], p[mp], tau[mp], normal=normal, map_line=line)

    def _associate(self, s: _Scan, m: ScanMotion, gate: float, lines: bool = True) -> Planes:
        """Point-to-plane matches of the scan's sample at motion ``m``.

        The map's planes first; the points without one that have a scan-line normal
        (:mod:`l2calib.references.ct_normals`, rotated into the world) take the plane with that
        normal through their ``line_neighbours`` nearest map points within ``line_match_m``,
        where those lie within ``line_flat_m`` of it (a far ground ring of a 16-beam LiDAR: a
        line in the map, on the scan point's surface) and the point within ``line_gate_m``.
        """
        R, t = m.poses(s.tau)  # once: the world points and the scan-line normals both need R
        world = np.einsum("nij,nj->ni", R, s.points) + t  # as m.transform, keeping R and t
        never = self.o.one_line_planes == "never"
        planes = facing(
            self.map.associate(world, gate), world, t, self.o.min_incidence_deg, all_lines=never
        )
        if s.normal is None or not lines:
            return planes
        rest = np.ones(len(world), bool)
        rest[planes.index] = False
        rest &= np.isfinite(s.normal[:, 0])
        rest = np.flatnonzero(rest)
        n = np.einsum("nij,nj->ni", R[rest], s.normal[rest])
        found, off = self.map.on_plane(
            world[rest], n, self.o.line_match_m, self.o.line_neighbours, self.o.line_flat_m
        )
        rest, n = rest[found], n[found]
        near = np.abs(np.einsum("ni,ni->n", n, world[rest]) - off) <= self.o.line_gate_m
        return Planes(
            np.concatenate([planes.index, rest[near]]),
            np.concatenate([planes.normal, n[near]]),
            np.concatenate([planes.offset, off[near]]),
        )

    def _alpha_noise(self, motions: list[ScanMotion], stamps: np.ndarray, k: int) -> float:
        """Process noise of α for scan ``k`` (rad/s²/√s), from the recent angular acceleration.

        α (the within-scan change of the body rate) is seen only weakly by one scan. Where the
        rig turns smoothly (a UAV, a vehicle) a loose α lets the weakly seen terms wander and
        the map follow them (a 16-beam UAV flight drifted 1° in pitch in 2 s, then lost track);
        a hand-swung rig needs it loose. So its noise follows the largest change of the body
        rate between consecutive scans over the last ``alpha_noise_window_s``, between
        ``noise_alpha_min_rad_s2`` and ``noise_alpha_rad_s2``.
        """
        o = self.o
        lo, hi = o.noise_alpha_min_rad_s2, o.noise_alpha_rad_s2
        t = (stamps[:k] - stamps[0]) / NS_PER_S
        first = max(1, int(np.searchsorted(t, t[-1] - o.alpha_noise_window_s)))
        if lo >= hi or first >= k:  # no history yet: loose
            return hi
        acc = max(
            np.linalg.norm(motions[j].omega - motions[j - 1].omega) / (t[j] - t[j - 1])
            for j in range(first, k)
        )
        return float(np.clip(o.alpha_noise_gain * acc, lo, hi))

    def _predict(
        self,
        m: ScanMotion,
        P: np.ndarray,
        dt: float,
        alpha_noise: float | None = None,
        widen: float = 1.0,
    ) -> tuple[ScanMotion, np.ndarray]:
        """The next scan's prior: motion and covariance ``[18, 18]``.

        ``widen`` scales the process noise (σ) of the body rate and α, for a retry.
        """
        pred, F = m.propagate(dt)
        q = self.q_density.copy()
        if alpha_noise is not None:
            q[9:12] = alpha_noise**2
        q[6:12] *= widen**2
        return pred, F @ P @ F.T + np.diag(q * dt)

    def _jacobian(self, m: ScanMotion, p: np.ndarray, tau: np.ndarray, n: np.ndarray) -> np.ndarray:
        """``[N, 18]`` derivative of the point-to-plane distances (update order of retract)."""
        phi = m.rotvec(tau)
        E = Rotation.from_rotvec(phi).as_matrix()  # R(τ) = R_b E, once for both blocks
        n_b = n @ m.R_b  # R_bᵀ n per row
        J = np.empty((len(p), 18))
        J[:, 0:3] = np.cross(np.einsum("nij,nj->ni", E, p), n_b)
        g = np.cross(p, np.einsum("nji,nj->ni", E, n_b))  # p × R(τ)ᵀ n
        Jphi = np.einsum("ni,nij->nj", g, right_jacobian(phi))
        J[:, 6:9] = tau[:, None] * Jphi
        J[:, 9:12] = (tau**2)[:, None] * Jphi
        J[:, 3:6] = n
        J[:, 12:15] = tau[:, None] * n
        J[:, 15:18] = (tau**2)[:, None] * n
        return J

    def _solve(
        self, s: _Scan, pred: ScanMotion, P_pred: np.ndarray
    ) -> tuple[ScanMotion, np.ndarray]:
        """The scan's motion and its covariance ``[18, 18]`` (iterated update)."""
        o = self.o
        m = pred
        info_prior = np.linalg.inv(P_pred)
        info_p = 1.0 / o.sigma_point_m**2
        scales = np.geomspace(o.robust_scale_start_m, o.robust_scale_m, o.iterations)
        H = info_prior
        ratio = 0.0
        for it in range(o.iterations):
            gate = max(o.max_correspondence_m * (0.5**it), 4 * o.map_voxel_m)
            planes = self._associate(s, m, gate, lines=it >= o.line_match_from)
            if len(planes.index) < o.min_planes:
                break
            p, tau, n = s.points[planes.index], s.tau[planes.index], planes.normal
            sc = scales[it]

            def cost_of(mm: ScanMotion, p=p, tau=tau, n=n, off=planes.offset, sc=sc):  # noqa: ANN202
                r = np.einsum("ni,ni->n", n, mm.transform(p, tau)) - off
                pr = prior_residual(mm, pred)
                rho = sc**2 * r**2 / (sc**2 + r**2)  # Geman-McClure
                return info_p * float(rho.sum()) + float(pr @ info_prior @ pr), r

            cost, r = cost_of(m)
            lam = 1e-4
            for _ in range(o.inner_steps):
                wt = (sc**2 / (sc**2 + r**2)) ** 2  # its IRLS weights
                J = self._jacobian(m, p, tau, n)
                Jw = J * (info_p * wt)[:, None]
                H = J.T @ Jw + info_prior
                grad = Jw.T @ r + info_prior @ prior_residual(m, pred)
                while True:
                    dx = -np.linalg.solve(H + lam * np.diag(np.diag(H)), grad)
                    cand = m.retract(dx)
                    c_cost, c_r = cost_of(cand)
                    if c_cost <= cost:
                        m, cost, r, lam = cand, c_cost, c_r, lam * 0.3
                        break
                    lam *= 10.0
                    if lam > 1e4:
                        break
                if lam > 1e4 or np.linalg.norm(dx[:6]) < 1e-6:
                    break
            ratio = float(np.sum(np.abs(r) < 3 * sc)) / len(s.points)  # points on a plane
        self.last_inlier_ratio = ratio
        P = np.linalg.inv(H)
        return m, 0.5 * (P + P.T)

    def _insert(self, s: _Scan, m: ScanMotion, born: float = 0.0) -> None:
        world = m.transform(s.map_points, s.map_tau)
        line = s.map_line
        gate = self.o.insert_max_residual_m
        if gate > 0 and len(self.map):
            # A point off a plane the map already has is a spurious return short of the
            # surface (or a small object): it would blur the plane for every later scan.
            planes = self.map.associate(world, 4 * self.o.map_voxel_m)
            r = np.einsum("ni,ni->n", planes.normal, world[planes.index]) - planes.offset
            keep = np.ones(len(world), bool)
            keep[planes.index[np.abs(r) > gate]] = False
            world = world[keep]
            line = None if line is None else line[keep]
        self.map.insert(world, born, line)

    def _retry(
        self,
        s: _Scan,
        m: ScanMotion,
        P_new: np.ndarray,
        last: ScanMotion,
        P: np.ndarray,
        dt: float,
        alpha_noise: float,
        ratios: list[float],
    ) -> tuple[ScanMotion, np.ndarray]:
        """The solve again with a wider motion prior where the scan fits far worse than before.

        Meant for a hand swing that reverses within a scan (body rate +1.3 rad/s, α ~15 rad/s²
        in 0.1 s on a 64-beam hand-held run), beyond the prior's process noise, where the solve
        would stay near the prediction and fit fewer points. When the share of points on a
        plane drops below ``retry_inlier_drop`` times the median of the last five scans, the
        scan is solved again from the same motion with the body rate's and α's noise widened
        ``retry_widen`` times, and the solution with more points on a plane is kept (CT-ICP's
        robust registration, too, registers a frame whose fit fails its assessment again, with
        a denser sample and wider neighbourhoods).

        Measured since (2026-12-03, every retry logged on hand-held runs of a 64-beam (9 s) and
        a 32-beam LiDAR (20 s) in the hall): most retries change nothing (inlier share within
        0.002, body rate within 0.03 rad/s), so this is not what kept the 64-beam run on track;
        on the 32-beam run, as it lost track in its hardest swing (18.5 s), one retry was kept
        for +0.002 and moved the body rate by 0.7 rad/s: the run tracks without retries (0.44
        cm) and loses track with them. Both runs sit at an edge where tiny differences decide
        whether that swing is followed (docs/references.md, "Engine 8"): the acceptance rule
        is too weak, and what would hold the edge is open.
        """
        o = self.o
        if o.retry_widen <= 1 or len(ratios) < 5:
            return m, P_new
        ratio = self.last_inlier_ratio
        if ratio >= o.retry_inlier_drop * float(np.median(ratios[-5:])):
            return m, P_new
        pred, P_pred = self._predict(last, P, dt, alpha_noise, widen=o.retry_widen)
        m2, P2 = self._solve(s, pred, P_pred)
        self.retries += 1
        if self.last_inlier_ratio > ratio:
            return m2, P2
        self.last_inlier_ratio = ratio
        return m, P_new

    def _forward(
        self,
        prepared: list[_Scan],
        stamps: np.ndarray,
        start: ScanMotion,
        P: np.ndarray,
        last: int,
        on_scan: Callable[[int], None] | None = None,
        scans: list[LidarScan] | None = None,
    ) -> list[ScanMotion]:
        """Inserts scan 0 with ``start`` and solves scans ``1..last`` (inclusive).

        Where a scan is found lost (but for an unverifiable scene, which a second solve cannot
        change), the last ``rollback_scans`` scans are undone, map points included
        (:meth:`_state`, :meth:`_restore`), and solved again with a ``rollback_density`` times
        denser sample; at most ``rollback_max`` times per run, each time with a fresh sample,
        and ``scans`` (the raw scans) are needed for it. A roll-back's sample of scan ``i`` is
        drawn by a generator seeded with ``(seed, i, roll-back number)``, so it does not depend
        on how many scans were prepared before (with the run's one generator a stretch that
        tracked on a 21 s run was lost on a 40 s run of the same recording), and the first pass
        (``prepared``) is untouched by it.
        """
        self.map = self._new_map()
        self._insert(prepared[0], start)
        self._poor = self._drift = 0
        self._unverified_since: float | None = None
        motions = [start]
        ratios: list[float] = []
        saved = [self._state(P)]  # [k]: the state after scan k
        dense: dict[int, _Scan] = {}  # the denser samples of rolled-back scans
        k = 1
        while k <= last:
            s = dense.get(k, prepared[k])
            dt = float(stamps[k] - stamps[k - 1]) / NS_PER_S
            alpha_noise = self._alpha_noise(motions, stamps, k)
            pred, P_pred = self._predict(motions[-1], P, dt, alpha_noise)
            m, P_new = self._solve(s, pred, P_pred)
            m, P = self._retry(s, m, P_new, motions[-1], P, dt, alpha_noise, ratios)
            ratios.append(self.last_inlier_ratio)
            now = float(stamps[k] - stamps[0]) / NS_PER_S
            self.last_old_residual, self.last_old_info = self._old_residual(s, m, now)
            try:
                self._check_tracking(k, stamps, m)
            except ReferenceLostTrackError:
                j = max(1, k - self.o.rollback_scans)
                o = self.o
                if scans is None or self.rollbacks >= o.rollback_max or self.unseen:
                    raise
                if o.rollback_scans == 0 or saved[j - 1] is None:
                    raise
                attempt = self.rollbacks + 1
                for i in range(j, k + 1):
                    rng = np.random.default_rng([o.seed, i, attempt])
                    dense[i] = self._prepare(scans[i], o.rollback_density, rng)
                P = self._restore(saved[j - 1])
                del motions[j:], ratios[j - 1 :], saved[j:]
                self.rollbacks += 1
                log.info(ROLLBACK_LOG, k, j, k, attempt, o.rollback_max)
                self.lost_at_s = None
                k = j
                continue
            motions.append(m)
            self._insert(s, m, now)
            self.map.crop(m.t_b)
            saved.append(self._state(P))
            if len(saved) > self.o.rollback_scans + 1:
                saved[-self.o.rollback_scans - 2] = None  # only the last few are rolled back to
            if on_scan is not None:
                on_scan(k)
            k += 1
        return motions

    def _state(self, P: np.ndarray) -> tuple:
        """What a roll-back restores (the map's arrays are never changed in place)."""
        mp = self.map
        return (mp.points, mp.keys, mp.born, mp.line, P, self._poor, self._drift,
                self._unverified_since)  # fmt: skip

    def _restore(self, state: tuple) -> np.ndarray:
        """Puts a :meth:`_state` back; returns its covariance."""
        mp = self.map
        mp.points, mp.keys, mp.born, mp.line, P, self._poor, self._drift = state[:7]
        self._unverified_since = state[7]
        mp._now = mp._old = None  # their plane caches hold the undone points
        return P

    def _bootstrap(self, prepared: list[_Scan], stamps: np.ndarray) -> ScanMotion:
        """The first scan's motion, from scans 0 and 1 sharing one constant velocity.

        Scan 0 is the first map, so its own motion is unknown. Consecutive scans are distorted
        alike, so registering scan 1 rigidly to scan 0 gives their relative pose even before
        deskewing; that pose over the scan interval is the velocity, with which both scans are
        deskewed and registered again (iterated, as KISS-ICP's deskew but without the previous
        scan's velocity to start from). The world frame is scan 0's start.
        """
        z = np.zeros(3)
        start = ScanMotion(np.eye(3), z, z, z, z, z)
        dt = float(stamps[1] - stamps[0]) / NS_PER_S
        P = np.diag(np.repeat([np.radians(10.0), 0.5, 1e-6, 1e-6, 1e-6, 1e-6], 3) ** 2)
        for _ in range(self.o.bootstrap_rounds):
            self.map = self._new_map()
            self._insert(prepared[0], start)
            pred, _ = start.propagate(dt)
            m1, _ = self._solve(prepared[1], pred, P)  # pose only: the motion is held
            omega = Rotation.from_matrix(m1.R_b).as_rotvec() / dt
            start = ScanMotion(np.eye(3), z, omega, z, m1.t_b / dt, z)
        return start

    def run(
        self, scans: list[LidarScan], on_scan: Callable[[int], None] | None = None
    ) -> tuple[np.ndarray, list[ScanMotion]]:
        """Solves every scan; returns the scan start stamps ``[S]`` (int64 ns) and motions."""
        if len(scans) < 2:
            raise ReferenceSourceError(
                f"ct-lidar needs at least 2 scans in a segment, got {len(scans)}",
                fix="select longer segments (selection.window_s) or check the LiDAR topic",
            )
        from threadpoolctl import threadpool_limits

        stamps = np.array([s.stamp_ns for s in scans], np.int64)
        prepared = [self._prepare(s) for s in scans]
        # [N, 18] products are far too small for threaded BLAS: its threads only spin and
        # compete with the other core's work (measured 1.5x slower on 2 busy cores).
        with threadpool_limits(1, user_api="blas"):
            start = self._bootstrap(prepared, stamps)
            motions = self._forward(
                prepared, stamps, start, self.P0, len(scans) - 1, on_scan, scans
            )
        for m in motions:
            if not all(np.all(np.isfinite(x)) for x in (m.R_b, m.t_b, m.omega, m.v)):
                raise ReferenceLostTrackError(
                    "ct-lidar produced a non-finite pose", fix="check the scans' point times"
                )
        return stamps, motions
