"""guo speed on 300k points (the size of the clouds of Guo et al. 2018, Table 2): a full-size Maple's branch and leaf
surfaces sampled area-uniformly, through reconstruct_guo (ground, Eq. 8 weights, roots, markers, growth, leaves,
refinement, meshing), beside a bare scipy cKDTree build + 48-nearest-neighbour query of the same points (the query the
Eq. 8 weights need) for scale. Target: <= 60 s per plant (analysis-by-synthesis excluded)."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from plantbench.generate.case import grow_species
from plantbench.metrics.surface import sample_surface
from plantbench.plant import TriMesh
from reference_impl.guo import species_prior
from reference_impl.guo.pipeline import reconstruct_guo

N_POINTS = 300_000


@pytest.fixture(scope="module")
def maple_points():
    plant, _ = grow_species("maple", 0)
    mesh = TriMesh.concatenate([plant.branch_mesh, plant.leaf_mesh])
    return sample_surface(mesh, N_POINTS, np.random.default_rng(0))[0]


@pytest.mark.benchmark(group="guo-300k")
def test_guo_300k_points(benchmark, maple_points):
    prior = species_prior("maple")
    res = benchmark.pedantic(reconstruct_guo, args=(maple_points, np.random.default_rng(0)),
                             kwargs={"prior": prior}, rounds=1, iterations=1)
    assert len(res.skeleton) > 1000 and len(res.leaves) > 1000


@pytest.mark.benchmark(group="guo-300k")
def test_raw_ckdtree_knn_300k(benchmark, maple_points):
    def query():
        return cKDTree(maple_points).query(maple_points, k=48, workers=-1)

    dist, _ = benchmark.pedantic(query, rounds=1, iterations=1)
    assert dist.shape == (N_POINTS, 48)
