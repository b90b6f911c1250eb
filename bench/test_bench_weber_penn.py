"""Weber-Penn generator speed: a full-size wp_conifer (about 2.2k branches, 11k leaves) through generate_case
(recursive stems, tubes, leaves, all files), through growth in memory and through the stem recursion alone, beside
the raw numpy Bezier evaluation of the same number of leaves (leaf.leaf_points on the leaf grid, the vectorised
core of leaf placement). Target (issue 11): generate_case <= 10 s on the 2-core development machine."""

import numpy as np
import pytest

from plantbench.generate import generate_case
from plantbench.generate.case import grow_species
from plantbench.generate.weber_penn import grow_skeleton
from plantbench.geometry.leaf import BezierLeaf, leaf_grid, leaf_points
from plantbench.seeding import rng as seeded_rng
from plantbench.species import load_species

SPECIES = "wp_conifer"


@pytest.mark.benchmark(group="generate-weber-penn")
def test_generate_case_full_wp_conifer(benchmark, tmp_path):
    meta = benchmark.pedantic(generate_case, args=(SPECIES, 0, tmp_path), rounds=2, iterations=1)
    assert meta.counts.branches > 1800 and meta.counts.leaves > 9000


@pytest.mark.benchmark(group="generate-weber-penn")
def test_grow_full_wp_conifer(benchmark):
    plant, _ = benchmark.pedantic(grow_species, args=(SPECIES, 0), rounds=2, iterations=1)
    assert len(plant.leaves) > 9000


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
