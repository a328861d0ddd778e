"""Local voxel map of world points with point-to-plane association, for ``ct-lidar``.

Hand-written (numpy + scipy's cKDTree) rather than open3d or KISS-ICP's map: the continuous-time
registration needs, per query point, a local plane *and* a test that the neighbourhood is not
line-like (16-beam rings give many neighbourhoods that lie on one scan line, whose "normal" is
arbitrary); neither library exposes that, and both would cost a copy per scan.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

_OFF = 1 << 20  # voxel indices are packed into one int64 key, 21 bits per axis


def voxel_keys(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """``[N]`` int64 key of the voxel holding each of ``points`` ``[N, 3]`` (m)."""
    idx = np.floor(points / voxel_m).astype(np.int64) + _OFF
    return (idx[:, 0] << 42) | (idx[:, 1] << 21) | idx[:, 2]


def voxel_pick(points: np.ndarray, voxel_m: float, rng: np.random.Generator | None) -> np.ndarray:
    """Indices of one point per ``voxel_m`` voxel of ``points`` ``[N, 3]`` (m), in voxel order.

    ``rng`` given: a random point of each voxel; ``None``: the first in ``points``' order (for
    a scan in firing order, the earliest fired, so which side of a voxel is kept follows the
    sweep's direction).
    """
    order = np.arange(len(points)) if rng is None else rng.permutation(len(points))
    _, first = np.unique(voxel_keys(points[order], voxel_m), return_index=True)
    return order[first]


def voxel_subsample(points: np.ndarray, voxel_m: float, rng: np.random.Generator) -> np.ndarray:
    """Sorted indices of one random point per ``voxel_m`` voxel of ``points`` ``[N, 3]``."""
    if len(points) == 0:
        return np.zeros(0, np.int64)
    return np.sort(voxel_pick(points, voxel_m, rng))


@dataclass(frozen=True)
class Planes:
    """Point-to-plane associations of query points.

    Attributes:
        index: ``[M]`` indices of the query points that found a plane.
        normal: ``[M, 3]`` unit plane normals (world frame).
        offset: ``[M]`` plane offsets ``d`` so that the plane is ``n·x = d`` (m).
        one_line: ``[M]`` whether all points of the plane's fit were seen on one scan line
            (``ring``), or ``None`` where not known.
    """

    index: np.ndarray
    normal: np.ndarray
    offset: np.ndarray
    one_line: np.ndarray | None = None


class _PlaneCache:
    """Planes of one point set at the centres of query voxels, each fitted once.

    A query takes the plane fitted to the ``k`` map points nearest its voxel's centre (voxel
    edge ``cell_m``): one fit per occupied voxel, shared by every association round of a scan,
    instead of a ``k``-NN search and a fit per query and round (55 % of the odometry's time
    before). The centre, like a query, falls between a sparse LiDAR's scan lines; a map point
    would not (its nearest neighbours lie on its own line, which looks line-like).
    """

    def __init__(self, points: np.ndarray, cell_m: float, line: np.ndarray) -> None:
        self.points = points
        self.line = line  # [P] scan-line (ring) of each point, -1 unknown
        self.cell_m = cell_m
        self.tree = cKDTree(points) if len(points) else None
        self.keys = np.zeros(0, np.int64)  # sorted
        self.good = np.zeros(0, bool)
        self.normal = np.zeros((0, 3))
        self.offset = np.zeros(0)
        self.one_line = np.zeros(0, bool)


def _plane_tests(
    cov: np.ndarray, max_rms_m: float, min_spread_ratio: float
) -> tuple[np.ndarray, np.ndarray]:
    """Normals ``[M, 3]`` of covariances ``[M, 3, 3]`` and whether each is a plane ``[M]``."""
    evals, evecs = np.linalg.eigh(cov)  # ascending
    planar = evals[:, 0] <= max_rms_m**2
    spread = evals[:, 1] >= min_spread_ratio**2 * evals[:, 2]
    return evecs[:, :, 0], planar & spread


class VoxelPlaneMap:
    """World points, at most one per voxel, cropped to a radius around the sensor.

    Args:
        voxel_m: Voxel edge (m); a voxel keeps the first point that fell into it.
        radius_m: Points farther than this from the last crop centre are dropped (m).
        neighbours: Points per plane fit.
        max_plane_rms_m: Largest RMS distance of the neighbours from their plane (m).
        min_spread_ratio: Smallest ratio of the second to the largest principal spread of the
            neighbours (rejects line-like neighbourhoods).
        plane_radius_m: A plane needs all its ``neighbours`` within this distance of the centre
            of the query's voxel (m).
        cell_m: Edge of the query voxels whose planes are cached (m).
    """

    def __init__(
        self,
        voxel_m: float,
        radius_m: float,
        neighbours: int = 12,
        max_plane_rms_m: float = 0.05,
        min_spread_ratio: float = 0.2,
        plane_radius_m: float = 1.0,
        cell_m: float = 0.1,
    ) -> None:
        self.voxel_m = voxel_m
        self.radius_m = radius_m
        self.neighbours = neighbours
        self.max_plane_rms_m = max_plane_rms_m
        self.min_spread_ratio = min_spread_ratio
        self.plane_radius_m = plane_radius_m
        self.cell_m = cell_m
        self.points = np.zeros((0, 3))
        self.keys = np.zeros(0, np.int64)
        self.born = np.zeros(0)  # insertion time of each point (s, the caller's clock)
        self.line = np.zeros(0, np.int64)  # scan line (ring) each point was seen on, -1 unknown
        self._now: _PlaneCache | None = None
        self._old: tuple[float, _PlaneCache] | None = None

    def __len__(self) -> int:
        return len(self.points)

    def insert(
        self, points_world: np.ndarray, born: float = 0.0, line: np.ndarray | None = None
    ) -> None:
        """Adds the points whose voxels are still empty, stamped ``born`` (s).

        ``line``: ``[N]`` the scan line (ring) each point was seen on (``None``: unknown).
        """
        keys = voxel_keys(points_world, self.voxel_m)
        keys, first = np.unique(keys, return_index=True)
        new = ~np.isin(keys, self.keys, assume_unique=True)
        self.points = np.concatenate([self.points, points_world[first[new]]])
        self.keys = np.concatenate([self.keys, keys[new]])
        self.born = np.concatenate([self.born, np.full(int(new.sum()), born)])
        lines = np.full(len(points_world), -1, np.int64) if line is None else np.asarray(line)
        self.line = np.concatenate([self.line, lines[first[new]].astype(np.int64)])
        self._now = None

    def crop(self, centre: np.ndarray) -> None:
        """Drops points farther than ``radius_m`` from ``centre`` ``[3]``."""
        keep = np.einsum("ij,ij->i", self.points - centre, self.points - centre) <= self.radius_m**2
        if not keep.all():
            self.points, self.keys, self.born = self.points[keep], self.keys[keep], self.born[keep]
            self.line = self.line[keep]
            self._now = None  # the old points' cache may keep cropped points: far, harmless

    def associate(self, query_world: np.ndarray, max_distance_m: float) -> Planes:
        """The plane at each query point ``[N, 3]`` (that of its voxel, :class:`_PlaneCache`).

        A query keeps the plane if the ``neighbours`` map points nearest its voxel's centre lie
        within ``plane_radius_m`` of it, are planar (RMS below ``max_plane_rms_m``) and not
        line-like, and the query is within ``max_distance_m`` of the plane.
        """
        if self._now is None:
            self._now = _PlaneCache(self.points, self.cell_m, self.line)
        return self._planes(self._now, query_world, max_distance_m)

    def on_plane(
        self,
        query_world: np.ndarray,
        normal_world: np.ndarray,
        max_distance_m: float,
        neighbours: int,
        tol_m: float,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Planes through queries ``[N, 3]`` with given normals ``[N, 3]``, where the map agrees.

        A query keeps its plane where its ``neighbours`` nearest map points lie within
        ``max_distance_m`` and all within ``tol_m`` of the plane with that normal through their
        mean (a line of map points on the query's surface; points on another surface bend away).

        Returns:
            Indices ``[M]`` of the queries kept and the planes' offsets ``[M]`` (m).
        """
        if self._now is None:
            self._now = _PlaneCache(self.points, self.cell_m, self.line)
        c = self._now
        empty = np.zeros(0, np.int64), np.zeros(0)
        if c.tree is None or len(c.points) < neighbours or len(query_world) == 0:
            return empty
        dist, nn = c.tree.query(query_world, k=neighbours, distance_upper_bound=max_distance_m)
        idx = np.flatnonzero(np.isfinite(dist[:, -1]))
        d = np.einsum("nki,ni->nk", c.points[nn[idx]], normal_world[idx])
        off = d.mean(axis=1)
        flat = np.abs(d - off[:, None]).max(axis=1) <= tol_m
        return idx[flat], off[flat]

    def associate_older(
        self, query_world: np.ndarray, max_distance_m: float, before: float
    ) -> Planes:
        """As :meth:`associate`, with only the map points born at ``before`` (s) or earlier.

        Their planes are kept until ``before`` changes.
        """
        if self._old is None or self._old[0] != before:
            old = self.born <= before
            self._old = (before, _PlaneCache(self.points[old], self.cell_m, self.line[old]))
        return self._planes(self._old[1], query_world, max_distance_m)

    def _planes(self, c: _PlaneCache, query_world: np.ndarray, max_distance_m: float) -> Planes:
        empty = Planes(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0), np.zeros(0, bool))
        if c.tree is None or len(c.points) < self.neighbours or len(query_world) == 0:
            return empty
        keys = voxel_keys(query_world, c.cell_m)
        new = np.unique(keys)
        pos = np.searchsorted(c.keys, new).clip(max=max(len(c.keys) - 1, 0))
        if len(c.keys):
            new = new[c.keys[pos] != new]
        if len(new):
            self._fit(c, new)
        at = np.searchsorted(c.keys, keys)
        n = c.normal[at]
        dist = np.abs(np.einsum("ni,ni->n", n, query_world) - c.offset[at])
        idx = np.flatnonzero(c.good[at] & (dist <= max_distance_m))
        return Planes(idx, n[idx], c.offset[at[idx]], c.one_line[at[idx]])

    def _fit(self, c: _PlaneCache, keys: np.ndarray) -> None:
        """Fits the planes of voxels ``keys`` ``[M]`` (new, sorted) into the cache."""
        k = self.neighbours
        idx = np.stack([(keys >> 42) & 0x1FFFFF, (keys >> 21) & 0x1FFFFF, keys & 0x1FFFFF], 1)
        centres = (idx - _OFF + 0.5) * c.cell_m
        dist, nn = c.tree.query(centres, k=k, distance_upper_bound=self.plane_radius_m)
        ok = np.isfinite(dist[:, -1])
        normal = np.zeros((len(keys), 3))
        offset = np.zeros(len(keys))
        good = np.zeros(len(keys), bool)
        one_line = np.zeros(len(keys), bool)
        if ok.any():
            ln = c.line[nn[ok]]  # [M, k]
            one_line[ok] = (ln[:, 0] >= 0) & np.all(ln == ln[:, :1], axis=1)
            nbr = c.points[nn[ok]]  # [M, k, 3]
            centre = nbr.mean(axis=1)
            d = nbr - centre[:, None]
            cov = np.einsum("mki,mkj->mij", d, d) / k
            normal[ok], good[ok] = _plane_tests(cov, self.max_plane_rms_m, self.min_spread_ratio)
            offset[ok] = np.einsum("mi,mi->m", normal[ok], centre)
        keys = np.concatenate([c.keys, keys])
        order = np.argsort(keys, kind="stable")
        c.keys = keys[order]
        c.good = np.concatenate([c.good, good])[order]
        c.normal = np.concatenate([c.normal, normal])[order]
        c.offset = np.concatenate([c.offset, offset])[order]
        c.one_line = np.concatenate([c.one_line, one_line])[order]


def facing(
    planes: Planes, world: np.ndarray, origin: np.ndarray, min_deg: float, all_lines: bool = False
) -> Planes:
    """The map planes, less those fitted to one scan line within ``min_deg`` of the viewing ray.

    A one-line plane that holds the query's viewing ray (``world - origin``, both ``[N, 3]``) is
    a scan line of a structured surface seen from about here: a ring over a ribbed wall
    or along a façade lies on the beam's cone, and the fit returns the cone's tangent plane,
    which contains the ray. Its distance pulls the scan along the cone's normal (up/down on a
    horizontal ring): measured on a 16-beam UAV flight, a quarter of the map planes at the true
    pose were such fakes, 5-9 cm off, and the scan drifted 0.1° in pitch per scan. Planes on
    several lines stay (a dense LiDAR's grazing floor: dropping those lost a 64-beam hand-held
    run), as do all planes of LiDARs without a ``ring`` field.

    ``all_lines``: drop every one-line plane (registration, ``one_line_planes='never'``). One
    line does not fix a plane: besides the cone's tangent plane, a ring crossing a floor-wall
    corner fits a plane through the kink (measured on a 16-beam UAV flight in a hall: floor
    points 25 m away on planes tilted 60°, 20-35 cm off at the true pose, facing the ray).
    """
    if len(planes.index) == 0 or planes.one_line is None:
        return planes
    if all_lines:
        ok = ~planes.one_line
        return Planes(planes.index[ok], planes.normal[ok], planes.offset[ok], planes.one_line[ok])
    if min_deg <= 0:
        return planes
    ray = world[planes.index] - origin[planes.index]
    cos = np.abs(np.einsum("ni,ni->n", planes.normal, ray)) / np.linalg.norm(ray, axis=1)
    ok = ~planes.one_line | (cos >= np.sin(np.radians(min_deg)))
    return Planes(planes.index[ok], planes.normal[ok], planes.offset[ok], planes.one_line[ok])
