"""The shortcuts that make one cell's metrics fast give the values of the plain computation exactly: bounded and
selected nearest-neighbour searches, distances settled through anchors for threshold tests, skeleton samples and
ray-casting scenes shared between metric families."""

from __future__ import annotations

import numpy as np
import pytest

from plantbench.cameras import look_at
from plantbench.metrics.reprojection import render_silhouettes
from plantbench.metrics.skeleton import (
    sample_skeleton,
    sample_weights,
    skeleton_prf,
    skeleton_samples,
    skeleton_support,
)
from plantbench.metrics.surface import (
    kdtree,
    mesh_to_scan,
    nearest_distances,
    point_to_mesh_distances,
    raycasting_scene,
    sample_surface,
    threshold_distances,
)
from plantbench.plant import Skeleton

from .synth import cylinder, random_tree


def test_bounded_and_selected_searches_match_the_full_one(rng):
    """Within the bound: the same distance and the same index, ties included (every reference point twice);
    beyond it or unselected: (inf, m)."""
    ref = np.repeat(rng.random((300, 3)), 2, axis=0)
    query = rng.random((25_000, 3)) * 1.4 - 0.2
    d, i = nearest_distances(ref, query)
    within = float(np.median(d))
    db, ib = nearest_distances(ref, query, within=within)
    near = d <= within
    np.testing.assert_array_equal(db[near], d[near])
    np.testing.assert_array_equal(ib[near], i[near])
    assert np.isinf(db[~near]).all() and (ib[~near] == len(ref)).all()
    select = rng.random(len(query)) < 0.3
    ds, is_ = nearest_distances(ref, query, tree=kdtree(ref), query_tree=kdtree(query), select=select)
    np.testing.assert_array_equal(ds[select], d[select])
    np.testing.assert_array_equal(is_[select], i[select])
    assert np.isinf(ds[~select]).all() and (is_[~select] == len(ref)).all()


@pytest.mark.parametrize("every", [1, 3, 8])
def test_threshold_distances_compare_like_the_exact_ones(rng, every):
    """Queries along polylines (skeleton samples); thresholds shared or per query, some equal to exact distances:
    d < t and d <= t as with the exact distance, for every threshold."""
    query, radii = sample_skeleton(random_tree(rng, 8, seg_len=0.04), 0.002)
    ref = sample_skeleton(random_tree(rng, 8, seg_len=0.04), 0.002)[0] + 0.01
    exact, _ = nearest_distances(ref, query)
    shared = np.concatenate([[0.004, 0.02], rng.choice(exact, 3)])
    per_query = np.concatenate([np.multiply.outer(radii, [0.5, 1.0, 2.0]), np.broadcast_to(shared, (len(query), 5))],
                               axis=1)
    for th in (shared, per_query):
        d = threshold_distances(ref, query, th, every=every)
        t = th if th.ndim == 2 else th[None, :]
        np.testing.assert_array_equal(d[:, None] < t, exact[:, None] < t)
        np.testing.assert_array_equal(d[:, None] <= t, exact[:, None] <= t)
    assert np.isinf(threshold_distances(ref, query, [])).all()
    assert len(threshold_distances(ref, np.zeros((0, 3)), shared)) == 0


def _prf_full_search(gt: Skeleton, pred: Skeleton, step: float, height: float | None) -> dict[str, float]:
    """skeleton_prf as plain unbounded nearest-neighbour searches both ways."""
    from plantbench.metrics.points import tau_label

    g, rg = sample_skeleton(gt, step)
    p, _ = sample_skeleton(pred, step)
    d_p, nearest = kdtree(g).query(p)
    d_g, _ = kdtree(p).query(g)
    out = {}
    for t in (0.5, 1.0, 2.0):
        prec, rec = float(np.mean(d_p < t * rg[nearest])), float(np.mean(d_g < t * rg))
        out |= {f"precision@{t:.1f}": prec, f"recall@{t:.1f}": rec,
                f"f1@{t:.1f}": 2 * prec * rec / (prec + rec) if prec + rec > 0 else 0.0}
    if height is not None:
        for kind, volume in (("v", True), ("l", False)):
            wg, wp = sample_weights(gt, step, volume=volume), sample_weights(pred, step, volume=volume)
            for f in (0.005, 0.01, 0.02):
                tau = f * height
                prec = float(wp[d_p < tau].sum()) / float(wp.sum())
                rec = float(wg[d_g < tau].sum()) / float(wg.sum())
                out |= {f"{kind}precision@{tau_label(f)}": prec, f"{kind}recall@{tau_label(f)}": rec,
                        f"{kind}f1@{tau_label(f)}": 2 * prec * rec / (prec + rec) if prec + rec > 0 else 0.0}
    return out


@pytest.mark.parametrize("height", [None, 1.0, 3.0])
def test_skeleton_prf_matches_the_full_search(rng, height):
    """A thick trunk (2 r beyond the largest height tolerance) and predicted branches near it, farther than that
    tolerance, and far away: every path of the bounded searches, the same values to the last bit."""
    gt = random_tree(rng, 10, seg_len=0.05, trunk_segments=10)
    gt = Skeleton(gt.positions, np.where(np.arange(len(gt)) < 11, 0.06, gt.radii), gt.parents)
    near = random_tree(rng, 10, seg_len=0.05, trunk_segments=10)
    pred = Skeleton(np.concatenate([near.positions + [0.05, 0.0, 0.0], near.positions + [2.0, 0.0, 0.0]]),
                    np.concatenate([near.radii, near.radii]),
                    np.concatenate([near.parents, np.where(near.parents >= 0, near.parents + len(near), -1)]))
    assert skeleton_prf(gt, pred, step=0.004, height=height) == _prf_full_search(gt, pred, 0.004, height)


@pytest.mark.parametrize("height", [5.0, 10.0, 20.0])
@pytest.mark.parametrize("every", [4, 16])
def test_skeleton_prf_settled_from_anchors_matches_the_full_search(rng, monkeypatch, height, every):
    """The anchors' path of skeleton_prf's precision (on from _SETTLE_MIN samples, forced here): a thick trunk, a
    prediction near it and one far away, and a third along the trunk's axis inside it (radius tests that pass
    without a height test), settled and searched samples and far anchors alike, the same values to the last bit."""
    import plantbench.metrics.skeleton as sk

    gt = random_tree(rng, 10, seg_len=0.05, trunk_segments=10)
    gt = Skeleton(gt.positions, np.where(np.arange(len(gt)) < 11, 0.06, gt.radii), gt.parents)
    near = random_tree(rng, 10, seg_len=0.05, trunk_segments=10)
    parts = [near.positions + [0.05, 0.0, 0.0], near.positions + [2.0, 0.0, 0.0], gt.positions[:11] + [0.03, 0, 0]]
    offsets = np.cumsum([0, len(near), len(near)])
    parents = [near.parents, near.parents, np.arange(-1, 10)]
    pred = Skeleton(np.concatenate(parts), np.concatenate([near.radii, near.radii, np.full(11, 0.01)]),
                    np.concatenate([np.where(q >= 0, q + o, -1) for q, o in zip(parents, offsets)]))
    expected = _prf_full_search(gt, pred, 0.002, height)
    monkeypatch.setattr(sk, "_SETTLE_MIN", 1)
    monkeypatch.setattr(sk, "_SETTLE_EVERY", every)
    settled = sk._settle(sk.skeleton_samples(gt, 0.002), sk.skeleton_samples(pred, 0.002),
                         np.array([f * height for f in sk.HEIGHT_FRACTIONS]), 2.0)[0]
    assert 0 < settled.sum() < len(settled)  # both paths taken
    assert skeleton_prf(gt, pred, step=0.002, height=height) == expected


def test_shared_skeleton_samples_give_the_same_values(rng):
    gt, pred = random_tree(rng, 6), random_tree(rng, 5)
    g, p = skeleton_samples(gt, 0.003), skeleton_samples(pred, 0.003)
    np.testing.assert_array_equal(g.points, sample_skeleton(gt, 0.003)[0])
    np.testing.assert_array_equal(g.radii, sample_skeleton(gt, 0.003)[1])
    np.testing.assert_array_equal(g.weights(), sample_weights(gt, 0.003))
    np.testing.assert_array_equal(g.weights(volume=False), sample_weights(gt, 0.003, volume=False))
    assert skeleton_prf(g, p, height=1.0) == skeleton_prf(gt, pred, step=0.003, height=1.0)
    obs = g.points[::7] + 0.002
    assert skeleton_support(p, obs, tolerances=(0.01, 0.05)) == skeleton_support(pred, obs, tolerances=(0.01, 0.05),
                                                                                  step=0.003)


def test_shared_mesh_sample_and_scene_give_the_same_values(rng):
    mesh = cylinder(n_around=24, n_up=12)
    scan = rng.random((3000, 3)) * [0.3, 0.3, 1.2] - [0.15, 0.15, 0.1]
    drawn = mesh_to_scan(scan, mesh, rng=np.random.default_rng(5), n_area_samples=4000)
    area = sample_surface(mesh, 4000, np.random.default_rng(5))[0]
    scene = raycasting_scene(mesh)
    assert mesh_to_scan(scan, mesh, rng=None, area_sample=area, scene=scene) == drawn
    np.testing.assert_array_equal(point_to_mesh_distances(mesh, scan, scene=scene), point_to_mesh_distances(mesh, scan))
    cam = look_at((2.0, 0.5, 0.6), (0.0, 0.0, 0.5), fov_x_deg=50, width=64, height=48)
    np.testing.assert_array_equal(render_silhouettes(mesh, [cam], scene=scene)[0], render_silhouettes(mesh, [cam])[0])
