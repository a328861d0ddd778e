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


def voxel_subsample(points: np.ndarray, voxel_m: float, rng: np.random.Generator) -> np.ndarray:
    """Indices of one random point per ``voxel_m`` voxel of ``points`` ``[N, 3]``."""
    if len(points) == 0:
        return np.zeros(0, np.int64)
    order = rng.permutation(len(points))
    _, first = np.unique(voxel_keys(points[order], voxel_m), return_index=True)
    return np.sort(order[first])


@dataclass(frozen=True)
class Planes:
    """Point-to-plane associations of query points.

    Attributes:
        index: ``[M]`` indices of the query points that found a plane.
        normal: ``[M, 3]`` unit plane normals (world frame).
        offset: ``[M]`` plane offsets ``d`` so that the plane is ``n·x = d`` (m).
    """

    index: np.ndarray
    normal: np.ndarray
    offset: np.ndarray


class VoxelPlaneMap:
    """World points, at most one per voxel, cropped to a radius around the sensor.

    Args:
        voxel_m: Voxel edge (m); a voxel keeps the first point that fell into it.
        radius_m: Points farther than this from the last crop centre are dropped (m).
        neighbours: Points per plane fit.
        max_plane_rms_m: Largest RMS distance of the neighbours from their plane (m).
        min_spread_ratio: Smallest ratio of the second to the largest principal spread of the
            neighbours (rejects line-like neighbourhoods).
    """

    def __init__(
        self,
        voxel_m: float,
        radius_m: float,
        neighbours: int = 12,
        max_plane_rms_m: float = 0.05,
        min_spread_ratio: float = 0.2,
    ) -> None:
        self.voxel_m = voxel_m
        self.radius_m = radius_m
        self.neighbours = neighbours
        self.max_plane_rms_m = max_plane_rms_m
        self.min_spread_ratio = min_spread_ratio
        self.points = np.zeros((0, 3))
        self.keys = np.zeros(0, np.int64)
        self.born = np.zeros(0)  # insertion time of each point (s, the caller's clock)
        self._tree: cKDTree | None = None
        self._old: tuple[float, cKDTree | None, np.ndarray] | None = None

    def __len__(self) -> int:
        return len(self.points)

    def insert(self, points_world: np.ndarray, born: float = 0.0) -> None:
        """Adds the points whose voxels are still empty, stamped ``born`` (s)."""
        keys = voxel_keys(points_world, self.voxel_m)
        keys, first = np.unique(keys, return_index=True)
        new = ~np.isin(keys, self.keys, assume_unique=True)
        self.points = np.concatenate([self.points, points_world[first[new]]])
        self.keys = np.concatenate([self.keys, keys[new]])
        self.born = np.concatenate([self.born, np.full(int(new.sum()), born)])
        self._tree = None

    def crop(self, centre: np.ndarray) -> None:
        """Drops points farther than ``radius_m`` from ``centre`` ``[3]``."""
        keep = np.einsum("ij,ij->i", self.points - centre, self.points - centre) <= self.radius_m**2
        if not keep.all():
            self.points, self.keys, self.born = self.points[keep], self.keys[keep], self.born[keep]
            self._tree = None  # the old points' tree may keep cropped points: far, harmless

    def associate(self, query_world: np.ndarray, max_distance_m: float) -> Planes:
        """Fits a plane to the map neighbours of each query point ``[N, 3]``.

        A query keeps its plane if all ``neighbours`` lie within ``max_distance_m`` of it, the
        neighbourhood is planar (RMS below ``max_plane_rms_m``) and not line-like.
        """
        if self._tree is None and len(self.points):
            self._tree = cKDTree(self.points)
        return self._fit(self._tree, self.points, query_world, max_distance_m)

    def associate_older(
        self, query_world: np.ndarray, max_distance_m: float, before: float
    ) -> Planes:
        """As :meth:`associate`, with only the map points born at ``before`` (s) or earlier.

        Their tree is kept until ``before`` or the map's crop changes.
        """
        if self._old is None or self._old[0] != before:
            pts = self.points[self.born <= before]
            self._old = (before, cKDTree(pts) if len(pts) else None, pts)
        return self._fit(self._old[1], self._old[2], query_world, max_distance_m)

    def _fit(
        self,
        tree: cKDTree | None,
        points: np.ndarray,
        query_world: np.ndarray,
        max_distance_m: float,
    ) -> Planes:
        k = self.neighbours
        empty = Planes(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0))
        if tree is None or len(points) < k or len(query_world) == 0:
            return empty
        dist, nn = tree.query(query_world, k=k, distance_upper_bound=max_distance_m)
        ok = np.isfinite(dist[:, -1])
        if not ok.any():
            return empty
        idx = np.flatnonzero(ok)
        nbr = points[nn[idx]]  # [M, k, 3]
        centre = nbr.mean(axis=1)
        d = nbr - centre[:, None]
        cov = np.einsum("mki,mkj->mij", d, d) / k
        evals, evecs = np.linalg.eigh(cov)  # ascending
        planar = evals[:, 0] <= self.max_plane_rms_m**2
        spread = evals[:, 1] >= self.min_spread_ratio**2 * evals[:, 2]
        good = planar & spread
        normal = evecs[good, :, 0]
        return Planes(idx[good], normal, np.einsum("mi,mi->m", normal, centre[good]))
