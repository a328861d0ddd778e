"""Surface normals of a spinning LiDAR's scan points from its scan lines, for ``ct-lidar``.

A sparse LiDAR (16 beams) draws the ground and far walls as lines metres apart: every map
neighbourhood there lies on one line, so the map gives no plane (:mod:`l2calib.references.
ct_map` rejects line-like neighbourhoods), and the ground, which holds the height, pitch and
roll of a UAV or a ground vehicle, goes unused. Within one scan the surface is still seen across
lines: a point, its neighbours on its own line and the points of the lines just above and below
at the same azimuth span a patch of the surface, however far apart the lines are (as LOAM and
LeGO-LOAM use the range image's rows and columns). The normal is kept only where the patch up
holds the point below and the patch down the point above (a curb or an edge between the lines
bends them apart).

Hand-written: open3d's and scipy's neighbour searches are Euclidean, which on 16 lines finds
the point's own line only; the range-image structure needs the ring of every point.
"""

from __future__ import annotations

import numpy as np


def _unit(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    norm = np.linalg.norm(v, axis=1)
    return v / np.where(norm > 0, norm, 1.0)[:, None], norm


def line_normals(
    points: np.ndarray,
    ring: np.ndarray,
    query: np.ndarray,
    max_gap_ratio: float = 0.4,
    max_offset_m: float = 0.05,
) -> np.ndarray:
    """Unit normals ``[Q, 3]`` (LiDAR frame) at scan points ``points[query]``, NaN where unknown.

    Args:
        points: ``[N, 3]`` one scan's points (LiDAR frame, m).
        ring: ``[N]`` laser ring of each point (any numbering; lines are ordered by elevation).
        query: ``[Q]`` indices of the points whose normals are wanted.
        max_gap_ratio: A neighbour on an adjacent line may be at most this times the point's
            range away (and its own-line neighbours at most a tenth of it).
        max_offset_m: Largest distance of the point below from the patch spanned upwards,
            and of the point above from the patch spanned downwards (m).
    """
    n_out = np.full((len(query), 3), np.nan)
    if len(points) < 3 or len(query) == 0:
        return n_out
    rng_m = np.linalg.norm(points, axis=1)
    elev = np.arctan2(points[:, 2], np.hypot(points[:, 0], points[:, 1]))
    rings, ring_idx = np.unique(ring, return_inverse=True)
    order = np.argsort([np.median(elev[ring_idx == i]) for i in range(len(rings))])
    rank = np.empty(len(rings), np.int64)
    rank[order] = np.arange(len(rings))
    line = rank[ring_idx]
    az = (np.arctan2(points[:, 1], points[:, 0]) + np.pi) / (2 * np.pi)  # [0, 1]
    key = line * 2.0 + az  # lines do not overlap: 2 apart
    sort = np.argsort(key)
    skey = key[sort]
    pos = np.searchsorted(skey, key[query])  # the query's own slot (keys are unique enough)

    def at(slot: np.ndarray, want_line: np.ndarray) -> np.ndarray:
        """Point indices at sorted ``slot``, -1 where outside or on another line."""
        ok = (slot >= 0) & (slot < len(sort))
        idx = np.where(ok, sort[slot.clip(0, len(sort) - 1)], -1)
        return np.where(ok & (line[idx] == want_line), idx, -1)

    lq = line[query]
    prev, nxt = at(pos - 1, lq), at(pos + 1, lq)

    def nearest_on(dl: int) -> np.ndarray:
        want = lq + dl
        s = np.searchsorted(skey, want * 2.0 + az[query])
        a, b = at(s - 1, want), at(s, want)
        da = np.where(a >= 0, np.abs(az[a] - az[query]), np.inf)
        db = np.where(b >= 0, np.abs(az[b] - az[query]), np.inf)
        return np.where(da <= db, a, b)

    up, down = nearest_on(1), nearest_on(-1)
    p = points[query]
    r = rng_m[query][:, None]
    ok = (prev >= 0) & (nxt >= 0) & (up >= 0) & (down >= 0)
    tang, tlen = _unit(points[nxt] - points[prev])
    u, ulen = _unit(points[up] - p)
    d, dlen = _unit(points[down] - p)
    ok &= (tlen <= 0.2 * r[:, 0]) & (ulen <= max_gap_ratio * r[:, 0])
    ok &= dlen <= max_gap_ratio * r[:, 0]
    n_up, s_up = _unit(np.cross(tang, u))
    n_dn, s_dn = _unit(np.cross(tang, d))
    ok &= (s_up > 0.3) & (s_dn > 0.3)  # the lines are not along the tangent
    off_dn = np.abs(np.einsum("ni,ni->n", n_up, points[down] - p))
    off_up = np.abs(np.einsum("ni,ni->n", n_dn, points[up] - p))
    ok &= (off_dn <= max_offset_m) & (off_up <= max_offset_m)
    sign = np.sign(np.einsum("ni,ni->n", n_up, n_dn))[:, None]
    n, _ = _unit(n_up + sign * n_dn)
    n_out[ok] = n[ok]
    return n_out
