"""Generator speed: a full-size Maple (about 1.7k branches, 9.6k leaves) through generate_case (growth, tubes,
leaves, all files) and through growth alone, beside the raw scipy cKDTree marker query that dominates one growth
cycle (the same markers against the grown plant's nodes, k = 8 within the perception radius). Target: generate_case
<= 10 s on the 2-core development machine."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from plantbench.generate import generate_case
from plantbench.generate.case import grow_species
from plantbench.generate.space_colonisation import grow_skeleton
from plantbench.seeding import rng as seeded_rng
from plantbench.species import load_species

SPECIES = "maple"


@pytest.mark.benchmark(group="generate-maple")
def test_generate_case_full_maple(benchmark, tmp_path):
    meta = benchmark.pedantic(generate_case, args=(SPECIES, 0, tmp_path), rounds=2, iterations=1)
    assert meta.counts.branches > 1200 and meta.counts.leaves > 8000


@pytest.mark.benchmark(group="generate-maple")
def test_grow_full_maple(benchmark):
    plant, _ = benchmark.pedantic(grow_species, args=(SPECIES, 0), rounds=2, iterations=1)
    assert len(plant.leaves) > 8000


@pytest.mark.benchmark(group="generate-maple")
def test_raw_ckdtree_marker_query(benchmark):
    spec = load_species(SPECIES)
    result, _, markers = grow_skeleton(spec, seeded_rng(0, "generate", SPECIES))
    radius = spec.growth.perception_radius * spec.table1.internode_length

    def query():
        return cKDTree(result.positions).query(markers, k=8, distance_upper_bound=radius)

    dist, _ = benchmark(query)
    assert np.isfinite(dist[:, 0]).any()
