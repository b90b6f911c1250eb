"""Weber-Penn generator stages: the stem recursion alone for a full-size wp_conifer (about 2.2k branches, 11k
leaves), beside the raw numpy Bezier evaluation of the same number of leaves (leaf.leaf_points on the leaf grid,
the vectorised core of leaf placement). The whole plant, through generate_case and through growth in memory, is
timed with the other family's in test_bench_generate.py."""

import numpy as np
import pytest

from plantbench.generate.weber_penn import grow_skeleton
from plantbench.geometry.leaf import BezierLeaf, leaf_grid, leaf_points
from plantbench.seeding import rng as seeded_rng
from plantbench.species import load_species

SPECIES = "wp_conifer"


@pytest.mark.benchmark(group="generate-weber-penn")
def test_stem_recursion_wp_conifer(benchmark):
    spec = load_species(SPECIES)
    sk = benchmark.pedantic(grow_skeleton, args=(spec, seeded_rng(0, "generate", SPECIES)), rounds=2, iterations=1)
    assert sum(sk.stems) > 1000


@pytest.mark.benchmark(group="generate-weber-penn")
def test_raw_numpy_leaf_points(benchmark):
    spec = load_species(SPECIES)
    omega = np.repeat(BezierLeaf(**spec.leaves.shape.model_dump()).vector()[None], 11000, 0)
    u, v, _ = leaf_grid(tuple(spec.leaves.resolution))
    pts = benchmark(leaf_points, omega, u, v)
    assert pts.shape == (11000, len(u), 3)
