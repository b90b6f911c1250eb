"""The ``space-colonisation`` family: a species TOML -> a :class:`~plantbench.plant.Plant`.

Markers fill the species' crown envelope (:mod:`.envelope`); stems grow from the ground by Palubicki et al.'s
space colonisation (:mod:`.palubicki`); radii follow Eq. 5 (:mod:`plantbench.geometry.tubes`); branches become
generalised cylinders and leaves Bezier blades on petioles (:mod:`.foliage`).
``scale`` in (0, 1] shrinks the envelope by scale^(1/3), which shrinks the growth budget (total branch length,
number of internodes) roughly in proportion to ``scale``; internode length and leaf size are unchanged.
"""

from __future__ import annotations

import numpy as np

from plantbench.errors import InputError
from plantbench.generate.envelope import envelope_volume, sample_markers
from plantbench.generate.foliage import foliage_params, place_leaves
from plantbench.generate.palubicki import GrowthParams, grow_space_colonisation
from plantbench.generate.params import SpaceColonisationSpecies
from plantbench.geometry.tubes import node_frames, supported_length_radii, tube_mesh
from plantbench.geometry.vectors import levels
from plantbench.plant import Plant, Skeleton

__all__ = ["grow", "grow_skeleton", "foliage_params"]


def _check_scale(scale: float) -> float:
    if not (0.0 < float(scale) <= 1.0):
        raise InputError(f"scale must be in (0, 1], got {scale}", field="scale")
    return float(scale)


def grow_skeleton(spec: SpaceColonisationSpecies, rng: np.random.Generator, *, scale: float = 1.0):
    """Markers and growth only: returns (GrowthResult, radii (n,) float, markers (m, 3) float)."""
    scale = _check_scale(scale)
    s3 = scale ** (1.0 / 3.0)
    env = spec.envelope
    t1 = spec.table1
    ell = t1.internode_length
    height = env.height * s3
    radius = env.radius * s3
    volume = envelope_volume(height=height, crown_base=env.crown_base, radius=radius, shape=env.shape)
    count = max(int(round(env.marker_density * volume / ell**3)), 16)
    markers = sample_markers(rng, count, height=height, crown_base=env.crown_base, radius=radius, shape=env.shape,
                             offset=env.offset)
    k = spec.roots.count
    if k == 1:
        root_pos = np.zeros((1, 3))
        root_dir = np.array([[0.0, 0.0, 1.0]])
    else:
        ang = 2 * np.pi * np.arange(k) / k + rng.uniform(0, 2 * np.pi) + rng.normal(0, 0.2, k)
        rad = spec.roots.spread * s3 * (0.6 + 0.4 * rng.random(k))
        root_pos = np.stack([rad * np.cos(ang), rad * np.sin(ang), np.zeros(k)], 1)
        lean = np.radians(spec.roots.lean + rng.normal(0, 4.0, k))
        root_dir = np.stack([np.sin(lean) * np.cos(ang), np.sin(lean) * np.sin(ang), np.cos(lean)], 1)
    g = spec.growth
    params = GrowthParams(
        internode_length=ell,
        roll_angle=t1.roll_angle,
        branching_angle=t1.branching_angle,
        perception_angle=g.perception_angle,
        perception_radius=g.perception_radius,
        occupancy_radius=g.occupancy_radius,
        apical_control=g.apical_control,
        vigour=g.vigour,
        max_shoot=g.max_shoot,
        direction_weight=g.direction_weight,
        tropism=g.tropism,
        noise=g.noise,
        max_turn=g.max_turn,
        bud_break=g.bud_break,
        max_iterations=g.max_iterations,
        shed_age=g.shed_age,
        shed_max_internodes=g.shed_max_internodes,
        bole_height=env.crown_base * height,
    )
    result = grow_space_colonisation(markers, root_pos, root_dir, params, rng)
    radii = supported_length_radii(result.positions, result.parents, gamma=t1.diameter_coefficient,
                                   tip_radius=spec.wood.tip_radius, internode_length=ell)
    return result, radii, markers


def grow(spec: SpaceColonisationSpecies, rng: np.random.Generator, *, scale: float = 1.0) -> Plant:
    """Grow one plant of ``spec`` (all random draws from ``rng``)."""
    result, radii, _ = grow_skeleton(spec, rng, scale=scale)
    pos = result.positions.copy()
    pos[result.parents < 0, 2] = 0.0
    skeleton = Skeleton(pos, radii, result.parents, result.order)
    main = (result.parents >= 0) & ~result.lateral
    branch_mesh = tube_mesh(pos, result.parents, radii, main, max_sides=spec.wood.max_sides,
                            min_sides=spec.wood.min_sides, edge_length=0.5 * spec.table1.internode_length)
    tangent, normal, _, _ = node_frames(pos, result.parents, main)
    foliage = place_leaves(pos, result.parents, radii, main, tangent, normal, levels(result.parents),
                           foliage_params(spec), rng)
    meta = {
        "derived": {
            "growth_units": round(float(result.growth_units), 6),
            "iterations": int(result.iterations),
            "markers_left": int(result.markers_left),
        },
        "scale": float(scale),
    }
    return Plant(skeleton, branch_mesh, foliage.mesh, foliage.face_ids, foliage.leaves, meta)
