"""Voxel plane maps for point-to-plane residuals, one hash shared by many candidate maps.

Each voxel accumulates the moments of the points inserted into it (count, sum, sum of outer
products) and keeps the plane fitted to them (normal = eigenvector of the smallest eigenvalue of
the covariance). A query point is matched to the plane of the voxel it falls in.

Voxels are keyed by int32 ``(group, ix, iy, iz)`` in one open3d ``HashMap`` so K candidate maps (the
``odometry`` mode, one map per candidate) and one shared map (``shared-map`` mode, group 0) use
the same code and a single batched lookup per iteration. open3d's hash map is used because torch
has no hash table and a dense grid per candidate would not fit in memory.
"""

from __future__ import annotations

import numpy as np
import open3d.core as o3c
import torch
from torch import Tensor
from torch.utils.dlpack import from_dlpack

# value layout: n, sum(3), outer(6: xx xy xz yy yz zz), normal(3), d, ok
_N, _S, _O, _NRM, _D, _OK, _WIDTH = 0, slice(1, 4), slice(4, 10), slice(10, 13), 13, 14, 15
_CPU = o3c.Device("CPU:0")


def _o3d(x: Tensor) -> o3c.Tensor:
    return o3c.Tensor.from_dlpack(torch.utils.dlpack.to_dlpack(x.contiguous()))


class VoxelPlaneMap:
    """Planes of accumulated points per voxel, for several independent maps (groups).

    Args:
        voxel_size_m: Edge of the cubic voxels (m).
        min_points: Points a voxel needs before its plane is used.
        max_thickness_m: Largest plane thickness (sqrt of smallest eigenvalue) accepted (m).
        capacity: Initial hash capacity (voxels over all groups).
    """

    def __init__(
        self,
        voxel_size_m: float,
        min_points: int = 5,
        max_thickness_m: float = 0.05,
        capacity: int = 1 << 18,
    ) -> None:
        self.voxel_size_m = float(voxel_size_m)
        self.min_points = int(min_points)
        self.max_thickness_m = float(max_thickness_m)
        self._hash = o3c.HashMap(
            capacity,
            key_dtype=o3c.int32,
            key_element_shape=(4,),
            value_dtypes=[o3c.float64],
            value_element_shapes=[(_WIDTH,)],
            device=_CPU,
        )

    def __len__(self) -> int:
        return int(self._hash.size())

    def _keys(self, points: Tensor, groups: Tensor) -> Tensor:
        """int32 keys ``[..., 4]`` = (group, ix, iy, iz) of points ``[..., 3]``."""
        ijk = torch.floor(points / self.voxel_size_m).clamp(-(2**30), 2**30).to(torch.int32)
        g = groups.to(torch.int32).expand(points.shape[:-1])[..., None]
        return torch.cat([g, ijk], dim=-1)

    def _values(self) -> Tensor:
        return from_dlpack(self._hash.value_tensor().to_dlpack())

    def _find(self, keys: Tensor) -> tuple[Tensor, Tensor]:
        return self._find_o3d(_o3d(keys.reshape(-1, 4)))

    def _find_o3d(self, keys: o3c.Tensor) -> tuple[Tensor, Tensor]:
        buf, mask = self._hash.find(keys)
        return from_dlpack(buf.to_dlpack()).to(torch.int64), from_dlpack(mask.to_dlpack())

    def insert(self, points: Tensor, groups: Tensor) -> None:
        """Adds world points ``[P, 3]`` (float64) to maps ``groups [P]`` and refits planes."""
        if points.shape[0] == 0:
            return
        keys = _o3d(self._keys(points, groups).reshape(-1, 4))
        _, fresh = self._hash.activate(keys)  # duplicate keys share one slot
        fresh = from_dlpack(fresh.to_dlpack())
        idx, _ = self._find_o3d(keys)
        values = self._values()  # re-fetch: activation may have reallocated the buffer
        values[idx[fresh]] = 0.0
        x, y, z = points.unbind(-1)
        per_point = torch.stack(
            [torch.ones_like(x), x, y, z, x * x, x * y, x * z, y * y, y * z, z * z], dim=-1
        )
        values[:, :10].index_add_(0, idx, per_point)
        self._refit(values, torch.unique(idx))

    def _refit(self, values: Tensor, idx: Tensor) -> None:
        v = values[idx]
        n = v[:, _N].clamp_min(1.0)
        mean = v[:, _S] / n[:, None]
        o = v[:, _O] / n[:, None]
        cov = (
            torch.stack(
                [o[:, 0], o[:, 1], o[:, 2], o[:, 1], o[:, 3], o[:, 4], o[:, 2], o[:, 4], o[:, 5]],
                -1,
            ).reshape(-1, 3, 3)
            - mean[:, :, None] * mean[:, None, :]
        )
        evals, evecs = torch.linalg.eigh(cov)
        normal = evecs[:, :, 0]
        thick = evals[:, 0].clamp_min(0).sqrt()
        spread = evals[:, 1].clamp_min(0).sqrt()
        ok = (
            (v[:, _N] >= self.min_points)
            & (thick <= self.max_thickness_m)
            & (spread >= 0.1 * self.voxel_size_m)
        )
        v[:, _NRM] = normal
        v[:, _D] = -(normal * mean).sum(-1)
        v[:, _OK] = ok.to(v.dtype)
        values[idx] = v

    def query(
        self, points: Tensor, groups: Tensor, neighbours: bool = False
    ) -> tuple[Tensor, Tensor, Tensor]:
        """Planes for points ``[..., 3]`` in maps ``groups`` (broadcastable to ``[...]``).

        Args:
            points: World points.
            groups: Map of each point.
            neighbours: Also try the 6 face-neighbouring voxels where the point's own voxel has no
                plane, keeping the plane with the smallest residual: widens the basin of
                convergence to about 1.5 voxels (used on the first iteration).

        Returns:
            ``normal [..., 3]``, ``d [...]`` (plane ``n·x + d = 0``) and ``ok [...]``.
        """
        shape = points.shape[:-1]
        keys = self._keys(points, groups).reshape(-1, 4)
        normal, d, ok = self._lookup(keys)
        if neighbours and not bool(ok.all()):
            miss = torch.nonzero(~ok).squeeze(-1)
            p_miss = points.reshape(-1, 3)[miss]
            best = torch.full((miss.shape[0],), float("inf"), dtype=points.dtype)
            for axis in range(3):
                for step in (-1, 1):
                    k = keys[miss].clone()
                    k[:, axis + 1] += step
                    n_k, d_k, ok_k = self._lookup(k)
                    res = ((n_k * p_miss).sum(-1) + d_k).abs()
                    better = ok_k & (res < best)
                    best = torch.where(better, res, best)
                    normal[miss] = torch.where(better[:, None], n_k, normal[miss])
                    d[miss] = torch.where(better, d_k, d[miss])
                    ok[miss] = ok[miss] | better
        return normal.reshape(*shape, 3), d.reshape(shape), ok.reshape(shape)

    def _lookup(self, keys: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        idx, found = self._find(keys)
        plane = self._values()[:, _NRM.start : _OK + 1][idx.clamp_min(0)]  # normal, d, ok
        ok = found & (plane[:, 4] > 0.5)
        plane = plane[:, :4] * ok[:, None]
        return plane[:, :3], plane[:, 3], ok

    def counts_per_group(self, num_groups: int) -> np.ndarray:
        """Number of voxels per group (for diagnostics)."""
        keys = from_dlpack(self._hash.key_tensor().to_dlpack())
        active = from_dlpack(self._hash.active_buf_indices().to_dlpack()).to(torch.int64)
        groups = keys[active, 0].to(torch.int64).numpy()
        return np.bincount(groups, minlength=num_groups)


_AXIS_BITS = 21  # ±1M voxels per axis: ±500 km at 0.5 m
_AXIS_OFF = 1 << (_AXIS_BITS - 1)


def _pack(ijk: Tensor) -> Tensor:
    """int64 key of integer voxel coordinates ``[..., 3]``; out-of-range coordinates clamp."""
    u = (ijk.to(torch.int64) + _AXIS_OFF).clamp(0, (1 << _AXIS_BITS) - 1)
    return (u[..., 0] << (2 * _AXIS_BITS)) | (u[..., 1] << _AXIS_BITS) | u[..., 2]


#: Largest bounding box (voxels) of a frozen map indexed by a dense grid: 8 M int32 cells,
#: 32 MB per process (a 400 m × 400 m × 50 m scene at 1 m voxels).
MAX_DENSE_CELLS = 8_000_000


class FrozenPlaneMap:
    """A read-only plane map (one group) answered by a dense index grid or by binary search.

    The shared map never changes after it is built, so instead of probing a hash table (slow
    when most queries miss, as they do for far-off candidates) every occupied voxel with a plane
    is kept in a sorted int64 key array. When the map's bounding box is small enough
    (:data:`MAX_DENSE_CELLS`), a dense int32 grid maps each voxel of the box to its plane and a
    lookup is one gather: written here because a per-scan ``torch.searchsorted`` over the keys
    was a fifth of an odometry step (profile in ``docs/backends.md``) and neither torch nor
    Open3D offers a batched read-only lookup that is faster. Larger maps keep the binary search.
    Both answer exactly the same.
    """

    def __init__(self, source: VoxelPlaneMap, group: int = 0) -> None:
        self.voxel_size_m = source.voxel_size_m
        keys = from_dlpack(source._hash.key_tensor().to_dlpack())
        active = from_dlpack(source._hash.active_buf_indices().to_dlpack()).to(torch.int64)
        values = source._values()[active]
        keys = keys[active]
        keep = (keys[:, 0] == group) & (values[:, _OK] > 0.5)
        packed = _pack(keys[keep, 1:])
        order = torch.argsort(packed)
        self._keys = packed[order].contiguous()
        self._planes = values[keep][order][:, _NRM.start : _D + 1].contiguous()  # n (3), d
        self._grid: Tensor | None = None  # dense index of the bounding box, or None
        ijk = keys[keep, 1:].to(torch.int64)[order]
        if len(ijk):
            lo, hi = ijk.min(0).values, ijk.max(0).values
            dims = hi - lo + 1
            if int(dims.prod()) <= MAX_DENSE_CELLS:
                self._lo, self._dims = lo, dims
                self._grid = torch.full((int(dims.prod()),), -1, dtype=torch.int32)
                self._grid[self._linear(ijk - lo)] = torch.arange(len(ijk), dtype=torch.int32)

    def _linear(self, rel: Tensor) -> Tensor:
        """Row-major cell index of box-relative voxel coordinates ``[..., 3]``."""
        return (rel[..., 0] * self._dims[1] + rel[..., 1]) * self._dims[2] + rel[..., 2]

    def __len__(self) -> int:
        return int(self._keys.shape[0])

    def _lookup(self, ijk: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        if len(self) == 0:
            z = torch.zeros(*ijk.shape[:-1], 3, dtype=torch.float64)
            return z, z[..., 0], torch.zeros(ijk.shape[:-1], dtype=torch.bool)
        if self._grid is not None:
            rel = ijk - self._lo
            inside = ((rel >= 0) & (rel < self._dims)).all(-1)
            cell = self._linear(torch.where(inside[..., None], rel, 0))
            idx = self._grid[cell].to(torch.int64)
            ok = inside & (idx >= 0)
            idx = idx.clamp_min(0)
        else:
            key = _pack(ijk)
            idx = torch.searchsorted(self._keys, key).clamp(max=len(self) - 1)
            ok = self._keys[idx] == key
        plane = self._planes[idx] * ok[..., None]
        return plane[..., :3], plane[..., 3], ok

    def query(
        self, points: Tensor, groups: Tensor | None = None, neighbours: bool = False
    ) -> tuple[Tensor, Tensor, Tensor]:
        """Same contract as :meth:`VoxelPlaneMap.query` (``groups`` is ignored)."""
        ijk = torch.floor(points / self.voxel_size_m).to(torch.int64)
        normal, d, ok = self._lookup(ijk)
        if neighbours and not bool(ok.all()):
            miss = ~ok
            p_miss, ijk_miss = points[miss], ijk[miss]
            best = torch.full(p_miss.shape[:-1], float("inf"), dtype=points.dtype)
            n_m, d_m, ok_m = normal[miss], d[miss], ok[miss]
            for axis in range(3):
                for step in (-1, 1):
                    shifted = ijk_miss.clone()
                    shifted[:, axis] += step
                    n_k, d_k, ok_k = self._lookup(shifted)
                    res = ((n_k * p_miss).sum(-1) + d_k).abs()
                    better = ok_k & (res < best)
                    best = torch.where(better, res, best)
                    n_m = torch.where(better[:, None], n_k, n_m)
                    d_m = torch.where(better, d_k, d_m)
                    ok_m = ok_m | better
            normal, d, ok = normal.clone(), d.clone(), ok.clone()
            normal[miss], d[miss], ok[miss] = n_m, d_m, ok_m
        return normal, d, ok
