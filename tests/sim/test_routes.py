"""Route paths: the loop turns left only, ``loop-cw`` right only, ``figure-8`` both ways."""

from __future__ import annotations

import numpy as np
import pytest

from l2calib.data import ImuSamples
from l2calib.errors import ConfigError
from l2calib.selection.planar import planar_motion
from l2calib.sim.config import SimConfig
from l2calib.sim.motion import RouteCurve
from l2calib.sim.profiles import build_motion, profile_params
from l2calib.sim.scenes import make_world
from l2calib.sim.sweep import check_clearance
from l2calib.sim.world import ROUTE_PATHS


def _turning(path: str) -> tuple[float, float]:
    """Total left and right heading change (rad) along the route's closed centre line."""
    curve = RouteCurve(make_world("urban", 3, path=path).route)
    s = np.linspace(0.0, curve.length, 20000, endpoint=False)
    dpsi = curve.curvature(s) * (curve.length / len(s))
    return float(dpsi[dpsi > 0].sum()), float(-dpsi[dpsi < 0].sum())


@pytest.mark.parametrize(
    ("path", "left", "right"),
    [("loop", 2 * np.pi, 0), ("loop-cw", 0, 2 * np.pi), ("figure-8", 2 * np.pi, 2 * np.pi)],
)
def test_each_path_turns_the_way_it_says(path, left, right):
    got = _turning(path)
    assert np.allclose(got, (left, right), atol=0.05), got


def test_loop_cw_drives_the_same_streets_and_figure_8_adds_a_cross_street():
    loop, cw, eight = (make_world("urban", 4, path=p) for p in ROUTE_PATHS)
    assert np.array_equal(loop.vertices, cw.vertices)  # same mesh, route reversed
    a, b = loop.route.polyline(), cw.route.polyline()
    assert np.allclose(a[0], b[0]) and np.allclose(a[1:], b[:0:-1])
    assert eight.route.path == "figure-8" and len(eight.vertices) != len(loop.vertices)
    # The cross street is open: 4 m above its centre line the nearest surface is the road.
    mid = eight.route.polyline()
    on_cross = mid[np.abs(mid[:, 0]) < 0.01]
    assert len(on_cross) > 20
    pts = np.c_[on_cross, np.full(len(on_cross), 4.0)]
    assert eight.distance(pts).min() > 3.99


def test_unknown_or_unsupported_paths_fail_with_the_fix():
    with pytest.raises(ConfigError, match="no figure-8 route") as err:
        make_world("hall", 0, path="figure-8")
    assert "world.name=urban" in err.value.fix
    with pytest.raises(ConfigError, match="unknown route path 'spiral'"):
        make_world("urban", 0, path="spiral")
    with pytest.raises(ValueError, match="unknown route path"):
        SimConfig.model_validate({"world": {"route": "spiral"}})


@pytest.mark.parametrize("profile", ["handheld", "uav", "ugv"])
def test_figure_8_keeps_clear_of_every_surface(profile):
    T = np.eye(4)
    T[:3, 3] = [0.65, -0.372, -0.016]  # the paper's handheld rig: largest lever arm
    w = make_world("urban", 2, path="figure-8")
    m = build_motion(w, profile_params(profile), 0.75, 75.0, [(0.0, 1.0)], np.random.default_rng(2))
    assert check_clearance(w, m, T, 75.0) >= w.clearance_m / 2


@pytest.mark.parametrize(("path", "lo", "hi"), [("loop", 0.95, 1.0), ("figure-8", 0.0, 0.3)])
def test_one_way_share_of_a_simulated_drive(path, lo, hi):
    w = make_world("urban", 5, path=path)
    m = build_motion(w, profile_params("ugv"), 0.2, 62.0, [(0.0, 1.0)], np.random.default_rng(5))
    t = np.arange(1.0, 60.0, 0.005)
    st = m.state(t)
    f_imu = np.einsum("nji,nj->ni", st.R_world_base, st.a_world_imu + [0.0, 0.0, 9.81])
    imu = ImuSamples((t * 1e9).astype(np.int64), st.omega_base, f_imu)
    share = planar_motion([imu]).one_way_share
    assert lo <= share <= hi, share
