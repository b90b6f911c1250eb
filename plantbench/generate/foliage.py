"""Leaf placement shared by every generator family: Bezier leaves on petioles at the nodes of thin branches.

Leaves sit at every node thinner than ``max_branch_radius`` (Palubicki's LEAFINESS rule), arranged around the
twig in a spiral (one leaf per node, rolling by the divergence angle), opposite-decussate (two per node, pairs
turning by 90 degrees) or in whorls (n per node, alternate whorls offset by half the gap). The petiole leaves the
bark at the insertion angle; the blade turns from the petiole direction towards the horizontal (``droop``), its
upper side facing up, rolled by a random angle. Every leaf varies in length (log-normal), width (log-normal scale
of the silhouette offsets) and bend/fold/curl (normal jitter of the out-of-plane parameters). With
``random_phase`` the whole phyllotaxis turns by one random azimuth per plant.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from plantbench.geometry.leaf import (
    PARAM_NAMES,
    PRISM_FACES,
    BezierLeaf,
    leaf_points,
    petiole_prisms,
    tessellate_placed,
)
from plantbench.geometry.tubes import axis_positions
from plantbench.geometry.vectors import unit
from plantbench.plant import Leaf, TriMesh

if TYPE_CHECKING:
    from plantbench.generate.params import SpaceColonisationSpecies
    from plantbench.generate.params_wp import WeberPennSpecies

__all__ = ["FoliageParams", "Foliage", "foliage_params", "place_leaves"]

_Z_PARAMS = np.array([n.endswith("_z") or n[-2:] in ("z1", "z2", "z3") for n in PARAM_NAMES])
_X_PARAMS = np.array([n.startswith("sil_x") for n in PARAM_NAMES])


@dataclass(frozen=True)
class FoliageParams:
    """See :class:`plantbench.generate.params.Leaves` for each field's meaning."""

    shape: BezierLeaf
    length: float
    arrangement: str = "spiral"
    divergence: float = 137.5
    whorl_count: int = 3
    max_branch_radius: float = 0.004
    insertion_angle: float = 50.0
    droop: float = 0.5
    petiole_length: float = 0.01
    petiole_radius: float = 0.0006
    length_sd: float = 0.15
    width_sd: float = 0.08
    shape_jitter: float = 0.03
    roll_sd: float = 15.0
    random_phase: bool = False
    resolution: tuple[int, int] = (3, 6)


@dataclass(frozen=True)
class Foliage:
    leaves: list[Leaf]
    mesh: TriMesh
    face_ids: np.ndarray


def foliage_params(spec: SpaceColonisationSpecies | WeberPennSpecies) -> FoliageParams:
    """The leaf placement of a species of either family, from its ``leaves`` group."""
    lv = spec.leaves
    return FoliageParams(
        shape=BezierLeaf(**lv.shape.model_dump()),
        length=lv.length,
        arrangement=lv.arrangement,
        divergence=lv.divergence,
        whorl_count=lv.whorl_count,
        max_branch_radius=lv.max_branch_radius,
        insertion_angle=lv.insertion_angle,
        droop=lv.droop,
        petiole_length=lv.petiole_length,
        petiole_radius=lv.petiole_radius,
        length_sd=lv.length_sd,
        width_sd=lv.width_sd,
        shape_jitter=lv.shape_jitter,
        roll_sd=lv.roll_sd,
        random_phase=lv.random_phase,
        resolution=tuple(lv.resolution),
    )


def _phyllotaxis(k_axis: np.ndarray, p: FoliageParams) -> tuple[int, np.ndarray]:
    """Leaves per node and their azimuths (k, per) around the twig at nodes of phyllotaxis step ``k_axis`` (k,):
    a spiral rolls by the divergence angle, opposite pairs turn by 90 degrees, alternate whorls by half the gap."""
    if p.arrangement == "spiral":
        return 1, np.radians(p.divergence) * k_axis[:, None] + np.zeros((1, 1))
    if p.arrangement == "opposite":
        return 2, 0.5 * np.pi * k_axis[:, None] + np.array([[0.0, np.pi]])
    per = p.whorl_count
    gap = 2 * np.pi / per
    return per, 0.5 * gap * (k_axis[:, None] % 2) + gap * np.arange(per)[None, :]


def _petioles(positions: np.ndarray, radii: np.ndarray, tangent: np.ndarray, normal: np.ndarray, node_of: np.ndarray,
              az: np.ndarray, p: FoliageParams, rng: np.random.Generator
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The petiole of each leaf (m,) at node ``node_of`` and azimuth ``az`` around the twig.

    Returns its unit direction (at the insertion angle from the twig, +- 8 degrees), the twig's unit radial
    direction towards it, its start on the twig axis and its end at the blade base, past the bark (each (m, 3)).
    """
    m = len(node_of)
    t = tangent[node_of]
    nrm = normal[node_of]
    b = np.cross(t, nrm)
    radial = np.cos(az)[:, None] * nrm + np.sin(az)[:, None] * b
    beta = np.radians(p.insertion_angle) + rng.normal(0.0, np.radians(8.0), m)
    pet = unit(np.cos(beta)[:, None] * t + np.sin(beta)[:, None] * radial)
    pet_start = positions[node_of]
    base = positions[node_of] + radii[node_of, None] * radial + p.petiole_length * pet
    return pet, radial, pet_start, base


def _blade_frames(pet: np.ndarray, radial: np.ndarray, p: FoliageParams, rng: np.random.Generator) -> np.ndarray:
    """Rotations (m, 3, 3) whose columns are each blade's x (its axis), y and z (its upper side) in world: the axis
    turns from the petiole direction towards the horizontal by ``droop`` (+- 0.1), z faces up, then the blade rolls
    about its axis by a random angle."""
    m = len(pet)
    horiz = pet * np.array([1.0, 1.0, 0.0])
    hn = np.linalg.norm(horiz, axis=1)
    horiz = np.where(hn[:, None] > 1e-6, horiz / np.maximum(hn, 1e-12)[:, None], radial * np.array([1.0, 1.0, 0.0]))
    horiz = unit(horiz)
    droop = np.clip(p.droop + rng.normal(0.0, 0.1, m), 0.0, 1.0)
    x = unit((1 - droop)[:, None] * pet + droop[:, None] * horiz)
    up = np.array([0.0, 0.0, 1.0])
    z = up - (x @ up)[:, None] * x
    bad = np.linalg.norm(z, axis=1) < 1e-6
    z[bad] = np.cross(x[bad], radial[bad])
    z = unit(z)
    roll = rng.normal(0.0, np.radians(p.roll_sd), m)
    y = np.cross(z, x)
    z = np.cos(roll)[:, None] * z + np.sin(roll)[:, None] * y
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=2)


def _blade_shapes(p: FoliageParams, m: int, per: int, length_factor: np.ndarray | None,
                  rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Bezier parameters (m, 21) and lengths (m,) of the blades: the species' leaf with a log-normal width, jittered
    bend/fold/curl and a log-normal length (times each node's ``length_factor``)."""
    omega0 = p.shape.vector()
    omega = np.repeat(omega0[None], m, 0)
    omega[:, _X_PARAMS] *= np.exp(rng.normal(0.0, p.width_sd, m))[:, None]
    omega[:, _Z_PARAMS] += rng.normal(0.0, p.shape_jitter, (m, int(_Z_PARAMS.sum())))
    omega[:, _Z_PARAMS] = np.clip(omega[:, _Z_PARAMS], -0.5, 0.5)
    lengths = p.length * np.exp(rng.normal(0.0, p.length_sd, m))
    if length_factor is not None:
        lengths = lengths * np.repeat(np.asarray(length_factor, dtype=np.float64), per)
    return omega, lengths


def _leaf_mesh(omega: np.ndarray, lengths: np.ndarray, rot: np.ndarray, base: np.ndarray, pet_start: np.ndarray,
               p: FoliageParams) -> tuple[TriMesh, np.ndarray]:
    """Every blade tessellated at once plus the petioles (triangular prisms from the twig axis to the blade base);
    returns the mesh, faces grouped by leaf, and each face's leaf id."""
    m = len(omega)
    world, blade_faces = tessellate_placed(omega, lengths, rot, base, p.resolution)  # (m, q, 3)
    q = world.shape[1]
    blade_ids = np.repeat(np.arange(m), len(blade_faces) // m)
    pv = petiole_prisms(pet_start, base, p.petiole_radius)  # (m, 6, 3)
    off = m * q
    pet_faces = (PRISM_FACES[None] + (off + np.arange(m) * 6)[:, None, None]).reshape(-1, 3)
    pet_ids = np.repeat(np.arange(m), 6)
    verts = np.concatenate([world.reshape(-1, 3), pv.reshape(-1, 3)])
    faces = np.concatenate([blade_faces, pet_faces])
    ids = np.concatenate([blade_ids, pet_ids])
    order = np.argsort(ids, kind="stable")  # faces grouped by leaf
    return TriMesh(verts, faces[order]), ids[order]


def _leaf_records(omega: np.ndarray, lengths: np.ndarray, rot: np.ndarray, base: np.ndarray,
                  node_of: np.ndarray) -> list[Leaf]:
    """One :class:`~plantbench.plant.Leaf` per blade, its width from both silhouettes of the unit leaf."""
    m = len(omega)
    vs = np.linspace(0.0, 1.0, 33)
    right = leaf_points(omega, np.ones_like(vs), vs)[..., 1]
    left = leaf_points(omega, -np.ones_like(vs), vs)[..., 1]
    widths = (right.max(axis=1) - left.min(axis=1)) * lengths
    transforms = np.zeros((m, 4, 4))
    transforms[:, :3, :3] = rot
    transforms[:, :3, 3] = base
    transforms[:, 3, 3] = 1.0
    return [
        Leaf(int(i), int(node_of[i]), transforms[i], {nm: float(val) for nm, val in zip(PARAM_NAMES, omega[i])},
             float(lengths[i]), float(widths[i]))
        for i in range(m)
    ]


def place_leaves(positions: np.ndarray, parents: np.ndarray, radii: np.ndarray, main: np.ndarray,
                 tangent: np.ndarray, normal: np.ndarray, levels: list[np.ndarray], params: FoliageParams,
                 rng: np.random.Generator, *, nodes: np.ndarray | None = None, axis_index: np.ndarray | None = None,
                 length_factor: np.ndarray | None = None) -> Foliage:
    """Leaves for a skeleton with node frames (:func:`plantbench.geometry.tubes.node_frames`).

    nodes : (k,) int, increasing, optional
        The nodes that bear leaves; default: every non-root node thinner than ``params.max_branch_radius``.
    axis_index : (k,) int, optional
        Phyllotaxis step of each of ``nodes`` (the spiral/decussate/whorl roll counts it); default: the node's
        position along its axis.
    length_factor : (k,) float, optional
        Multiplies the blade length of the leaves at each of ``nodes`` (size profiles along a twig); default 1.

    Returns the leaves (ids 0..N-1 in node order), their mesh (blades and petioles) and the per-face leaf id.
    """
    p = params
    n = len(parents)
    if nodes is None:
        nodes = np.flatnonzero((parents >= 0) & (radii <= p.max_branch_radius))
    else:
        nodes = np.asarray(nodes, dtype=np.int64)
    k_axis = axis_positions(parents, main, levels)[nodes] if axis_index is None else np.asarray(axis_index, np.int64)
    per, az = _phyllotaxis(k_axis, p)
    m = len(nodes) * per
    if m == 0 or n == 0:
        return Foliage([], TriMesh.empty(), np.zeros(0, np.int64))
    node_of = np.repeat(nodes, per)
    az = az.ravel() + rng.normal(0.0, np.radians(10.0), m)
    if p.random_phase:  # drawn after the default draws: species without it keep their plants
        az = az + rng.uniform(0.0, 2 * np.pi)
    pet, radial, pet_start, base = _petioles(positions, radii, tangent, normal, node_of, az, p, rng)
    rot = _blade_frames(pet, radial, p, rng)
    omega, lengths = _blade_shapes(p, m, per, length_factor, rng)
    # what leaves.json records is exactly what is tessellated: round first, then build the mesh from the rounded values
    omega = np.round(omega, 6)
    lengths = np.round(lengths, 6)
    rot = np.round(rot, 9)
    base = np.round(base, 9)
    mesh, face_ids = _leaf_mesh(omega, lengths, rot, base, pet_start, p)
    return Foliage(_leaf_records(omega, lengths, rot, base, node_of), mesh, face_ids)
