"""Metric speed beside the raw library doing the same work:

* mesh-to-scan D for 1M reconstructed vertices against 1M scan points, beside a bare
  ``cKDTree(scan).query(vertices, workers=-1)`` on the same arrays (target: <= 1.5x);
* Stava S_T of two ~2k-branch trees, with split/merge (target: <= 10 s) and without;
* leaf detection of 3000 predicted against 3000 ground-truth leaf centroids (a dense crown), beside scipy's
  dense Hungarian assignment (``linear_sum_assignment``) that gives the same match count.
"""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from plantbench.metrics.leaves import leaf_detection
from plantbench.metrics.stava import stava_similarity
from plantbench.metrics.surface import mesh_to_scan
from plantbench.plant import TriMesh
from tests.metrics.synth import random_tree


@pytest.fixture(scope="module")
def clouds():
    rng = np.random.Generator(np.random.PCG64(0))
    n = 1_000_000
    scan = rng.random((n, 3))
    verts = rng.random((n, 3))
    return scan, TriMesh(verts, np.zeros((0, 3), np.int64))


@pytest.mark.benchmark(group="mesh-to-scan-1M")
def test_bare_ckdtree_query(benchmark, clouds):
    scan, mesh = clouds

    def bare():
        d, _ = cKDTree(scan).query(mesh.vertices, workers=-1)
        return d.mean(), d.std()

    benchmark.pedantic(bare, rounds=3, iterations=1)


@pytest.mark.benchmark(group="mesh-to-scan-1M")
def test_plantbench_mesh_to_scan(benchmark, clouds):
    scan, mesh = clouds
    rng = np.random.Generator(np.random.PCG64(1))
    res = benchmark.pedantic(mesh_to_scan, args=(scan, mesh), kwargs={"rng": rng, "reverse": False},
                             rounds=3, iterations=1)
    assert res.D_cm > 0


@pytest.fixture(scope="module")
def trees():
    rng = np.random.Generator(np.random.PCG64(1))
    return random_tree(rng, 1000, trunk_segments=60), random_tree(rng, 1000, trunk_segments=60)


@pytest.mark.benchmark(group="stava-2k-branches")
def test_stava_split_merge(benchmark, trees):
    r = benchmark.pedantic(stava_similarity, args=trees, rounds=1, iterations=1)
    assert 0 < r.S_T < 1


@pytest.mark.benchmark(group="stava-2k-branches")
def test_stava_nosplit(benchmark, trees):
    r = benchmark.pedantic(stava_similarity, args=trees, kwargs={"split_merge": False}, rounds=1, iterations=1)
    assert 0 < r.S_T < 1


@pytest.fixture(scope="module")
def leaf_centroids():
    rng = np.random.Generator(np.random.PCG64(2))
    gt = rng.random((3000, 3)) * [1.0, 1.0, 1.5]
    pred = np.concatenate([gt[:2400] + rng.normal(0, 0.02, (2400, 3)), rng.random((600, 3)) * [1.0, 1.0, 1.5]])
    return gt, pred, 0.04


@pytest.mark.benchmark(group="leaf-detection-3k")
def test_bare_dense_hungarian(benchmark, leaf_centroids):
    from scipy.optimize import linear_sum_assignment
    from scipy.spatial.distance import cdist

    gt, pred, radius = leaf_centroids

    def bare():
        d = cdist(gt, pred)
        r, c = linear_sum_assignment(np.where(d <= radius, d, 1e6 + d))
        return int(np.count_nonzero(d[r, c] <= radius))

    leaf_centroids_matched["dense"] = benchmark.pedantic(bare, rounds=1, iterations=1)


@pytest.mark.benchmark(group="leaf-detection-3k")
def test_plantbench_leaf_detection(benchmark, leaf_centroids):
    gt, pred, radius = leaf_centroids
    res = benchmark.pedantic(leaf_detection, args=(gt, pred), kwargs={"radius": radius}, rounds=3, iterations=1)
    if "dense" in leaf_centroids_matched:
        assert res["matched"] == leaf_centroids_matched["dense"]


leaf_centroids_matched: dict[str, int] = {}
