"""The no-data prior: a tree of the hinted species that looks at nothing but the plant's height.

It is the floor beside every method (docs/design.md): a method earns its row by beating it. It grows the hinted
species from the species library (``scenes/species``, the generative model itself: an oracle of the model, marked
as such in every table, though it reads no ground truth of the case) with the method seed, scales it to the
height of the input cloud (its vertical extent above the ground plane z = 0,
:func:`plantbench.geometry.clouds.cloud_height`) and stands it where the cloud stands
(:func:`plantbench.geometry.clouds.cloud_base`: the median x, y of the cloud's lowest tenth), not on the true root,
which no method is given. It writes skeleton, mesh and leaves. Without a species hint it refuses to run.
"""

from __future__ import annotations

import math
from pathlib import Path

from plantbench.errors import InputError
from plantbench.geometry.clouds import cloud_base, cloud_height
from plantbench.plant import Plant, TriMesh

__all__ = ["SpeciesPrior", "grow_prior", "growth_height", "GROWTH_STEP", "cloud_height"]


def grow_prior(species: str, seed: int, height: float) -> Plant:
    """The hinted species grown from the stream ``rng(seed, "method", "prior", species)`` (a stream no case draws)
    at the size of a plant ``height`` metres tall (rounded: :func:`growth_height`), then scaled to exactly that
    height (root at the origin).

    The generators' ``scale`` grows a smaller plant of the species (size ~ scale^(1/3), fewer branches and leaves of
    the same size): the prior grows it once at full size (height H1) and, when ``height`` < H1, again at scale
    (height / H1)^3 from the same stream, so a small plant gets a small plant's branch and leaf counts."""
    from plantbench.generate.families import FAMILIES
    from plantbench.seeding import rng
    from plantbench.species import load_species

    if not height > 0:
        raise InputError(f"prior: the plant height must be > 0, got {height}")
    spec = load_species(species)
    grow = FAMILIES[spec.family].grow
    plant = grow(spec, rng(int(seed), "method", "prior", species), scale=1.0)
    grown = growth_height(height)
    if grown < plant.height:
        scale = max((grown / plant.height) ** 3, 1e-3)
        plant = grow(spec, rng(int(seed), "method", "prior", species), scale=scale)
    return plant.scaled(height / plant.height)


GROWTH_STEP = 0.01
"""The prior grows its plant at the input's height rounded to steps of 1 % (:func:`growth_height`), then scales it
to the exact height: growth is a chain of discrete choices that a 1e-6 m change of the height would reshuffle,
scaling is continuous in it."""


def growth_height(height: float) -> float:
    """``height`` rounded to the nearest power of (1 + :data:`GROWTH_STEP`): the height the prior grows at."""
    step = math.log1p(GROWTH_STEP)
    return math.exp(round(math.log(height) / step) * step)


class SpeciesPrior:
    """``prior``: the species grown with another seed, scaled to the input's height and stood on its base; reads
    nothing else."""

    name = "prior"
    inputs = "points"
    oracle = True
    """It reads the generator's species file (the generative model), which no other method may."""
    reads_ground_truth = False
    """Its input folder is a plain method's (points and hint): no ground truth of the case."""

    def reconstruct(self, capture_dir: Path, out_dir: Path, *, seed: int, species: str | None = None,
                    **options) -> None:
        from plantbench.hints import read_hint
        from plantbench.io.plantio import write_reconstruction
        from plantbench.io.ply import read_points

        if options:
            raise InputError(f"prior: takes no options, got {', '.join(sorted(options))}")
        hint = read_hint(capture_dir)
        if hint is None:
            raise InputError("prior: no species hint (hint.json) in the input folder; the no-data prior grows the "
                             "hinted species and cannot run without one", path=Path(capture_dir))
        cloud = Path(capture_dir) / "points.ply"
        if not cloud.is_file():
            raise InputError("prior: no points.ply to take the plant's height from", path=cloud)
        points = read_points(cloud)[0]
        plant = grow_prior(hint.species, seed, cloud_height(points)).translated(cloud_base(points))
        write_reconstruction(out_dir, plant.skeleton, mesh=TriMesh.concatenate([plant.branch_mesh, plant.leaf_mesh]),
                             leaves=plant.leaves)
