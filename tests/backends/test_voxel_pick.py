"""Which point of each voxel the backend's downsampling keeps (``voxel_point``)."""

from __future__ import annotations

import numpy as np

from l2calib.references.ct_map import voxel_pick
from l2calib_backends.prepare import voxel_means


def _sweep(n: int = 2000) -> np.ndarray:
    """Points in firing order along a 10 m arc at 8 m range (one sweep of one ring)."""
    az = np.linspace(0.0, 1.25, n)
    return np.stack([8.0 * np.cos(az), 8.0 * np.sin(az), np.zeros(n)], axis=1)


def _voxels(points: np.ndarray, voxel_m: float) -> np.ndarray:
    return np.floor(points / voxel_m).astype(np.int64)


def test_earliest_keeps_the_first_fired_point_of_each_voxel() -> None:
    pts = _sweep()
    idx = voxel_pick(pts, 0.5, None)
    keys = _voxels(pts, 0.5)
    _, expected = np.unique(keys, axis=0, return_index=True)
    assert sorted(idx.tolist()) == sorted(expected.tolist())


def test_random_keeps_one_point_per_voxel_not_tied_to_firing_order() -> None:
    pts = _sweep()
    earliest = np.sort(voxel_pick(pts, 0.5, None))
    picked = np.sort(voxel_pick(pts, 0.5, np.random.default_rng(3)))
    keys = _voxels(pts[picked], 0.5)
    assert len(picked) == len(earliest)
    assert len(np.unique(keys, axis=0)) == len(picked)  # one per voxel, every voxel
    # Most voxels hold ~20 points: a random pick is the earliest in only a few of them.
    assert np.mean(picked == earliest) < 0.3
    again = np.sort(voxel_pick(pts, 0.5, np.random.default_rng(3)))
    assert np.array_equal(picked, again)  # seeded: reproducible


def test_centroid_is_each_voxels_mean_point_and_time() -> None:
    pts = _sweep()
    t = np.linspace(0.0, 0.1, len(pts))  # firing time (s)
    mean_pts, mean_t = voxel_means(pts, 0.5, t)
    keys = _voxels(pts, 0.5)
    _, inv = np.unique(keys, axis=0, return_inverse=True)
    inv = inv.ravel()
    assert len(mean_pts) == inv.max() + 1
    k = inv[1000]  # the voxel of one mid-sweep point
    assert np.allclose(mean_pts[k], pts[inv == k].mean(axis=0))
    assert np.isclose(mean_t[k], t[inv == k].mean())
    # On the arc the centroid sits just inside the circle (a chord's mean), by far less than 1 cm.
    assert np.all(np.abs(np.linalg.norm(mean_pts[:, :2], axis=1) - 8.0) < 0.01)
