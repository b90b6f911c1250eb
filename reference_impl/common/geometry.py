"""Meshes for reconstructed skeletons and leaves, built with the generator's own geometry code.

- :func:`branch_mesh`: generalised cylinders along the skeleton (plantbench.geometry.tubes.tube_mesh, the same
  sweep that builds the ground-truth branches), each node's thickest child continuing its axis.
- :func:`leaf_frames`: a leaf-to-world 4x4 transform per leaf from a base point, an axis and a normal.
- :func:`quad_leaves`: flat rectangular quads (Xu et al. 2007 section 6: alpha-textured quads).
- :func:`bezier_leaves`: the Chaurasia-Beardsley Bezier leaf (plantbench.geometry.leaf) tessellated per leaf.
Each leaf builder returns the mesh and :class:`plantbench.plant.Leaf` records for leaves.json.
"""

from __future__ import annotations

import numpy as np

from plantbench.geometry.vectors import unit
from plantbench.plant import Leaf, Skeleton, TriMesh

__all__ = ["branch_mesh", "leaf_frames", "quad_leaves", "bezier_leaves"]


def branch_mesh(skeleton: Skeleton, *, edge_length: float, max_sides: int = 12, min_sides: int = 4) -> TriMesh:
    """Tubes along every axis of ``skeleton``; ``edge_length``: target ring edge length, metres."""
    from plantbench.geometry.tubes import main_child_mask, tube_mesh

    if len(skeleton) == 0:
        return TriMesh.empty()
    main = main_child_mask(skeleton.parents, skeleton.radii)
    return tube_mesh(skeleton.positions, skeleton.parents, skeleton.radii, main, max_sides=max_sides,
                     min_sides=min_sides, edge_length=edge_length)


def leaf_frames(base: np.ndarray, axis: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """(k, 4, 4) leaf-to-world transforms: leaf +x along ``axis``, +z along ``normal`` (orthogonalised), base at
    ``base``. base, axis, normal : (k, 3)."""
    x = unit(np.asarray(axis, float))
    nz = np.asarray(normal, float) - np.sum(np.asarray(normal, float) * x, 1, keepdims=True) * x
    bad = np.linalg.norm(nz, axis=1) < 1e-9
    if bad.any():
        alt = np.where(np.abs(x[bad, 2:3]) < 0.9, np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]]))
        nz[bad] = alt - np.sum(alt * x[bad], 1, keepdims=True) * x[bad]
    z = unit(nz)
    y = np.cross(z, x)
    t = np.zeros((len(x), 4, 4))
    t[:, :3, 0], t[:, :3, 1], t[:, :3, 2], t[:, :3, 3] = x, y, z, base
    t[:, 3, 3] = 1.0
    return t


def quad_leaves(transforms: np.ndarray, lengths: np.ndarray, widths: np.ndarray, nodes: np.ndarray,
                extra: list[dict] | None = None) -> tuple[TriMesh, list[Leaf]]:
    """Flat quads, one per leaf: in the leaf frame the rectangle [0, length] x [-width/2, width/2] at z = 0,
    two triangles facing +z. ``extra``: per-leaf entries stored in Leaf.params (e.g. the leaf-cluster size)."""
    k = len(lengths)
    if k == 0:
        return TriMesh.empty(), []
    corners = np.zeros((k, 4, 4))
    corners[:, :, 3] = 1.0
    corners[:, 1, 0] = lengths
    corners[:, 2, 0] = lengths
    corners[:, [0, 1], 1] = (-0.5 * widths)[:, None]
    corners[:, [2, 3], 1] = (0.5 * widths)[:, None]
    world = np.einsum("kij,kvj->kvi", transforms, corners)[:, :, :3]
    base = 4 * np.arange(k)[:, None]
    faces = np.concatenate([base + [0, 1, 2], base + [0, 2, 3]])
    leaves = [Leaf(i, int(nodes[i]), transforms[i], dict(extra[i]) if extra else {"model": "quad"},
                   float(lengths[i]), float(widths[i])) for i in range(k)]
    return TriMesh(world.reshape(-1, 3), faces), leaves


def bezier_leaves(transforms: np.ndarray, lengths: np.ndarray, nodes: np.ndarray, *, shape=None,
                  resolution: tuple[int, int] = (2, 4)) -> tuple[TriMesh, list[Leaf]]:
    """Bezier leaves (plantbench.geometry.leaf, default shape unless ``shape`` (a BezierLeaf) is given)."""
    from plantbench.geometry.leaf import BezierLeaf, max_half_width, tessellate_many

    k = len(lengths)
    if k == 0:
        return TriMesh.empty(), []
    leaf = shape or BezierLeaf()
    omega = np.broadcast_to(leaf.vector(), (k, 21))
    verts, faces = tessellate_many(omega, np.asarray(lengths, float), resolution)
    m = verts.shape[1]
    hom = np.concatenate([verts, np.ones((k, m, 1))], axis=2)
    world = np.einsum("kij,kvj->kvi", transforms, hom)[:, :, :3]
    all_faces = (faces[None, :, :] + (m * np.arange(k))[:, None, None]).reshape(-1, 3)
    width = 2.0 * float(max_half_width(leaf.vector()))
    params = leaf.to_dict()
    leaves = [Leaf(i, int(nodes[i]), transforms[i], params, float(lengths[i]), float(lengths[i]) * width)
              for i in range(k)]
    return TriMesh(world.reshape(-1, 3), all_faces), leaves
