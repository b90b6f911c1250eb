"""Generator speed, one full-size plant of each family through generate_case (growth, tubes, leaves, all files)
and through growth in memory: a Maple (space colonisation, about 1.7k branches, 9.6k leaves) and a wp_conifer
(Weber-Penn, about 2.2k branches, 11k leaves). Beside them, the raw scipy cKDTree marker query that dominates one
space-colonisation growth cycle (the same markers against the grown plant's nodes, k = 8 within the perception
radius); the Weber-Penn stages are in test_bench_weber_penn.py. Target (issue 11): generate_case <= 10 s on the
2-core development machine."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from plantbench.generate import generate_case
from plantbench.generate.case import grow_species
from plantbench.generate.space_colonisation import grow_skeleton
from plantbench.seeding import rng as seeded_rng
from plantbench.species import load_species

FULL_SIZE = [  # species, then the fewest branches and leaves its full-size plant has
    pytest.param("maple", 1200, 8000, marks=pytest.mark.benchmark(group="generate-maple"), id="maple"),
    pytest.param("wp_conifer", 1800, 9000, marks=pytest.mark.benchmark(group="generate-weber-penn"),
                 id="wp_conifer"),
]


@pytest.mark.parametrize(("species", "branches", "leaves"), FULL_SIZE)
def test_generate_case_full(benchmark, tmp_path, species, branches, leaves):
    meta = benchmark.pedantic(generate_case, args=(species, 0, tmp_path), rounds=2, iterations=1)
    assert meta.counts.branches > branches and meta.counts.leaves > leaves


@pytest.mark.parametrize(("species", "branches", "leaves"), FULL_SIZE)
def test_grow_full(benchmark, species, branches, leaves):
    plant, _ = benchmark.pedantic(grow_species, args=(species, 0), rounds=2, iterations=1)
    assert len(plant.leaves) > leaves


@pytest.mark.benchmark(group="generate-maple")
def test_raw_ckdtree_marker_query(benchmark):
    spec = load_species("maple")
    result, _, markers = grow_skeleton(spec, seeded_rng(0, "generate", "maple"))
    radius = spec.growth.perception_radius * spec.table1.internode_length

    def query():
        return cKDTree(result.positions).query(markers, k=8, distance_upper_bound=radius)

    dist, _ = benchmark(query)
    assert np.isfinite(dist[:, 0]).any()
