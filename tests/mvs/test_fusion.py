"""Fusion: back-projection and voxel de-duplication."""

from __future__ import annotations

import numpy as np
import pytest

from plantbench.cameras import look_at
from plantbench.errors import InputError
from reference_impl.mvs.fusion import backproject, fuse_views, voxel_downsample


def test_backproject_reprojects_to_its_pixels(rng):
    cam = look_at((2, 1, 1.5), (0, 0, 0.3), fov_x_deg=50, width=40, height=30)
    depth = (2 + rng.random((30, 40))).astype(np.float32)
    depth[5, 7] = np.nan
    pts, idx = backproject(depth, cam)
    uv, z = cam.project(pts)
    v, u = np.divmod(idx, 40)
    assert len(pts) == 30 * 40 - 1
    assert np.allclose(uv, np.stack([u, v], 1), atol=1e-6) and np.allclose(z, depth.ravel()[idx], rtol=1e-6)


def test_voxel_mean_matches_naive(rng):
    pts = rng.random((500, 3))
    col = rng.integers(0, 256, (500, 3)).astype(np.uint8)
    out, _, oc, size = voxel_downsample(pts, 10, colours=col, voxel=0.25)
    assert size == 0.25
    keys = np.floor((pts - pts.min(0)) / 0.25).astype(int)
    groups = {}
    for k, p, c in zip(map(tuple, keys), pts, col):
        groups.setdefault(k, []).append((p, c))
    want = sorted(tuple(np.round(np.mean([p for p, _ in g], 0), 9)) for g in groups.values())
    assert sorted(tuple(np.round(p, 9)) for p in out) == want
    assert oc.dtype == np.uint8 and len(oc) == len(groups)


def test_duplicates_from_two_views_merge():
    """Two views of the same plane produce two copies of every surface point; fusion leaves one per voxel."""
    cams = [look_at((np.cos(a) * 3, np.sin(a) * 3, 2), (0, 0, 0), fov_x_deg=40, width=60, height=60)
            for a in (0.0, 0.3)]
    depths, normals, images = [], [], []
    for c in cams:
        o, d = c.pixel_rays()
        t = -o[2] / d[:, 2]
        depths.append((t * (d @ c.R[2])).reshape(60, 60).astype(np.float32))
        normals.append(np.broadcast_to(np.array([0, 0, 1.0], np.float32), (60, 60, 3)).copy())
        images.append(np.full((60, 60, 3), 100, np.uint8))
    pts, nrm, col, view = fuse_views(depths, normals, images, cams, [np.ones((60, 60), bool)] * 2)
    assert len(pts) == 7200 and np.allclose(pts[:, 2], 0, atol=1e-6) and set(view) == {0, 1}
    out, on, oc, size = voxel_downsample(pts, 2000, normals=nrm, colours=col)
    assert len(out) <= 2000 and size > 0
    # no two output points share a voxel: nearest neighbours are at least ~ a voxel apart on average
    from scipy.spatial import cKDTree

    d, _ = cKDTree(out).query(out, k=2)
    assert np.median(d[:, 1]) > 0.5 * size
    assert np.allclose(out[:, 2], 0, atol=1e-6) and np.allclose(on, [0, 0, 1]) and np.all(oc == 100)


def test_voxel_target_is_respected_and_small_input_untouched(rng):
    pts = rng.random((3000, 3))
    out, _, _, size = voxel_downsample(pts, 1000)
    assert 500 < len(out) <= 1000
    # the search stops within 1 % of the smallest voxel that meets the target (numpy's voxels, counted by np.unique)
    distinct = [len(np.unique(np.floor((pts - pts.min(0)) / s).astype(int), axis=0)) for s in (size, size / 1.011)]
    assert distinct[0] == len(out) and distinct[1] > 1000
    same, _, _, size0 = voxel_downsample(pts, 5000)
    assert size0 == 0 and same is not None and len(same) == 3000
    with pytest.raises(InputError):
        voxel_downsample(pts, 0)
