"""Procedural scene builders: open3d primitives assembled into each world's mesh.

:func:`make_world` builds a world by name. Each builder adds its structures to a
:class:`MeshBuilder` and returns the world's :class:`~l2calib.sim.world.Route` (centre line and
free space around it, clearance included).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from l2calib.errors import ConfigError
from l2calib.sim.world import ROUTE_PATHS, WORLD_NAMES, Route, World


class MeshBuilder:
    """Accumulates open3d primitives with one reflectivity per primitive."""

    def __init__(self) -> None:
        self.vertices: list[np.ndarray] = []
        self.triangles: list[np.ndarray] = []
        self.refl: list[np.ndarray] = []
        self._count = 0

    def _add(self, mesh: Any, refl: float) -> None:
        v = np.asarray(mesh.vertices, dtype=np.float64)
        t = np.asarray(mesh.triangles, dtype=np.int64) + self._count
        self.vertices.append(v)
        self.triangles.append(t)
        self.refl.append(np.full(len(t), refl, dtype=np.float32))
        self._count += len(v)

    def box(
        self,
        cx: float,
        cy: float,
        z0: float,
        sx: float,
        sy: float,
        sz: float,
        refl: float,
        yaw: float = 0.0,
    ) -> None:
        """Box of size ``(sx, sy, sz)`` centred at ``(cx, cy)`` in xy, bottom at ``z0``."""
        import open3d as o3d

        m = o3d.geometry.TriangleMesh.create_box(sx, sy, sz)
        m.translate((-sx / 2, -sy / 2, 0.0))
        if yaw:
            m.rotate(m.get_rotation_matrix_from_xyz((0.0, 0.0, yaw)), center=(0.0, 0.0, 0.0))
        m.translate((cx, cy, z0))
        self._add(m, refl)

    def cylinder(
        self, cx: float, cy: float, z0: float, radius: float, height: float, refl: float
    ) -> None:
        """Vertical cylinder (16-sided prism) standing on ``z0``."""
        import open3d as o3d

        m = o3d.geometry.TriangleMesh.create_cylinder(radius, height, resolution=16, split=1)
        m.translate((cx, cy, z0 + height / 2))
        self._add(m, refl)

    def build(self, name: str, seed: int, route: Route, clearance_m: float) -> World:
        """The accumulated mesh as a :class:`World`."""
        return World(
            name=name,
            seed=seed,
            vertices=np.concatenate(self.vertices).astype(np.float32),
            triangles=np.concatenate(self.triangles).astype(np.int32),
            reflectivity=np.concatenate(self.refl),
            route=route,
            clearance_m=clearance_m,
        )


def _ring_positions(rng: np.random.Generator, half: float, spacing: float) -> np.ndarray:
    """Jittered positions along ``[-half, half]`` about every ``spacing`` metres."""
    n = max(int(2 * half / spacing), 1)
    base = np.linspace(-half, half, n + 1)[:-1] + spacing / 2
    return base + rng.uniform(-0.25, 0.25, size=base.shape) * spacing


def _sides(hx: float, hy: float) -> list[tuple[float, float, float, float]]:
    """The four straight sides as (centre x, centre y, half length, orientation 0=x / 1=y)."""
    return [(0.0, -hy, hx, 0), (0.0, hy, hx, 0), (-hx, 0.0, hy, 1), (hx, 0.0, hy, 1)]


def _along(side: tuple[float, float, float, float], s: float, d: float) -> tuple[float, float]:
    """Point at ``s`` along a side and ``d`` outward (away from the origin)."""
    cx, cy, _, axis = side
    if axis == 0:
        return s, cy + np.sign(cy) * d
    return cx + np.sign(cx) * d, s


def _balconies(
    rng: np.random.Generator,
    b: MeshBuilder,
    span: tuple[float, float],
    line: float,
    height: float,
    axis: int,
) -> None:
    """Balcony slabs (0.8 m deep, 1 m tall) on a facade: every 3 m floor, every ~5 m along it.

    ``span`` is the facade's extent along x (``axis`` 0) or y (1); ``line`` the slab centres'
    other coordinate. Facade detail gives LiDAR odometry structure along the street.
    """
    for z in np.arange(3.0, height - 1.0, 3.0):
        for s in np.arange(span[0] + 2.5, span[1] - 2.0, 5.0):
            if rng.random() < 0.6:
                w = rng.uniform(2.0, 4.0)
                x, y = (s, line) if axis == 0 else (line, s)
                sx, sy = (w, 0.8) if axis == 0 else (0.8, w)
                b.box(x, y, z, sx, sy, 1.0, rng.uniform(0.3, 0.8))


def _block(
    rng: np.random.Generator, b: MeshBuilder, spans: list[tuple[float, float]], by: float
) -> None:
    """Central block(s): one row of buildings per ``(x0, x1)`` span, ``2 by`` deep.

    Buildings of different heights with narrow gaps, balconies on both long facades.
    """
    for lo, hi in spans:
        edges = np.sort(rng.uniform(lo, hi, size=rng.integers(1, 4)))
        xs = np.concatenate([[lo], edges, [hi]])
        for x0, x1 in zip(xs[:-1], xs[1:], strict=True):
            gap = rng.uniform(0.0, 2.5)
            if x1 - x0 - gap > 3:
                sy, h = 2 * by - rng.uniform(0, 3), rng.uniform(6, 25)
                b.box((x0 + x1) / 2, 0, 0.15, x1 - x0 - gap, sy, h, rng.uniform(0.3, 0.7))
                for sign in (-1.0, 1.0):  # balconies on both long facades
                    _balconies(rng, b, (x0 + gap / 2, x1 - gap / 2), sign * (sy / 2 + 0.4), h, 0)


def _urban(rng: np.random.Generator, b: MeshBuilder, cross: bool = False) -> Route:
    """The street ring around a central block (buildings, sidewalks, furniture, parked cars).

    ``cross``: a smaller ring whose block a cross street along ``x = 0`` splits in two, for the
    ``figure-8`` path (one lap ≈ 210 m, about a minute at 4 m/s).
    """
    if cross:
        bx, by = rng.uniform(18, 22), rng.uniform(7, 9)
    else:
        bx, by = rng.uniform(25, 35), rng.uniform(15, 22)
    hx, hy = bx + 8, by + 8  # route: 8 m outside the block, road from -5 to +5 around it
    b.box(0, 0, -0.2, 400, 400, 0.2, 0.25)  # ground (asphalt)
    if cross:  # the inner sidewalks end 5 m either side of the cross street's centre line
        for sign in (-1.0, 1.0):
            b.box(sign * (bx + 8) / 2, 0, 0.0, bx - 2, 2 * (by + 3), 0.15, 0.35)
            for y in _ring_positions(rng, hy - 9.0, 12.0):  # street lights along it
                b.cylinder(sign * 6.5, y, 0.15, 0.12, rng.uniform(5, 8), 0.8)
    else:
        b.box(0, 0, 0.0, 2 * (bx + 3), 2 * (by + 3), 0.15, 0.35)  # inner sidewalk with curb
    for side in _sides(hx + 6.5, hy + 6.5):  # outer sidewalks, 3 m wide
        length = 2 * side[2] + 3
        sx, sy = (length, 3.0) if side[3] == 0 else (3.0, length)
        b.box(side[0], side[1], 0.0, sx, sy, 0.15, 0.35)
    _block(rng, b, [(-bx, -8.0), (8.0, bx)] if cross else [(-bx, bx)], by)
    # Outer buildings, 16 m from the route's sides outward (with cross streets as gaps).
    for side in _sides(hx + 8, hy + 8):
        s = -side[2] - 16.0
        while s < side[2] + 16.0:
            width, gap = rng.uniform(8, 25), rng.uniform(0, 8) if rng.random() < 0.5 else 0.5
            depth = rng.uniform(10, 20)
            cx, cy = _along(side, s + width / 2, depth / 2)
            sx, sy = (width, depth) if side[3] == 0 else (depth, width)
            h = rng.uniform(5, 30)
            b.box(cx, cy, 0.0, sx, sy, h, rng.uniform(0.3, 0.7))
            # Balconies on the street facade (d = 0 is the facade, negative d is the street).
            c = side[1] if side[3] == 0 else side[0]
            line = c - np.sign(c) * 0.4
            _balconies(rng, b, (s, s + width), line, h, side[3])
            s += width + gap
    # Street furniture on both sidewalks (straight parts only).
    for side in _sides(hx, hy):
        straight = side[2] - 8.0
        for d_out, spacing in ((-6.5, 14.0), (6.5, 15.0)):  # inner / outer sidewalk lines
            for s in _ring_positions(rng, straight, spacing):
                x, y = _along(side, s, d_out)
                # Keep the cross street's mouth free of lights. The item half a spacing further on
                # can still land at its edge (a bin, a bench or a tree 3-5 m from its centre
                # line, e.g. x = -4.5 m on seed 31); kept so the measured figure-8 rows reproduce.
                if cross and d_out < 0 and abs(x) < 10.0:
                    continue
                b.cylinder(x, y, 0.15, 0.12, rng.uniform(5, 8), 0.8)  # street light
                kind = rng.integers(0, 4)
                x2, y2 = _along(side, s + spacing / 2, d_out + np.sign(d_out) * 0.5)
                if kind == 0:  # tree: trunk and canopy
                    b.cylinder(x2, y2, 0.15, 0.2, 3.0, 0.4)
                    b.box(x2, y2, 3.0, 3.0, 3.0, 2.5, 0.5, yaw=rng.uniform(0, np.pi))
                elif kind == 1:
                    b.cylinder(x2, y2, 0.15, 0.3, 1.0, 0.6)  # bin
                elif kind == 2:
                    b.box(x2, y2, 0.15, 1.8, 0.5, 0.8, 0.5, yaw=0.0 if side[3] == 0 else np.pi / 2)
        for d_car in (-4.1, 4.1):  # parked cars in the parking lanes
            for s in _ring_positions(rng, straight - 3, 9.0):
                if rng.random() < 0.45:
                    x, y = _along(side, s, d_car)
                    if cross and d_car < 0 and abs(x) < 10.0:
                        continue
                    sx, sy = (4.5, 1.8) if side[3] == 0 else (1.8, 4.5)
                    b.box(x, y, 0.0, sx, sy, rng.uniform(1.4, 1.9), rng.uniform(0.2, 0.9))
    return Route(hx, hy, 8.0, half_width_m=4.1 - 0.9 - 0.4, z_range_m=(0.0, 30.0))


def _hall(rng: np.random.Generator, b: MeshBuilder) -> Route:
    hx_room, hy_room, height = rng.uniform(22, 28), rng.uniform(13, 17), rng.uniform(7, 10)
    b.box(0, 0, -0.2, 2 * hx_room + 2, 2 * hy_room + 2, 0.2, 0.3)  # floor
    b.box(0, 0, height, 2 * hx_room + 2, 2 * hy_room + 2, 0.3, 0.4)  # ceiling
    for sx, sy, cx, cy in (
        (2 * hx_room, 0.3, 0, hy_room),
        (2 * hx_room, 0.3, 0, -hy_room),
        (0.3, 2 * hy_room, hx_room, 0),
        (0.3, 2 * hy_room, -hx_room, 0),
    ):
        b.box(cx, cy, 0.0, sx, sy, height, 0.6)
    hx, hy = hx_room - 7, hy_room - 6  # route 6-7 m from the walls
    # Roof beams across the hall every 5 m and wall ribs every 3 m: structure along every axis.
    for x in np.arange(-hx_room + 2.5, hx_room - 1.0, 5.0):
        b.box(x, 0.0, height - 0.6, 0.4, 2 * hy_room, 0.6, 0.5)
    for x in np.arange(-hx_room + 1.5, hx_room - 1.0, 3.0):
        for y in (-hy_room + 0.275, hy_room - 0.275):
            b.box(x, y, 0.0, 0.4, 0.25, height, 0.6)
    for y in np.arange(-hy_room + 1.5, hy_room - 1.0, 3.0):
        for x in (-hx_room + 0.275, hx_room - 0.275):
            b.box(x, y, 0.0, 0.25, 0.4, height, 0.6)
    # Pillars along the walls and in the central island.
    for x in np.arange(-hx_room + 3, hx_room - 2, 6.0):
        for y in (-hy_room + 0.45, hy_room - 0.45):
            b.box(x, y, 0.0, 0.6, 0.6, height, 0.55)
    for x in np.linspace(-(hx - 4), hx - 4, 5):
        b.box(x, 0.0, 0.0, 0.6, 0.6, height, 0.55)
    # Furniture: against the walls (>= 3.5 m from the route) and in the island.
    for _ in range(rng.integers(12, 20)):
        side = _sides(hx_room, hy_room)[rng.integers(0, 4)]
        s = rng.uniform(-side[2] + 2, side[2] - 2)
        depth = rng.uniform(0.5, 1.2)
        x, y = _along(side, s, -depth / 2 - 0.2)
        w = rng.uniform(1.0, 3.0)
        sx, sy = (w, depth) if side[3] == 0 else (depth, w)
        b.box(x, y, 0.0, sx, sy, rng.uniform(0.7, 2.2), rng.uniform(0.2, 0.8))
    for _ in range(rng.integers(8, 14)):
        x, y = rng.uniform(-(hx - 5), hx - 5), rng.uniform(-(hy - 5), hy - 5)
        b.box(
            x,
            y,
            0.0,
            rng.uniform(0.6, 2.0),
            rng.uniform(0.6, 1.5),
            rng.uniform(0.5, 1.8),
            rng.uniform(0.2, 0.8),
            yaw=rng.uniform(0, np.pi),
        )
    return Route(hx, hy, 4.0, half_width_m=3.0, z_range_m=(0.0, height - 0.6))


def _corridor(rng: np.random.Generator, b: MeshBuilder) -> Route:
    half_len, half_w, height = rng.uniform(40, 60), 2.0, 3.0
    b.box(0, 0, -0.2, 2 * half_len + 2, 2 * half_w + 2, 0.2, 0.3)
    b.box(0, 0, height, 2 * half_len + 2, 2 * half_w + 2, 0.2, 0.5)
    for y in (-half_w - 0.1, half_w + 0.1):
        b.box(0, y, 0.0, 2 * half_len + 2, 0.2, height, 0.6)
    for x in (-half_len - 0.1, half_len + 0.1):
        b.box(x, 0, 0.0, 0.2, 2 * half_w, height, 0.6)
    for _ in range(rng.integers(2, 5)):  # a few flat pilasters / cabinets: near-degenerate
        y = (half_w - 0.1) * rng.choice([-1.0, 1.0])
        b.box(
            rng.uniform(-half_len + 5, half_len - 5),
            y,
            rng.uniform(0.0, 1.0),
            rng.uniform(0.3, 1.0),
            0.2,
            rng.uniform(0.5, 2.0),
            rng.uniform(0.3, 0.9),
        )
    # Out-and-back lanes 0.5 m either side of the axis: 2.0 - 0.5 - 0.2 (features) - clearance.
    return Route(half_len - 3.0, 0.5, 0.5, half_width_m=0.9, z_range_m=(0.0, height - 0.4))


def _open_field(rng: np.random.Generator, b: MeshBuilder) -> Route:
    b.box(0, 0, -0.2, 500, 500, 0.2, 0.2)
    for _ in range(rng.integers(4, 8)):
        radius, ang = rng.uniform(25, 70), rng.uniform(0, 2 * np.pi)
        x, y = radius * np.cos(ang), radius * np.sin(ang)
        if rng.random() < 0.5:
            b.cylinder(x, y, 0.0, rng.uniform(0.15, 0.4), rng.uniform(3, 8), 0.5)
        else:
            b.box(
                x,
                y,
                0.0,
                rng.uniform(2, 6),
                rng.uniform(2, 6),
                rng.uniform(2, 4),
                rng.uniform(0.3, 0.7),
                yaw=rng.uniform(0, np.pi),
            )
    return Route(15.0, 15.0, 15.0, half_width_m=5.0, z_range_m=(0.0, 30.0))


BUILDERS = {"urban": _urban, "hall": _hall, "corridor": _corridor, "open-field": _open_field}


def make_world(name: str, seed: int = 0, clearance_m: float = 0.4, path: str = "loop") -> World:
    """Builds the named world from ``seed`` (same name, seed and path give the same mesh).

    ``path`` (one of :data:`~l2calib.sim.world.ROUTE_PATHS`) is how the route is driven;
    ``figure-8`` builds the urban world with a cross street (a different mesh).

    Raises:
        ConfigError: if ``name`` is not one of :data:`WORLD_NAMES`, ``path`` not one of
            ``ROUTE_PATHS``, or ``figure-8`` is asked of a world other than ``urban``.
    """
    if name not in BUILDERS:
        raise ConfigError(f"unknown world {name!r}", fix=f"choose one of: {', '.join(WORLD_NAMES)}")
    if path not in ROUTE_PATHS:
        raise ConfigError(
            f"unknown route path {path!r}", fix=f"choose one of: {', '.join(ROUTE_PATHS)}"
        )
    if path == "figure-8" and name != "urban":
        raise ConfigError(
            f"the {name} world has no figure-8 route (only urban has a cross street)",
            fix="use world.name=urban, or world.route=loop / loop-cw",
        )
    rng = np.random.default_rng([seed, 17])
    builder = MeshBuilder()
    route = _urban(rng, builder, cross=True) if path == "figure-8" else BUILDERS[name](rng, builder)
    return builder.build(name, seed, dataclasses.replace(route, path=path), clearance_m)
