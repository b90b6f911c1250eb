"""The livny and xu baselines on a 300k-point cloud (a synthetic 3 m tree sampled on its tubes, plus ground), beside
a bare scipy cKDTree 10-NN query on the same points (the graph build every point method starts with) for scale.
Target (issue 7): <= 60 s per plant at 300k points."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from reference_impl.livny import reconstruct_livny
from reference_impl.xu import reconstruct_xu
from tests.baselines.synthetic import random_tree, sample_surface


@pytest.fixture(scope="module")
def cloud():
    rng = np.random.Generator(np.random.PCG64(0))
    gt = random_tree(rng, height=3.0, levels=3, segment=0.05)
    return sample_surface(rng, gt, 290_000, noise=0.002, one_sided=True, ground=10_000, ground_radius=2.0)


@pytest.mark.benchmark(group="baselines-300k")
def test_bare_ckdtree_knn(benchmark, cloud):
    def knn():
        return cKDTree(cloud).query(cloud, k=11, workers=-1)

    benchmark.pedantic(knn, rounds=2, iterations=1)


@pytest.mark.benchmark(group="baselines-300k")
def test_livny_300k(benchmark, cloud):
    res = benchmark.pedantic(lambda: reconstruct_livny(cloud, np.random.Generator(np.random.PCG64(1))),
                             rounds=1, iterations=1)
    assert len(res.skeleton.roots) == 1


@pytest.mark.benchmark(group="baselines-300k")
def test_xu_300k(benchmark, cloud):
    res = benchmark.pedantic(lambda: reconstruct_xu(cloud, np.random.Generator(np.random.PCG64(1))),
                             rounds=1, iterations=1)
    assert len(res.skeleton.roots) == 1
