"""guo's procedural leaves: "attached at the tip nodes along branch directions", with the leaf configuration of the
species hint (Guo et al. 2018, section 5.3: leaves per node, mean length, angle to the stem).

What the hint says (arrangement, mean leaf length, the roll angle phi as the divergence between successive leaves)
is used; what it does not say (insertion angle, droop, blade shape, petiole) takes generic values. The blade is the
Bezier leaf of :mod:`plantbench.geometry.leaf` with its default (generic) shape. The mesh layout is that of every
foliage mesh here: all blades first (the same number of vertices each), then one 6-vertex petiole prism per leaf.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from plantbench.geometry.leaf import (
    PARAM_NAMES,
    PRISM_FACES,
    BezierLeaf,
    leaf_points,
    petiole_prisms,
    tessellate_placed,
)
from plantbench.geometry.tubes import axis_positions, unit
from plantbench.plant import Leaf, TriMesh

__all__ = ["LeafConfig", "PlacedLeaves", "place_leaves"]


@dataclass(frozen=True)
class LeafConfig:
    """Leaf configuration of one run (the hint's values, generic ones where it is silent)."""

    length: float
    """Mean blade length, metres (the hint's leaf_length)."""
    arrangement: str = "spiral"
    """'spiral' (one leaf per node), 'opposite' (two, decussate) or 'whorl' (:attr:`per_whorl`)."""
    divergence: float = 137.5
    """Azimuth between successive spiral leaves, degrees (the hint's roll angle phi)."""
    per_whorl: int = 3
    max_radius: float = 0.002
    """Nodes of branches at most this thick bear leaves (twice the hint's twig radius)."""
    insertion_angle: float = 45.0
    """Angle between the petiole and the twig, degrees (generic)."""
    droop: float = 0.5
    """How far the blade turns from the petiole towards the horizontal, 0..1 (generic)."""
    petiole_ratio: float = 0.12
    """Petiole length as a fraction of the blade length (generic)."""
    petiole_radius: float = 0.0005
    resolution: tuple[int, int] = (2, 5)
    shape: BezierLeaf = field(default_factory=BezierLeaf)


@dataclass(frozen=True)
class PlacedLeaves:
    leaves: list[Leaf]
    mesh: TriMesh


def place_leaves(positions: np.ndarray, parents: np.ndarray, radii: np.ndarray, main: np.ndarray,
                 tangent: np.ndarray, normal: np.ndarray, levels: list[np.ndarray], eligible: np.ndarray,
                 config: LeafConfig, rng: np.random.Generator) -> PlacedLeaves:
    """Leaves on the ``eligible`` (n,) bool nodes thinner than ``config.max_radius``, with node frames
    (``tangent``, ``normal``: :func:`plantbench.geometry.tubes.node_frames`)."""
    nodes = np.flatnonzero(eligible & (parents >= 0) & (radii <= config.max_radius))
    k_axis = axis_positions(parents, main, levels)[nodes]
    if config.arrangement == "opposite":
        az = 0.5 * np.pi * k_axis[:, None] + np.array([[0.0, np.pi]])
    elif config.arrangement == "whorl":
        gap = 2 * np.pi / config.per_whorl
        az = 0.5 * gap * (k_axis[:, None] % 2) + gap * np.arange(config.per_whorl)[None, :]
    else:
        az = np.radians(config.divergence) * k_axis[:, None]
    per = az.shape[1]
    m = len(nodes) * per
    if m == 0:
        return PlacedLeaves([], TriMesh.empty())
    node_of = np.repeat(nodes, per)
    az = az.ravel() + rng.normal(0.0, np.radians(10.0), m)
    t, nrm = tangent[node_of], normal[node_of]
    radial = np.cos(az)[:, None] * nrm + np.sin(az)[:, None] * np.cross(t, nrm)
    beta = np.radians(config.insertion_angle)
    pet = unit(np.cos(beta) * t + np.sin(beta) * radial)
    start = positions[node_of]
    lengths = np.full(m, float(config.length))
    base = start + radii[node_of, None] * radial + config.petiole_ratio * lengths[:, None] * pet
    horiz = pet * np.array([1.0, 1.0, 0.0])
    flat = np.linalg.norm(horiz, axis=1) < 1e-6
    horiz[flat] = radial[flat] * np.array([1.0, 1.0, 0.0])
    x = unit((1 - config.droop) * pet + config.droop * unit(horiz))
    z = np.array([0.0, 0.0, 1.0]) - x[:, [2]] * x
    bad = np.linalg.norm(z, axis=1) < 1e-6
    z[bad] = np.cross(x[bad], radial[bad])
    z = unit(z)
    rot = np.round(np.stack([x, np.cross(z, x), z], axis=2), 9)
    base = np.round(base, 9)
    omega = np.repeat(config.shape.vector()[None], m, 0)
    world, blade_faces = tessellate_placed(omega, lengths, rot, base, config.resolution)
    q = world.shape[1]
    # petioles: triangular prisms from the twig axis to the blade base
    pv = petiole_prisms(start, base, config.petiole_radius)
    pet_faces = (PRISM_FACES[None] + (m * q + np.arange(m) * 6)[:, None, None]).reshape(-1, 3)
    verts = np.concatenate([world.reshape(-1, 3), pv.reshape(-1, 3)])
    faces = np.concatenate([blade_faces, pet_faces])
    ids = np.concatenate([np.repeat(np.arange(m), len(blade_faces) // m), np.repeat(np.arange(m), 6)])
    faces = faces[np.argsort(ids, kind="stable")]
    vs = np.linspace(0.0, 1.0, 33)
    width = float((leaf_points(omega[:1], np.ones_like(vs), vs)[..., 1].max()
                   - leaf_points(omega[:1], -np.ones_like(vs), vs)[..., 1].min()) * config.length)
    params = {name: float(v) for name, v in zip(PARAM_NAMES, omega[0])}
    leaves = []
    for i in range(m):
        tr = np.eye(4)
        tr[:3, :3], tr[:3, 3] = rot[i], base[i]
        leaves.append(Leaf(i, int(node_of[i]), tr, dict(params), float(lengths[i]), width))
    return PlacedLeaves(leaves, TriMesh(verts, faces))
