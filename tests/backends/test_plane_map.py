from __future__ import annotations

import numpy as np
import torch

from l2calib_backends.plane_map import VoxelPlaneMap


def test_planes_fit_and_groups_are_separate():
    rng = np.random.default_rng(0)
    xy = rng.uniform(-5, 5, (20000, 2))
    z = 0.2 * xy[:, 0] - 0.1 * xy[:, 1] + 1.0
    pts = torch.from_numpy(np.column_stack([xy, z]))
    m = VoxelPlaneMap(0.5)
    m.insert(pts, torch.zeros(len(pts), dtype=torch.int64))
    m.insert(pts + torch.tensor([0.0, 0.0, 3.0]), torch.ones(len(pts), dtype=torch.int64))
    q = pts[:500].clone()
    q[:, 2] += 0.02
    for group, shift in ((0, 0.0), (1, 3.0)):
        n, d, ok = m.query(q + torch.tensor([0.0, 0.0, shift]), torch.tensor([group]))
        res = (n * (q + torch.tensor([0.0, 0.0, shift]))).sum(-1) + d
        assert ok.float().mean() > 0.9
        expected = 0.02 / np.sqrt(1 + 0.2**2 + 0.1**2)
        np.testing.assert_allclose(res[ok].abs().numpy(), expected, atol=2e-3)
    assert m.counts_per_group(2).min() > 100


def test_neighbour_search_widens_the_basin():
    rng = np.random.default_rng(1)
    xy = rng.uniform(-5, 5, (20000, 2))
    pts = torch.from_numpy(np.column_stack([xy, np.full(len(xy), 0.25)]))
    m = VoxelPlaneMap(0.5)
    m.insert(pts, torch.zeros(len(pts), dtype=torch.int64))
    q = torch.from_numpy(np.column_stack([rng.uniform(-4, 4, (300, 2)), np.full(300, 0.7)]))
    _, _, ok_plain = m.query(q, torch.tensor([0]))
    n, d, ok_wide = m.query(q, torch.tensor([0]), neighbours=True)
    assert not ok_plain.any() and ok_wide.all()
    np.testing.assert_allclose(((n * q).sum(-1) + d).abs().numpy(), 0.45, atol=1e-9)


def test_frozen_map_dense_grid_answers_as_the_binary_search(monkeypatch):
    """The dense index of a small frozen map and the sorted-key search give the same planes,
    also for queries outside the map's bounding box and next to it (neighbour search)."""
    from l2calib_backends import plane_map

    rng = np.random.default_rng(2)
    xy = rng.uniform(-6, 6, (30000, 2))
    walls = np.column_stack([np.full(3000, 4.0), rng.uniform(-6, 6, (3000, 2))])
    pts = torch.from_numpy(np.vstack([np.column_stack([xy, 0.1 * xy[:, 0]]), walls]))
    source = VoxelPlaneMap(0.5)
    source.insert(pts, torch.zeros(len(pts), dtype=torch.int64))
    dense = plane_map.FrozenPlaneMap(source)
    monkeypatch.setattr(plane_map, "MAX_DENSE_CELLS", 0)
    search = plane_map.FrozenPlaneMap(source)
    assert dense._grid is not None and search._grid is None
    q = torch.from_numpy(rng.uniform(-9, 9, (4000, 3)))  # many outside the box
    for neighbours in (False, True):
        a, b = dense.query(q, neighbours=neighbours), search.query(q, neighbours=neighbours)
        assert torch.equal(a[2], b[2]) and bool(a[2].any()) and not bool(a[2].all())
        assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1])
