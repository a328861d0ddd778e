"""Procedural, seeded worlds as triangle meshes, ray-cast with open3d's ``RaycastingScene``.

World frame: z up, ground top at ``z = 0`` (m). Each world also defines a closed *route* (the
centre line the rig follows) with the free space around it, so that every motion profile stays
clear of the structures:

* ``urban`` — a street ring around a central block: buildings on both sides, sidewalks with
  curbs, street lights, trees, benches, bins and parked cars.
* ``hall`` — an indoor hall: walls, ceiling, pillars, shelves, tables and crates.
* ``corridor`` — a long, narrow corridor with almost no features (degenerate along its axis).
* ``open-field`` — a ground plane with a handful of distant objects (degenerate).

Meshes are assembled from open3d primitives (boxes, cylinders); each triangle carries a
reflectivity in ``[0, 1]`` that drives the simulated intensity.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

WORLD_NAMES = ("urban", "hall", "corridor", "open-field")
# How the rig drives its route: ``loop`` counter-clockwise (left turns only), ``loop-cw`` the same
# loop clockwise (right turns only), ``figure-8`` (urban only: a cross street splits the central
# block; one lap around each half, left turns then right turns).
ROUTE_PATHS = ("loop", "loop-cw", "figure-8")


@dataclass(frozen=True)
class Route:
    """Closed centre line of the rig's path with the free space around it.

    Attributes:
        half_x_m: Half length of the rounded-rectangle route along x (m).
        half_y_m: Half length along y (m).
        corner_radius_m: Corner radius (m); equal half sizes and radius give a circle.
        half_width_m: Free lateral distance either side of the centre line, clearance included
            (the rig origin plus its lever arm must stay within it).
        z_range_m: ``(min, max)`` free heights for any part of the rig (m).
        path: One of :data:`ROUTE_PATHS`: the rounded rectangle counter-clockwise (``loop``) or
            clockwise (``loop-cw``), or a ``figure-8`` through a cross street along ``x = 0``.
    """

    half_x_m: float
    half_y_m: float
    corner_radius_m: float
    half_width_m: float
    z_range_m: tuple[float, float]
    path: str = "loop"

    def polyline(self, spacing_m: float = 0.25) -> np.ndarray:
        """``[M, 2]`` points of the closed centre line, uniform in arc length.

        ``loop`` starts at the middle of the bottom (``y = -half_y``) side heading +x and turns
        left; ``loop-cw`` is the same line backwards (heading -x, right turns); ``figure-8``
        starts at the origin heading +y, laps the left half counter-clockwise, then the right
        half clockwise.
        """
        if self.path == "figure-8":
            return _figure8(self.half_x_m, self.half_y_m, self.corner_radius_m, spacing_m)
        loop = self._loop(spacing_m)
        return loop if self.path == "loop" else np.roll(loop[::-1], 1, axis=0)

    def _loop(self, spacing_m: float) -> np.ndarray:
        r = self.corner_radius_m
        ax, ay = self.half_x_m - r, self.half_y_m - r
        # Piecewise: bottom, corner, right, corner, top, corner, left, corner (lengths).
        lengths = np.array([2 * ax, np.pi * r / 2, 2 * ay, np.pi * r / 2] * 2)
        total = lengths.sum()
        n = max(int(np.ceil(total / spacing_m)), 64)
        s = (np.arange(n) / n * total + ax) % total  # start mid-bottom
        bounds = np.concatenate([[0.0], np.cumsum(lengths)])
        seg = np.clip(np.searchsorted(bounds, s, side="right") - 1, 0, 7)
        f = s - bounds[seg]
        out = np.empty((n, 2))
        corners = [(ax, -ay, -np.pi / 2), (ax, ay, 0.0), (-ax, ay, np.pi / 2), (-ax, -ay, np.pi)]
        starts = [
            (-ax, -ay - r, 1, 0),
            (ax + r, -ay, 0, 1),
            (ax, ay + r, -1, 0),
            (-ax - r, ay, 0, -1),
        ]
        for k in range(8):
            m = seg == k
            if k % 2 == 0:
                x0, y0, dx, dy = starts[k // 2]
                out[m] = np.stack([x0 + dx * f[m], y0 + dy * f[m]], 1)
            else:
                cx, cy, a0 = corners[k // 2]
                ang = a0 + f[m] / max(r, 1e-9)
                out[m] = np.stack([cx + r * np.cos(ang), cy + r * np.sin(ang)], 1)
        return out


def _figure8(hx: float, hy: float, r: float, spacing_m: float) -> np.ndarray:
    """``[M, 2]`` figure-8 centre line (see :meth:`Route.polyline`), uniform in arc length.

    Straights and 90° arcs of radius ``r`` traced as a turtle path (a piecewise line of this
    kind has no library generator worth a dependency).
    """
    sx, sy = hx - 2 * r, hy - r  # straight lengths: half of the top/bottom side, middle half
    moves: list[tuple[float, int]] = []  # (straight m, then a 90° turn: +1 left, -1 right)
    for turn in (1, -1):
        moves += [(sy, turn), (sx, turn), (2 * hy - 2 * r, turn), (sx, turn), (sy, 0)]
    total = sum(m for m, _ in moves) + 8 * np.pi * r / 2
    n = max(int(np.ceil(total / spacing_m)), 64)
    out, s_want = [], np.arange(n) / n * total
    pos, heading, s0 = np.zeros(2), np.pi / 2, 0.0
    for length, turn in moves:
        d = np.array([np.cos(heading), np.sin(heading)])
        m = (s_want >= s0) & (s_want < s0 + length)
        out.append(pos + np.outer(s_want[m] - s0, d))
        pos, s0 = pos + length * d, s0 + length
        if turn:
            arc = np.pi * r / 2
            centre = pos + turn * r * np.array([-d[1], d[0]])
            m = (s_want >= s0) & (s_want < s0 + arc)
            ang = heading - turn * np.pi / 2 + turn * (s_want[m] - s0) / r
            out.append(centre + r * np.column_stack([np.cos(ang), np.sin(ang)]))
            heading, s0 = heading + turn * np.pi / 2, s0 + arc
            back = heading - turn * np.pi / 2
            pos = centre + r * np.array([np.cos(back), np.sin(back)])
    return np.concatenate(out)


@dataclass(eq=False)
class World:
    """A static scene: triangle mesh, per-triangle reflectivity and the route through it.

    Attributes:
        name: World kind (one of :data:`WORLD_NAMES`).
        seed: Seed it was generated from.
        vertices: ``[V, 3]`` float32 vertex positions in the world frame (m).
        triangles: ``[T, 3]`` int32 vertex indices.
        reflectivity: ``[T]`` float32 reflectivity of each triangle in ``[0, 1]``.
        route: The rig's route and free space.
        clearance_m: Minimum distance kept between the rig and any surface (m).
    """

    name: str
    seed: int
    vertices: np.ndarray
    triangles: np.ndarray
    reflectivity: np.ndarray
    route: Route
    clearance_m: float = 0.4
    _scene: Any = field(default=None, repr=False)

    @property
    def scene(self) -> Any:
        """The open3d ``RaycastingScene`` (built on first use)."""
        if self._scene is None:
            import open3d as o3d

            mesh = o3d.t.geometry.TriangleMesh()
            mesh.vertex.positions = o3d.core.Tensor(self.vertices.astype(np.float32))
            mesh.triangle.indices = o3d.core.Tensor(self.triangles.astype(np.int32))
            scene = o3d.t.geometry.RaycastingScene()
            scene.add_triangles(mesh)
            self._scene = scene
        return self._scene

    def cast(
        self, origins: np.ndarray, directions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Casts rays; returns ``(range [N], triangle id [N], unit normal [N, 3])``.

        ``directions`` must be unit vectors (world frame); misses get ``range = inf`` and id -1.
        """
        import open3d as o3d

        rays = np.concatenate([origins, directions], axis=1).astype(np.float32)
        hit = self.scene.cast_rays(o3d.core.Tensor(rays))
        rng = hit["t_hit"].numpy().astype(np.float64)
        ids = hit["primitive_ids"].numpy().astype(np.int64)
        ids[~np.isfinite(rng)] = -1
        return rng, ids, hit["primitive_normals"].numpy()

    def distance(self, points: np.ndarray) -> np.ndarray:
        """``[N]`` unsigned distance (m) from world points ``[N, 3]`` to the nearest surface.

        open3d 0.20's closest-point query can miss long, thin triangles (e.g. a curb face
        0.15 m x 90 m) and then returns the distance to the next surface; use it for clearance,
        not as an exact oracle (re-cast a ray through a point to check it lies on a surface).
        """
        import open3d as o3d

        q = o3d.core.Tensor(np.asarray(points, dtype=np.float32))
        return self.scene.compute_distance(q).numpy().astype(np.float64)
