"""Per-view segmentation pieces (Chaurasia and Beardsley 2017, section 4.1) against constructed cases."""

from __future__ import annotations

import numpy as np

from reference_impl.leaves.params import LeafParams
from reference_impl.leaves.refine import points_near, processing_order, refine_candidates, template_points
from reference_impl.leaves.segment import Candidate, backproject, fit_planes, segment_view, superpixel_graph

from .conftest import ring_cameras


def test_backproject_inverts_projection(rng):
    cam = ring_cameras(1, radius=1.0, height=0.5, size=64)[0]
    depth = np.where(rng.random((64, 64)) < 0.3, np.inf, rng.uniform(0.5, 2.0, (64, 64)))
    pts, flat = backproject(depth, cam)
    uv, z = cam.project(pts)
    v, u = np.divmod(flat, 64)
    np.testing.assert_allclose(uv, np.c_[u, v], atol=1e-9)
    np.testing.assert_allclose(z, depth.ravel()[flat], rtol=1e-12)


def test_ransac_planes_and_invalid_segments(rng):
    params = LeafParams()
    delta = 0.02
    normals = [np.array([0.0, 0.0, 1.0]), np.array([1.0, 1.0, 0.0]) / np.sqrt(2)]
    pts, seg = [], []
    for s, n in enumerate(normals):
        basis = np.linalg.svd(n[None])[2][1:]
        p = rng.uniform(-0.05, 0.05, (80, 2)) @ basis + rng.normal(0, 0.001, (80, 1)) * n + s
        p[:5] += 0.2 * n  # off-plane outliers
        pts.append(p)
        seg.append(np.full(80, s))
    pts.append(rng.uniform(-0.2, 0.2, (80, 3)) + 5)  # a blob: no plane explains 60 % of it
    seg.append(np.full(80, 2))
    pts.append(rng.uniform(0, 0.01, (3, 3)) + 9)  # too few points
    seg.append(np.full(3, 3))
    keep, _, normal, valid = fit_planes(np.concatenate(pts), np.concatenate(seg), 4, delta=delta, params=params,
                                        rng=rng)
    assert valid.tolist() == [True, True, False, False]
    for s, n in enumerate(normals):
        assert abs(normal[s] @ n) > 0.999
        k = keep[s * 80: (s + 1) * 80]
        assert not k[:5].any() and k[5:].mean() > 0.95


def test_affinity_of_touching_offset_and_folded_patches():
    delta, sigma = 0.02, 0.2
    h, w = 4, 8
    labels = np.repeat(np.repeat(np.arange(4).reshape(1, 4), 2, axis=1), h, axis=0)  # four 4x2 vertical strips
    xs, ys = np.meshgrid(np.arange(w) * 0.003, np.arange(h) * 0.003)
    z = np.zeros((h, w))
    z[:, 4:6] += 2 * delta  # strip 2 is a parallel surface 2 delta above strips 0 and 1
    pts = np.stack([xs, ys, z], -1)
    centroid = np.array([pts[labels == k].mean(0) for k in range(4)])
    normal = np.array([[0, 0, 1.0], [0, 0, 1.0], [0, 0, 1.0], [0, 0, 1.0]])
    normal[3] = [0, np.sin(1.0), np.cos(1.0)]  # strip 3 folded by 1 rad, sharing strip 2's plane at the boundary
    centroid[3] = centroid[2]
    edges, aff = superpixel_graph(labels, pts, centroid, normal, delta=delta, sigma=sigma)
    got = {tuple(e): a for e, a in zip(edges.tolist(), aff, strict=True)}
    assert set(got) == {(0, 1), (1, 2), (2, 3)}
    np.testing.assert_allclose(got[(0, 1)], 1.0)  # coplanar neighbours: Eq. 8 gives exp(0)
    np.testing.assert_allclose(got[(1, 2)], np.exp(-(2.0**2) / (2 * sigma**2)), rtol=1e-9)  # d_p = 2
    dn = 1 - np.cos(1.0)
    assert got[(2, 3)] <= np.exp(-(dn**2) / (2 * sigma**2)) + 1e-12 and got[(2, 3)] < 0.85


def test_segment_view_separates_leaves(leaf_scene):
    from .conftest import ring_cameras as _rc

    views, depths, idmaps, _ = leaf_scene
    from PIL import Image

    cam = _rc(6, radius=0.55, height=0.45, size=160)[0]
    img = np.asarray(Image.open(views / "images" / "0000.png"))
    params = LeafParams()
    seg = segment_view(img, depths[0], cam, delta=0.02, leaf_length=0.1, params=params, rng=np.random.default_rng(0))
    truth = idmaps[0].ravel()[seg.pixel]
    assert (truth >= 0).all()  # only pixels with depth became points
    cand = seg.candidate
    big = [k for k in np.unique(cand[cand >= 0]) if (cand == k).sum() >= 20]
    for k in big:  # every sizeable candidate lies on one leaf
        vals, counts = np.unique(truth[cand == k], return_counts=True)
        assert counts.max() / counts.sum() > 0.95
    # every leaf with 100 visible pixels has a candidate covering most of it
    for leaf in range(6):
        n = (idmaps[0] == leaf).sum()
        if n >= 100:
            best = max(((cand == k) & (truth == leaf)).sum() for k in big)
            assert best > 0.6 * n


def test_processing_order_and_template():
    conf = np.array([0.965, 0.99, 0.5, 0.97, 0.1])
    size = np.array([1.0, 2.0, 9.0, 3.0, 5.0])
    # 0.965, 0.97 and 0.99 share the top bin of 25: larger first; then 0.5, then 0.1
    assert processing_order(conf, size, 25).tolist() == [3, 1, 0, 2, 4]
    t = template_points(2.0, 0.01)
    assert np.all((t[:, 0] / 0.5) ** 2 + (t[:, 1] / 0.25) ** 2 <= 1 + 1e-9)
    np.testing.assert_allclose(len(t) * 0.01**2, np.pi * 0.5 * 0.25, rtol=0.05)


def test_points_near_is_the_union_of_balls(rng):
    from scipy.spatial import cKDTree

    pts = rng.uniform(-1, 1, (3000, 3))
    placed = rng.uniform(-0.3, 0.3, (50, 3)) + [0.2, 0.0, -0.1]
    brute = np.flatnonzero((np.linalg.norm(pts[:, None] - placed[None], axis=2) <= 0.07).any(axis=1))
    assert points_near(cKDTree(pts), pts, placed, 0.07).tolist() == brute.tolist()
    assert points_near(cKDTree(pts), pts, placed[:0], 0.07).size == 0


def _ellipse_leaf(rng, n, centre, angle):
    """n points filling a 0.10 x 0.05 m elliptical leaf in a tilted plane, its major axis at ``angle``."""
    u = rng.uniform(-1, 1, (4 * n, 2))
    u = u[(u**2).sum(1) <= 1][:n] * [0.05, 0.025]
    c, s = np.cos(angle), np.sin(angle)
    frame = np.array([[c, s, 0.2], [-s, c, 0.1], [0.0, 0.0, 1.0]])
    frame, _ = np.linalg.qr(frame.T)
    return centre + u[:, :1] * frame[:, 0] + u[:, 1:] * frame[:, 1], frame.T


def test_refine_registers_the_template_to_a_few_points(rng):
    """A candidate of 30 points of a leaf (as on an mvs cloud) whose plane is tilted 20 degrees and 5 mm off: the
    template, registered to those points, claims the leaf's scene points seen from all views (400), which the
    template placed on the candidate's own frame does not, and none of a neighbouring leaf's."""
    from scipy.spatial import cKDTree

    leaf, frame = _ellipse_leaf(rng, 400, np.zeros(3), 0.3)
    other, _ = _ellipse_leaf(rng, 400, np.array([0.0, 0.0, 0.08]), 1.2)
    pts = np.vstack([leaf, other])
    tilt = np.radians(20)
    off = np.array([[1, 0, 0], [0, np.cos(tilt), np.sin(tilt)], [0, -np.sin(tilt), np.cos(tilt)]]) @ frame
    cand = Candidate(view=0, index=rng.choice(400, 30, replace=False), area=1e-3, centre=0.005 * frame[2], frame=off,
                     semi_axes=(0.05, 0.025), confidence=0.9)
    params = LeafParams()
    leaves, skipped, _ = refine_candidates(pts, [cand], delta=0.004, params=params, leaf_length=0.1)
    assert len(leaves) == 1 and skipped == {"duplicate": 0, "few_points_after_icp": 0}
    assert np.isin(np.arange(400), leaves[0]).mean() >= 0.95 and not np.isin(np.arange(400, 800), leaves[0]).any()
    unregistered = template_points(2.0, 0.01) * 0.1 @ off + cand.centre
    near = points_near(cKDTree(pts), pts, unregistered, params.capture_distance * 0.004)
    assert np.isin(np.arange(400), near).mean() < 0.8
