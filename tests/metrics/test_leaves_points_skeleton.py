"""Leaf counts and detection, point-cloud metrics and skeleton metrics against hand or brute-force computations."""

from __future__ import annotations

import numpy as np
import pytest

from plantbench.errors import InputError
from plantbench.metrics.leaves import leaf_count_metrics, leaf_detection, leaf_matches, leaf_shape_errors
from plantbench.metrics.points import cloud_metrics
from plantbench.metrics.skeleton import crown_area, dbh, sample_skeleton, skeleton_attributes, skeleton_prf
from plantbench.plant import Leaf, Skeleton

from .synth import random_tree


def test_leaf_counts():
    assert leaf_count_metrics(10, 7) == {"count_gt": 10.0, "count_pred": 7.0, "dic": -3.0, "abs_dic": 3.0,
                                         "rel_error": 0.3, "accuracy": 0.7}
    assert leaf_count_metrics(10, 25)["accuracy"] == 0.0
    assert leaf_count_metrics(0, 0)["accuracy"] == 1.0 and leaf_count_metrics(0, 0)["rel_error"] is None
    assert leaf_count_metrics(0, 2)["accuracy"] == 0.0


def test_leaf_detection_hungarian():
    gt = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], float)
    # pred 0 is near gt 0 and 1 but must be matched to only one; pred 2 is too far from everything
    pred = np.array([[0.5, 0, 0], [1.1, 0, 0], [5, 5, 5]], float)
    r = leaf_detection(gt, pred, radius=0.6)
    assert r["matched"] == 2 and r["precision"] == pytest.approx(2 / 3) and r["recall"] == pytest.approx(2 / 3)
    assert leaf_detection(gt, np.zeros((0, 3)), radius=1)["f1"] == 0.0
    with pytest.raises(InputError):
        leaf_detection(gt, pred, radius=0)


@pytest.mark.parametrize("m,n,radius", [(60, 80, 0.08), (200, 150, 0.05), (300, 300, 0.12), (40, 40, 1e-9)])
def test_leaf_detection_matches_dense_hungarian(rng, m, n, radius):
    """The matching count equals the dense Hungarian assignment's, pairs beyond the radius penalised (the
    definition), on clustered centroids (many candidate pairs per leaf)."""
    from scipy.optimize import linear_sum_assignment

    centres = rng.random((max(m, n) // 4, 3))
    gt = centres[rng.integers(0, len(centres), m)] + rng.normal(0, 0.03, (m, 3))
    pred = centres[rng.integers(0, len(centres), n)] + rng.normal(0, 0.03, (n, 3))
    d = np.sqrt(((gt[:, None] - pred[None]) ** 2).sum(-1))
    r, c = linear_sum_assignment(np.where(d <= radius, d, 1e6 + d))
    expected = int(np.count_nonzero(d[r, c] <= radius))
    got = leaf_detection(gt, pred, radius=radius)
    assert got["matched"] == expected
    assert got["precision"] == pytest.approx(expected / n) and got["recall"] == pytest.approx(expected / m)
    same = leaf_detection(gt, gt, radius=radius)
    assert same["matched"] == m


def _flat_leaf(transform: np.ndarray, length: float = 0.2) -> Leaf:
    """A flat, straight default Bezier blade (every out-of-plane parameter 0)."""
    from plantbench.geometry.leaf import BezierLeaf

    return Leaf(0, -1, transform, BezierLeaf().__dict__.copy(), length, 0.3 * length)


def _rot_x(deg: float) -> np.ndarray:
    a = np.radians(deg)
    t = np.eye(4)
    t[1:3, 1:3] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    return t


def test_leaf_shape_errors_analytic_cases():
    """A flat blade against: itself (0, 0 deg); itself lifted 1 cm along its normal (symmetric mean distance 1 cm
    exactly, 0.05 of a 20 cm blade); itself flipped upside down (0 deg: normals are unsigned); itself rolled 30 deg
    about its midrib (30 deg; the shape error of the roll by hand: points at half-width w lie w sin 30 deg off the
    other blade's plane, within its outline)."""
    base = np.eye(4)
    base[:3, 3] = [1.0, 2.0, 0.5]
    lifted = base.copy()
    lifted[2, 3] += 0.01
    gt = [_flat_leaf(base)] * 4
    pred = [_flat_leaf(base), _flat_leaf(lifted), _flat_leaf(base @ _rot_x(180)), _flat_leaf(base @ _rot_x(30))]
    shape, angle = leaf_shape_errors(gt, pred, np.array([[0, 0], [1, 1], [2, 2], [3, 3]]))
    assert shape[0] == pytest.approx(0, abs=1e-6) and angle[0] == pytest.approx(0, abs=1e-4)
    assert shape[1] == pytest.approx(0.05, rel=1e-4) and angle[1] == pytest.approx(0, abs=1e-4)
    assert shape[2] == pytest.approx(0, abs=1e-6) and angle[2] == pytest.approx(0, abs=1e-4)
    assert angle[3] == pytest.approx(30, abs=1e-4)
    # rolled 30 deg: every point at signed width y is |y| sin 30 deg from the other plane, whose outline covers its
    # foot (cos 30 |y| < |y|); the blade's area-weighted mean |y| from a fine grid of the same outline
    from plantbench.geometry.leaf import BezierLeaf, leaf_points

    u, v = np.meshgrid(np.linspace(-1, 1, 401), np.linspace(0, 1, 801))
    pts = leaf_points(BezierLeaf().vector(), u.ravel(), v.ravel()).reshape(801, 401, 3)
    half = np.abs(pts[:, -1, 1])  # half-width along the blade (unit leaf)
    mean_abs_y = float(np.trapezoid(half**2 / 2, pts[:, 0, 0]) / np.trapezoid(half, pts[:, 0, 0]))
    assert shape[3] == pytest.approx(np.sin(np.radians(30)) * mean_abs_y, rel=0.03)


def test_leaf_shape_errors_of_quad_leaves():
    """The baselines' flat quad leaves (params model 'quad', no Bezier fields): a 20 x 6 cm rectangle against itself
    (0) and against itself lifted 1 cm (0.01 / 0.2 = 0.05); a quad against a Bezier blade of the same frame: its
    area-weighted distance is positive (the rectangle's corners stick out of the blade's outline)."""
    base = np.eye(4)
    lifted = base.copy()
    lifted[2, 3] = 0.01
    quad = Leaf(0, 3, base, {"model": "quad", "leaves": 2}, 0.2, 0.06)
    up = Leaf(1, 3, lifted, {"model": "quad", "leaves": 2}, 0.2, 0.06)
    shape, angle = leaf_shape_errors([quad, quad, _flat_leaf(base)], [quad, up, quad],
                                     np.array([[0, 0], [1, 1], [2, 2]]))
    assert shape[0] == pytest.approx(0, abs=1e-6) and shape[1] == pytest.approx(0.05, rel=1e-4)
    assert shape[2] > 0.005 and np.allclose(angle, 0, atol=1e-6)
    # a blade without width (a degenerate quad): its vertices' mean distance, the midline 0 from the rectangle
    line = Leaf(2, 3, lifted, {"model": "quad", "leaves": 1}, 0.2, 0.0)
    shape, _ = leaf_shape_errors([quad], [line], np.array([[0, 0]]))
    assert np.isfinite(shape[0]) and shape[0] > 0.01 / 0.2 / 2


def test_leaf_matches_pairs_are_within_radius_and_one_to_one(rng):
    gt = rng.random((50, 3))
    pred = gt[rng.permutation(50)[:35]] + rng.normal(0, 0.01, (35, 3))
    pairs = leaf_matches(gt, pred, radius=0.05)
    assert len(pairs) == leaf_detection(gt, pred, radius=0.05)["matched"]
    assert len(set(pairs[:, 0])) == len(pairs) == len(set(pairs[:, 1]))
    assert np.all(np.linalg.norm(gt[pairs[:, 0]] - pred[pairs[:, 1]], axis=1) <= 0.05)


def test_cloud_metrics_brute_force(rng):
    gt = rng.random((200, 3))
    lab = (gt[:, 2] > 0.5).astype(np.int64)
    pred = gt[:150] + rng.normal(0, 0.01, (150, 3))
    pred = np.concatenate([pred, rng.random((20, 3)) + 3])  # junk far away
    out = cloud_metrics(gt, lab, pred, height=1.0)
    d = np.sqrt(((pred[:, None] - gt[None]) ** 2).sum(-1))
    d_pred, nn = d.min(1), d.argmin(1)
    d_gt = d.min(0)
    assert out["all.accuracy_cm"] == pytest.approx(np.minimum(d_pred, 0.1).mean() * 100)
    assert out["all.completeness_cm"] == pytest.approx(np.minimum(d_gt, 0.1).mean() * 100)
    tau = 0.01
    p, r = np.mean(d_pred < tau), np.mean(d_gt < tau)
    assert out["all.precision@1%"] == pytest.approx(p) and out["all.recall@1%"] == pytest.approx(r)
    assert out["all.fscore@1%"] == pytest.approx(2 * p * r / (p + r))
    w = lab[nn] == 0
    assert out["wood.precision@2%"] == pytest.approx(np.mean(d_pred[w] < 0.02))
    assert out["foliage.recall@0.5%"] == pytest.approx(np.mean(d_gt[lab == 1] < 0.005))
    same = cloud_metrics(gt, lab, gt, height=1.0)
    assert same["all.fscore@0.5%"] == 1.0 and same["all.chamfer_cm"] == 0.0
    empty = cloud_metrics(gt, lab, np.zeros((0, 3)), height=1.0)
    assert empty["all.fscore@1%"] == 0.0 and empty["all.accuracy_cm"] is None
    assert empty["all.completeness_cm"] == pytest.approx(10.0)
    no_leaves = cloud_metrics(gt, np.zeros(200, np.int64), gt, height=1.0)
    assert no_leaves["foliage.fscore@1%"] is None and no_leaves["wood.fscore@1%"] == 1.0


def test_skeleton_prf_by_hand():
    # GT: a vertical 1 m stem of radius 0.01; prediction: the same stem shifted 0.008 m sideways, and only its lower
    # half. t = 0.5 -> 0.005 < 0.008: nothing matches; t = 1 -> 0.01 > 0.008: the lower half matches.
    gt = Skeleton(np.array([[0, 0, 0], [0, 0, 1.0]]), np.array([0.01, 0.01]), np.array([-1, 0]))
    pred = Skeleton(np.array([[0.008, 0, 0], [0.008, 0, 0.5]]), np.array([0.01, 0.01]), np.array([-1, 0]))
    out = skeleton_prf(gt, pred, step=0.01)
    assert out["precision@0.5"] == 0.0 and out["recall@0.5"] == 0.0 and out["f1@0.5"] == 0.0
    assert out["precision@1.0"] == 1.0
    assert out["recall@1.0"] == pytest.approx(0.5, abs=0.02)
    single = Skeleton(np.zeros((1, 3)), np.ones(1) * 0.01, np.array([-1]))
    # GT samples: z = 0, 0.001, ..., 0.999 plus both nodes (1002); within 2 r = 0.02 of the origin: z < 0.02 -> 20 + 1
    assert skeleton_prf(gt, single)["recall@2.0"] == pytest.approx(21 / 1002)
    empty = Skeleton(np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64))
    assert skeleton_prf(gt, empty)["f1@1.0"] == 0.0
    with pytest.raises(InputError):
        skeleton_prf(empty, gt)


def test_sample_spacing_and_attributes(rng):
    t = random_tree(rng, 8)
    pts, rad = sample_skeleton(t, 0.002)
    from scipy.spatial import cKDTree

    # every point of every edge is within half a step of a sample
    e = t.edges
    f = rng.random(len(e))[:, None]
    q = t.positions[e[:, 0]] * (1 - f) + t.positions[e[:, 1]] * f
    assert cKDTree(pts).query(q)[0].max() <= 0.001 + 1e-12
    a = skeleton_attributes(t)
    assert a["total_length_m"] == pytest.approx(np.linalg.norm(np.diff(t.positions[e], axis=1)[:, 0], axis=1).sum())
    # DBH: a 3 m trunk with radius falling linearly 0.1 -> 0.05 over z: at 1.3 m, 2 * (0.1 - 0.05 * 1.3 / 3)
    s = Skeleton(np.array([[0, 0, 0], [0, 0, 1.0], [0, 0, 3.0]]), np.array([0.1, 0.1 - 0.05 / 3, 0.05]),
                 np.array([-1, 0, 1]))
    assert dbh(s) == pytest.approx(2 * (0.1 - 0.05 * 1.3 / 3))
    assert dbh(s, breast_height=5.0) is None


def test_crown_area_is_the_convex_hull_of_the_nodes_on_the_ground():
    # a 2 m square of tips at several heights around a stem: area 4, whatever the heights and interior nodes
    pos = np.array([[0.0, 0, 0], [0, 0, 1.5], [1, 1, 2.0], [-1, 1, 2.5], [-1, -1, 1.8], [1, -1, 2.2], [0.3, 0.2, 2]])
    s = Skeleton(pos, np.full(7, 0.01), np.array([-1, 0, 1, 1, 1, 1, 1]))
    assert crown_area(s) == pytest.approx(4.0)
    side = 0.7
    sq = Skeleton(np.array([[0, 0, 0], [side, 0, 1], [side, side, 1], [0, side, 1.0]]), np.full(4, 0.01),
                  np.array([-1, 0, 1, 2]))
    assert crown_area(sq) == pytest.approx(side**2)
    # degenerate: fewer than 3 distinct projections, or collinear ones (a vertical stem, a planar fan)
    stem = Skeleton(np.array([[0, 0, 0], [0, 0, 1.0], [0, 0, 2.0]]), np.full(3, 0.01), np.array([-1, 0, 1]))
    fan = Skeleton(np.array([[0, 0, 0], [1, 0, 1.0], [2, 0, 2.0], [-1, 0, 1]]), np.full(4, 0.01),
                   np.array([-1, 0, 1, 0]))
    assert crown_area(stem) is None and crown_area(fan) is None
    assert crown_area(Skeleton(np.zeros((0, 3)), np.zeros(0), np.zeros(0, int))) is None


def test_leaf_shape_errors_in_one_scene_equal_the_pair_by_pair_distances(rng):
    """The batched shape errors (every pair in its own cell of one Open3D scene) against the reference one pair at
    a time (a scene per blade): 300 leaves over a 4 m crown, curled, rolled and of several lengths, each matched with
    a perturbed copy, a quad, or a leaf a metre away (the largest pair sets the grid), plus a degenerate quad."""
    from scipy.spatial.transform import Rotation

    from plantbench.geometry.leaf import BezierLeaf
    from plantbench.metrics.leaves import _blade, _mean_distance

    def leaf(i, pos, rot, length, curl):
        t = np.eye(4)
        t[:3, :3], t[:3, 3] = rot, pos
        params = BezierLeaf().__dict__.copy()
        params.update(axis1_z=0.1 * curl, axis2_z=0.25 * curl, f_z2=0.05 * curl, g_z2=-0.04 * curl)
        return Leaf(i, -1, t, params, length, 0.3 * length)

    n = 300
    pos = rng.uniform([-2, -2, 0], [2, 2, 4], (n, 3))
    rots = Rotation.random(2 * n, random_state=1).as_matrix()
    gt = [leaf(i, pos[i], rots[i], rng.uniform(0.05, 0.3), rng.uniform(0, 1)) for i in range(n)]
    pred = []
    for i in range(n):
        kind = i % 3
        if kind == 0:
            pred.append(leaf(i, pos[i] + rng.normal(0, 0.01, 3), rots[n + i] if i % 2 else rots[i],
                             gt[i].length * rng.uniform(0.8, 1.2), rng.uniform(0, 1)))
        elif kind == 1:
            t = np.array(gt[i].transform, float)
            pred.append(Leaf(i, 3, t, {"model": "quad", "leaves": 2}, gt[i].length, 0.3 * gt[i].length))
        else:
            pred.append(leaf(i, pos[i] + rng.normal(0, 0.5, 3), rots[n + i], 0.2, 0.5))
    pred[5] = Leaf(5, 3, np.array(gt[5].transform, float), {"model": "quad", "leaves": 1}, 0.2, 0.0)
    pairs = np.stack([np.arange(n), np.arange(n)], 1)
    shape, angle = leaf_shape_errors(gt, pred, pairs)
    ref = np.array([0.5 * (_mean_distance(_blade(g), _blade(p)) + _mean_distance(_blade(p), _blade(g))) / g.length
                    for g, p in zip(gt, pred, strict=True)])
    assert np.allclose(shape, ref, rtol=1e-4, atol=1e-6), np.abs(shape - ref).max()
    normals = [np.asarray(x.transform)[:3, 2] for x in (*gt, *pred)]
    cos = np.abs([normals[i] @ normals[n + i] for i in range(n)])
    assert np.allclose(angle, np.degrees(np.arccos(np.minimum(cos, 1.0))), atol=1e-5)
    assert leaf_shape_errors(gt, pred, np.zeros((0, 2)))[0].shape == (0,)
