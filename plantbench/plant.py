"""In-memory model of a plant: skeleton, branch mesh, leaves.

This is the one representation shared by the generator (which produces it), the capture stage (which renders
it), the methods (which write the same shapes to their output folders) and the metrics (which compare two of
them). Arrays only, no behaviour beyond validation and a few derived views; reading and writing the on-disk
contract (docs/design.md, On-disk contracts) lives in :mod:`plantbench.io.plantio`.

Conventions: metres, right-handed world, Z up, roots on the ground plane z = 0.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from plantbench.errors import InputError

__all__ = ["Skeleton", "TriMesh", "Leaf", "Plant", "check_shape"]


def check_shape(name: str, array: Any, shape: tuple, dtype_kind: str | None = None) -> np.ndarray:
    """Validate ``array`` against ``shape`` (``-1`` for any length) and return it as an ndarray.

    The one validation helper used at public boundaries (metrics, I/O). Raises :class:`InputError` naming
    ``name`` on a wrong shape, a wrong dtype kind ('f' float, 'i' integer) or non-finite floats.
    """
    arr = np.asarray(array)
    if arr.ndim != len(shape) or any(s != -1 and s != a for s, a in zip(shape, arr.shape)):
        want = "(" + ", ".join("n" if s == -1 else str(s) for s in shape) + ")"
        raise InputError(f"{name}: expected shape {want}, got {arr.shape}")
    if dtype_kind == "f":
        if arr.dtype.kind not in "fiu":
            raise InputError(f"{name}: expected numbers, got dtype {arr.dtype}")
        arr = arr.astype(np.float64, copy=False)
        if arr.size and not np.all(np.isfinite(arr)):
            raise InputError(f"{name}: contains NaN or infinite values")
    elif dtype_kind == "i":
        if arr.size == 0:
            arr = arr.astype(np.int64)
        if arr.dtype.kind not in "iu":
            raise InputError(f"{name}: expected integers, got dtype {arr.dtype}")
        arr = arr.astype(np.int64, copy=False)
    return arr


@dataclass(frozen=True)
class Skeleton:
    """A forest of rooted trees given as a parent array.

    positions : (n, 3) float
        Node positions in metres.
    radii : (n,) float
        Branch radius at each node, metres, > 0.
    parents : (n,) int
        Index of each node's parent, -1 for a root. Edges run parent -> child.
    order : (n,) int
        Branch order (0 for the trunk/stems, +1 at each lateral branching); informative only.
    """

    positions: np.ndarray
    radii: np.ndarray
    parents: np.ndarray
    order: np.ndarray | None = None

    def __post_init__(self) -> None:
        pos = check_shape("skeleton positions", self.positions, (-1, 3), "f")
        n = len(pos)
        rad = check_shape("skeleton radii", self.radii, (n,), "f")
        par = check_shape("skeleton parents", self.parents, (n,), "i")
        order = np.zeros(n, np.int64) if self.order is None else check_shape("skeleton order", self.order, (n,), "i")
        if n and (par.min() < -1 or par.max() >= n):
            raise InputError("skeleton parents: index out of range")
        object.__setattr__(self, "positions", pos)
        object.__setattr__(self, "radii", rad)
        object.__setattr__(self, "parents", par)
        object.__setattr__(self, "order", order)

    def __len__(self) -> int:
        return len(self.positions)

    @property
    def edges(self) -> np.ndarray:
        """(m, 2) int: (parent, child) pairs."""
        child = np.flatnonzero(self.parents >= 0)
        return np.stack([self.parents[child], child], axis=1)

    @property
    def roots(self) -> np.ndarray:
        """(k,) int: indices of root nodes."""
        return np.flatnonzero(self.parents < 0)

    def children_counts(self) -> np.ndarray:
        """(n,) int: number of children of each node."""
        par = self.parents[self.parents >= 0]
        return np.bincount(par, minlength=len(self))

    def is_forest(self) -> bool:
        """True when following parents from every node reaches a root without a cycle."""
        n = len(self)
        # pointer jumping: after ceil(log2 n) + 1 squarings every node points at its root, unless on a cycle
        anc = np.where(self.parents < 0, np.arange(n), self.parents)
        for _ in range(int(np.ceil(np.log2(max(n, 2)))) + 1):
            anc = anc[anc]
        return bool(n == 0 or np.all(self.parents[anc] < 0))

    def translated(self, offset: np.ndarray) -> Skeleton:
        return Skeleton(self.positions + np.asarray(offset, float), self.radii, self.parents, self.order)


@dataclass(frozen=True)
class TriMesh:
    """A triangle mesh.

    vertices : (n, 3) float
    faces : (m, 3) int, indices into vertices
    """

    vertices: np.ndarray
    faces: np.ndarray

    def __post_init__(self) -> None:
        v = check_shape("mesh vertices", self.vertices, (-1, 3), "f")
        f = check_shape("mesh faces", self.faces, (-1, 3), "i")
        if f.size and (f.min() < 0 or f.max() >= len(v)):
            raise InputError("mesh faces: vertex index out of range")
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", f)

    @staticmethod
    def empty() -> TriMesh:
        return TriMesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64))

    @staticmethod
    def concatenate(meshes: list[TriMesh]) -> TriMesh:
        if not meshes:
            return TriMesh.empty()
        offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
        return TriMesh(
            np.concatenate([m.vertices for m in meshes]),
            np.concatenate([m.faces + o for m, o in zip(meshes, offsets)]),
        )

    def face_areas(self) -> np.ndarray:
        a, b, c = (self.vertices[self.faces[:, i]] for i in range(3))
        return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)


@dataclass(frozen=True)
class Leaf:
    """One leaf instance.

    id : int
        Leaf id, 0-based; instance maps store it as 2 + id.
    node : int
        Skeleton node the petiole attaches to (-1 when unknown, e.g. a reconstructed leaf).
    transform : (4, 4) float
        Leaf frame to world. In the leaf frame the blade's axis runs along +x from the base at the origin, the
        blade spans y, and +z is the upper-side normal.
    params : dict
        Bezier leaf parameters (plantbench.geometry.leaf.BezierLeaf fields).
    length, width : float
        Blade length and maximum width, metres.
    """

    id: int
    node: int
    transform: np.ndarray
    params: dict
    length: float
    width: float

    @property
    def centroid(self) -> np.ndarray:
        """World position of the blade's mid-axis point (half its length along the leaf x axis)."""
        return (self.transform @ np.array([0.5 * self.length, 0.0, 0.0, 1.0]))[:3]


@dataclass(frozen=True)
class Plant:
    """Ground truth (or a reconstruction) of one plant.

    leaf_mesh_ids : (m,) int, one per face of ``leaf_mesh``: the face's leaf id.
    meta : dict, what plant.json records besides the arrays (species, seed, parameters, counts ...).
    """

    skeleton: Skeleton
    branch_mesh: TriMesh
    leaf_mesh: TriMesh
    leaf_mesh_ids: np.ndarray
    leaves: list[Leaf] = field(default_factory=list)
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        ids = check_shape("leaf face ids", self.leaf_mesh_ids, (len(self.leaf_mesh.faces),), "i")
        object.__setattr__(self, "leaf_mesh_ids", ids)

    def scaled(self, factor: float) -> Plant:
        """The plant scaled by ``factor`` (> 0) about the origin: positions, radii, meshes and leaves (their frames
        stay rigid; blade length and width scale, the Bezier parameters are in leaf lengths)."""
        if not factor > 0:
            raise InputError(f"scale factor must be > 0, got {factor}")
        f = float(factor)
        sk = self.skeleton
        leaves = []
        for leaf in self.leaves:
            t = np.array(leaf.transform, float)
            t[:3, 3] *= f
            leaves.append(Leaf(leaf.id, leaf.node, t, dict(leaf.params), leaf.length * f, leaf.width * f))
        return Plant(Skeleton(sk.positions * f, sk.radii * f, sk.parents, sk.order),
                     TriMesh(self.branch_mesh.vertices * f, self.branch_mesh.faces),
                     TriMesh(self.leaf_mesh.vertices * f, self.leaf_mesh.faces), self.leaf_mesh_ids, leaves,
                     dict(self.meta))

    def translated(self, offset) -> Plant:
        """The plant moved by ``offset`` (3,): positions, meshes and leaf frames."""
        o = np.asarray(offset, float).reshape(3)
        sk = self.skeleton
        leaves = []
        for leaf in self.leaves:
            t = np.array(leaf.transform, float)
            t[:3, 3] += o
            leaves.append(Leaf(leaf.id, leaf.node, t, dict(leaf.params), leaf.length, leaf.width))
        return Plant(Skeleton(sk.positions + o, sk.radii, sk.parents, sk.order),
                     TriMesh(self.branch_mesh.vertices + o, self.branch_mesh.faces),
                     TriMesh(self.leaf_mesh.vertices + o, self.leaf_mesh.faces), self.leaf_mesh_ids, leaves,
                     dict(self.meta))

    @property
    def height(self) -> float:
        parts = [self.skeleton.positions[:, 2], self.branch_mesh.vertices[:, 2], self.leaf_mesh.vertices[:, 2]]
        z = np.concatenate([p for p in parts if p.size])
        return float(z.max()) if z.size else 0.0
