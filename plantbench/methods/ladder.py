"""The calibration ladder: controlled reconstructions built from a case's ground truth (docs/design.md).

Each rung is an oracle method (``ladder:NAME``, resolved by :func:`plantbench.methods.api.method_from_spec`) whose
output is the ground truth degraded in one known way, so that ``plantbench calibrate`` can run the rungs through
the runner like any method and ask of every metric whether it orders them as their fidelity does:

- ``gt``: the ground truth itself;
- ``orders<=K`` (K = 3, 2, 1): the skeleton pruned to branch orders <= K (the trunk is order 0), the leaves of the
  kept nodes kept, the wood mesh rebuilt from the pruned skeleton;
- ``jitter-F%`` (F = 0.25, 0.5, 1, 2): every node moved by an isotropic Gaussian offset whose RMS length is F % of
  the plant height, the wood mesh rebuilt from the moved skeleton, each leaf moved with its node;
- ``scale-S`` (S = 1.05, 1.1, 1.25): the plant scaled by S about its root;
- ``leaves-F%`` (F = 10, 25, 50): every leaf moved by F % of its own length in a random direction, the wood untouched;
- ``twigs+F%`` (F = 25, 100, 400): invented twigs, F % of the plant's branch count, drawn from its own terminal
  branches (length, angle, radii) and attached at random nodes (:func:`add_twigs`), the wood mesh rebuilt;
- ``tangle-20%``: a fifth of the nodes re-hung on a nearby node of an unrelated branch, jumps across gaps as a
  graph method on a noisy cloud makes them (:func:`tangle`), the wood mesh rebuilt;
- ``prior-a``, ``prior-b``: the no-data prior (:func:`plantbench.methods.prior.grow_prior`) with seeds 0 and 1,
  scaled to the ground truth's height (seed 1 is the suite's own ``prior`` row when the case seed is 1);
- ``other-species``: the next species of the same family in the library (by name, cyclic), grown as the prior
  grows it, scaled to the same height;
- ``observed``: the ground truth cut to the wood its capture's views observed (:func:`cut_to_observed`): it must
  score ``skeleton.vf1_observed@1%`` about 1 and ``skeleton.vrecall_hidden@1%`` about 0.

Random draws come from ``rng(seed, "ladder", NAME)``: a rung is the same bytes for the same seed.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from plantbench.errors import InputError
from plantbench.plant import Leaf, Plant, Skeleton, TriMesh

__all__ = ["RUNGS", "OBSERVED_RUNG", "Rung", "LadderMethod", "ladder_method", "build_rung", "prune",
           "cut_to_observed", "jitter", "move_leaves", "add_twigs", "tangle", "other_species"]

PREFIX = "ladder:"


def _rebuild_wood(skeleton: Skeleton) -> TriMesh:
    from plantbench.geometry.tubes import main_child_mask, tube_mesh

    main = main_child_mask(skeleton.parents, skeleton.radii)
    return tube_mesh(skeleton.positions, skeleton.parents, skeleton.radii, main)


def _leaf_vertex_ids(plant: Plant) -> np.ndarray:
    """(v,) leaf id of each leaf-mesh vertex (-1 for a vertex no face uses)."""
    ids = np.full(len(plant.leaf_mesh.vertices), -1, np.int64)
    ids[plant.leaf_mesh.faces.ravel()] = np.repeat(plant.leaf_mesh_ids, 3)
    return ids


def _moved_leaves(plant: Plant, offsets: np.ndarray) -> tuple[list[Leaf], TriMesh]:
    """Leaves (and their mesh) each translated by ``offsets[k]`` (one row per leaf, in ``plant.leaves`` order)."""
    by_id = {leaf.id: k for k, leaf in enumerate(plant.leaves)}
    leaves = []
    for leaf, off in zip(plant.leaves, offsets):
        t = np.array(leaf.transform, float)
        t[:3, 3] += off
        leaves.append(Leaf(leaf.id, leaf.node, t, dict(leaf.params), leaf.length, leaf.width))
    vid = _leaf_vertex_ids(plant)
    row = np.array([by_id.get(int(i), -1) for i in vid], np.int64) if len(vid) else np.zeros(0, np.int64)
    verts = plant.leaf_mesh.vertices.copy()
    has = row >= 0
    verts[has] += offsets[row[has]]
    return leaves, TriMesh(verts, plant.leaf_mesh.faces)


def prune(plant: Plant, max_order: int) -> Plant:
    """The plant with only the nodes of branch order <= ``max_order`` (and their leaves); wood mesh rebuilt."""
    sk = plant.skeleton
    keep = sk.order <= max_order
    if len(sk) and not keep[sk.parents[keep & (sk.parents >= 0)]].all():
        raise InputError("prune: a kept node's parent has a higher branch order (orders must not fall along a path)")
    return _subplant(plant, keep, sk.parents >= 0)


def cut_to_observed(plant: Plant, share: np.ndarray, *, min_share: float | None = None) -> Plant:
    """The plant cut to the wood its capture observed: the edges (``Skeleton.edges`` order) whose observed
    ``share`` (:mod:`plantbench.capture.observed`) is at least ``min_share`` (None: the metrics' cut,
    :data:`plantbench.metrics.skeleton.OBSERVED_EDGE`), with their end nodes and the leaves of
    those nodes; a kept node whose own edge is hidden starts a new stem (a root). The calibration rung that scores
    observation 1 and inference 0."""
    from plantbench.metrics.skeleton import OBSERVED_EDGE

    min_share = OBSERVED_EDGE if min_share is None else min_share
    sk = plant.skeleton
    share = np.asarray(share, float)
    child = np.flatnonzero(sk.parents >= 0)
    if share.shape != (len(child),):
        raise InputError(f"cut_to_observed: {len(share)} shares for {len(child)} edges")
    seen_edge = np.zeros(len(sk), bool)  # per node: its own edge (to its parent) observed
    seen_edge[child] = share >= min_share
    keep = seen_edge.copy()
    keep[sk.parents[seen_edge]] = True
    return _subplant(plant, keep, seen_edge)


def _subplant(plant: Plant, keep: np.ndarray, link: np.ndarray) -> Plant:
    """The plant's nodes where ``keep`` (and their leaves), each joined to its parent where ``link`` (the parent
    kept too), else a root; wood mesh rebuilt."""
    sk = plant.skeleton
    new_index = np.cumsum(keep) - 1
    par = sk.parents[keep]
    joined = link[keep] & (par >= 0)
    joined[joined] = keep[par[joined]]
    parents = np.where(joined, new_index[np.maximum(par, 0)], -1)
    skeleton = Skeleton(sk.positions[keep], sk.radii[keep], parents, sk.order[keep])
    kept_leaves = [leaf for leaf in plant.leaves if 0 <= leaf.node < len(sk) and keep[leaf.node]]
    kept_ids = np.array([leaf.id for leaf in kept_leaves], np.int64)
    face_keep = np.isin(plant.leaf_mesh_ids, kept_ids)
    leaf_mesh = TriMesh(plant.leaf_mesh.vertices, plant.leaf_mesh.faces[face_keep])
    leaves = [Leaf(leaf.id, int(new_index[leaf.node]), leaf.transform, leaf.params, leaf.length, leaf.width)
              for leaf in kept_leaves]
    return Plant(skeleton, _rebuild_wood(skeleton), leaf_mesh, plant.leaf_mesh_ids[face_keep], leaves,
                 dict(plant.meta))


def jitter(plant: Plant, fraction: float, rng: np.random.Generator) -> Plant:
    """Every node moved by N(0, s^2 I) with s = fraction x height / sqrt(3) (RMS offset = fraction x height); the
    wood mesh rebuilt, each leaf moved with its node (a leaf without a node stays)."""
    sk = plant.skeleton
    offsets = rng.normal(0.0, fraction * plant.height / np.sqrt(3.0), (len(sk), 3))
    skeleton = Skeleton(sk.positions + offsets, sk.radii, sk.parents, sk.order)
    leaf_off = np.array([offsets[leaf.node] if 0 <= leaf.node < len(sk) else np.zeros(3) for leaf in plant.leaves]
                        ).reshape(-1, 3)
    leaves, leaf_mesh = _moved_leaves(plant, leaf_off)
    return Plant(skeleton, _rebuild_wood(skeleton), leaf_mesh, plant.leaf_mesh_ids, leaves, dict(plant.meta))


def move_leaves(plant: Plant, fraction: float, rng: np.random.Generator) -> Plant:
    """Every leaf moved by ``fraction`` x its length in a uniformly random direction; the wood untouched."""
    d = rng.normal(size=(len(plant.leaves), 3))
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    lengths = np.array([leaf.length for leaf in plant.leaves]).reshape(-1, 1)
    leaves, leaf_mesh = _moved_leaves(plant, d * fraction * lengths)
    return Plant(plant.skeleton, plant.branch_mesh, leaf_mesh, plant.leaf_mesh_ids, leaves, dict(plant.meta))


def _terminal_branches(skeleton: Skeleton) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The plant's terminal branches (Stava chains ending at a tip): length, branching angle (radians, between the
    chain's first edge and the edge into its fork; from the vertical for a chain starting at a root), base radius
    (the chain's first node after its fork), tip radius and edge count, one row per branch."""
    from plantbench.skeletons import branch_chains, chain_lengths, children_lists

    kids = children_lists(skeleton)
    chains = [c for c in branch_chains(skeleton) if not len(kids[int(c[-1])])]
    pos, par, rad = skeleton.positions, skeleton.parents, skeleton.radii
    if not chains:
        raise InputError("ladder: the plant has no terminal branch to draw twigs from")
    first = np.array([c[0] for c in chains])
    second = np.array([c[1] for c in chains])
    out = pos[second] - pos[first]
    into = np.where((par[first] >= 0)[:, None], pos[first] - pos[np.maximum(par[first], 0)], [0.0, 0.0, 1.0])
    into[np.linalg.norm(into, axis=1) == 0] = [0.0, 0.0, 1.0]
    cos = np.sum(out * into, axis=1) / np.maximum(np.linalg.norm(out, axis=1) * np.linalg.norm(into, axis=1), 1e-300)
    return (chain_lengths(skeleton, chains), np.arccos(np.clip(cos, -1.0, 1.0)), rad[second],
            rad[[int(c[-1]) for c in chains]], np.array([len(c) - 1 for c in chains]))


def add_twigs(plant: Plant, fraction: float, rng: np.random.Generator) -> Plant:
    """The plant with invented twigs: ``fraction`` x its branch count (Stava chains) of straight twigs, each a
    terminal branch of the plant drawn at random (its length, branching angle, base and tip radius and edge count),
    attached at a node drawn uniformly among the nodes with children (without replacement while there are enough),
    leaving along the drawn angle from the direction of the edge into that node at a uniform roll; radii taper
    linearly from the base radius (at most the node's own) to the tip radius (at most the base). A twig that would
    end below the ground leaves upwards instead (the vertical component of its direction flipped). The leaves stay;
    the wood mesh is rebuilt."""
    from plantbench.geometry.vectors import perpendicular, unit
    from plantbench.skeletons import branch_chains

    sk = plant.skeleton
    n = int(round(fraction * len(branch_chains(sk))))
    length, angle, r_base, r_tip, edges = _terminal_branches(sk)
    inner = np.flatnonzero(sk.children_counts() > 0)
    if n == 0 or not len(inner):
        return plant
    at = rng.choice(inner, size=n, replace=n > len(inner))
    k = rng.integers(0, len(length), n)
    roll = rng.uniform(0.0, 2 * np.pi, n)
    pos, par = sk.positions, sk.parents
    u = np.where((par[at] >= 0)[:, None], pos[at] - pos[np.maximum(par[at], 0)], [0.0, 0.0, 1.0])
    u[np.linalg.norm(u, axis=1) == 0] = [0.0, 0.0, 1.0]
    u = unit(u)
    e1 = perpendicular(u)
    e2 = np.cross(u, e1)
    d = np.cos(angle[k])[:, None] * u + np.sin(angle[k])[:, None] * (np.cos(roll)[:, None] * e1
                                                                    + np.sin(roll)[:, None] * e2)
    below = pos[at, 2] + length[k] * d[:, 2] < 0
    d[below, 2] *= -1
    rb = np.minimum(r_base[k], sk.radii[at])
    rt = np.minimum(r_tip[k], rb)
    m = np.maximum(edges[k], 1)
    twig = np.repeat(np.arange(n), m)
    step = np.arange(int(m.sum())) - np.repeat(np.cumsum(m) - m, m) + 1  # 1..m along each twig
    f = step / np.repeat(m, m)
    new_pos = pos[at][twig] + (f * length[k][twig])[:, None] * d[twig]
    new_rad = rb[twig] + f * (rt - rb)[twig]
    first = step == 1
    new_index = len(sk) + np.arange(len(twig))
    new_par = np.where(first, at[twig], new_index - 1)
    skeleton = Skeleton(np.concatenate([pos, new_pos]), np.concatenate([sk.radii, new_rad]),
                        np.concatenate([par, new_par]), np.concatenate([sk.order, sk.order[at][twig] + 1]))
    return Plant(skeleton, _rebuild_wood(skeleton), plant.leaf_mesh, plant.leaf_mesh_ids, list(plant.leaves),
                 dict(plant.meta))


def tangle(plant: Plant, fraction: float, rng: np.random.Generator, *, max_gap: float = 0.05,
           candidates: int = 16) -> Plant:
    """The plant with jumps across gaps, as a graph method on a noisy cloud makes them: ``fraction`` of its non-root
    nodes, drawn at random and taken in that order, each re-hung on the nearest node (of its ``candidates`` nearest,
    within ``max_gap`` x the height) of a branch (Stava chain) that is neither its own nor one joined to it at a fork
    (its parent, sibling and child branches), unless that node descends from it (no cycle). A node without such a
    neighbour keeps its parent. Positions, radii and leaves stay; the wood mesh is rebuilt."""
    from scipy.spatial import cKDTree

    from plantbench.skeletons import branch_chains

    sk = plant.skeleton
    chains = branch_chains(sk)
    chain_of = np.full(len(sk), -1, np.int64)
    for c, nodes in enumerate(chains):
        chain_of[nodes[1:]] = c
        if sk.parents[nodes[0]] < 0:
            chain_of[nodes[0]] = c
    fork_chain = np.array([chain_of[c[0]] for c in chains])  # the branch each branch hangs from (-1: none)
    joined: list[set[int]] = [{c} for c in range(len(chains))]
    for c in range(len(chains)):
        if fork_chain[c] >= 0:
            joined[c].add(int(fork_chain[c]))
            joined[int(fork_chain[c])].add(c)
    by_fork: dict[int, list[int]] = {}
    for c, nodes in enumerate(chains):
        by_fork.setdefault(int(nodes[0]), []).append(c)
    for siblings in by_fork.values():
        for c in siblings:
            joined[c].update(siblings)
    movable = np.flatnonzero(sk.parents >= 0)
    chosen = rng.permutation(movable)[:int(round(fraction * len(movable)))]
    tree = cKDTree(sk.positions)
    dist, near = tree.query(sk.positions[chosen], k=min(candidates + 1, len(sk)),
                            distance_upper_bound=max_gap * plant.height)
    parents = sk.parents.copy()
    for v, row_d, row in zip(chosen.tolist(), np.atleast_2d(dist), np.atleast_2d(near)):
        for dv, u in zip(row_d.tolist(), row.tolist()):
            if not np.isfinite(dv) or u == v or chain_of[u] < 0 or int(chain_of[u]) in joined[int(chain_of[v])]:
                continue
            a = u
            while a >= 0 and a != v:  # v must not be an ancestor of u
                a = parents[a]
            if a == v:
                continue
            parents[v] = u
            break
    skeleton = Skeleton(sk.positions, sk.radii, parents, sk.order)
    return Plant(skeleton, _rebuild_wood(skeleton), plant.leaf_mesh, plant.leaf_mesh_ids, list(plant.leaves),
                 dict(plant.meta))


def other_species(species: str) -> str:
    """The species after ``species`` among the library's species of the same family, by name (cyclic)."""
    from plantbench.species import load_species
    from plantbench.species import species as library

    family = load_species(species).family
    same = [n for n in library.names() if load_species(n).family == family]
    if len(same) < 2:
        raise InputError(f"ladder: no other species of family {family!r} in the library")
    return same[(same.index(species) + 1) % len(same)]


@dataclass(frozen=True)
class Rung:
    """One rung of the ladder: its name and how it degrades the ground truth."""

    name: str
    build: Callable[[Plant, str, np.random.Generator], Plant]
    """(ground truth, species, rng) -> the rung's plant"""


def _prior(seed: int):
    def build(plant: Plant, species: str, rng: np.random.Generator) -> Plant:
        from plantbench.methods.prior import grow_prior

        return grow_prior(species, seed, plant.height)
    return build


def _other(plant: Plant, species: str, rng: np.random.Generator) -> Plant:
    from plantbench.methods.prior import grow_prior

    return grow_prior(other_species(species), 1, plant.height)


RUNGS: dict[str, Rung] = {r.name: r for r in [
    Rung("gt", lambda p, s, g: p),
    *(Rung(f"orders<={k}", lambda p, s, g, k=k: prune(p, k)) for k in (3, 2, 1)),
    *(Rung(f"jitter-{f:g}%", lambda p, s, g, f=f: jitter(p, f / 100, g)) for f in (0.25, 0.5, 1, 2)),
    *(Rung(f"scale-{f:g}", lambda p, s, g, f=f: p.scaled(f)) for f in (1.05, 1.1, 1.25)),
    *(Rung(f"leaves-{f:g}%", lambda p, s, g, f=f: move_leaves(p, f / 100, g)) for f in (10, 25, 50)),
    *(Rung(f"twigs+{f:g}%", lambda p, s, g, f=f: add_twigs(p, f / 100, g)) for f in (25, 100, 400)),
    Rung("tangle-20%", lambda p, s, g: tangle(p, 0.2, g)),
    Rung("prior-a", _prior(0)),
    Rung("prior-b", _prior(1)),
    Rung("other-species", _other),
]}
"""The rungs, best first within each kind."""


def build_rung(name: str, plant: Plant, species: str, seed: int) -> Plant:
    """The rung ``name`` of ``plant`` (of ``species``), random draws from ``rng(seed, "ladder", name)``."""
    from plantbench.registry import did_you_mean
    from plantbench.seeding import rng

    if name not in RUNGS:
        raise InputError(did_you_mean("calibration rung", name, list(RUNGS)))
    return RUNGS[name].build(plant, species, rng(int(seed), "ladder", name))


OBSERVED_RUNG = "observed"
"""The rung cut to the wood the capture observed (:func:`cut_to_observed`): it reads the capture's
``views/observed_wood.npz``, so it is built by :class:`LadderMethod` rather than from :data:`RUNGS`."""


class LadderMethod:
    """``ladder:NAME``: writes the rung NAME of the case's ground truth (an oracle: it reads ``plant/``)."""

    inputs = "views"
    oracle = True

    def __init__(self, rung: str) -> None:
        from plantbench.registry import did_you_mean

        if rung not in RUNGS and rung != OBSERVED_RUNG:
            raise InputError(did_you_mean("calibration rung", rung, [*RUNGS, OBSERVED_RUNG]))
        self.rung = rung
        self.name = PREFIX + rung

    def reconstruct(self, capture_dir: Path, out_dir: Path, *, seed: int, species: str | None = None,
                    **options) -> None:
        from plantbench.io.plantio import read_plant, write_reconstruction

        if options:
            raise InputError(f"{self.name}: takes no options, got {', '.join(sorted(options))}")
        plant, meta = read_plant(capture_dir)
        if self.rung == OBSERVED_RUNG:
            from plantbench.capture.observed import OBSERVED_FILE, read_observed

            out = cut_to_observed(plant, read_observed(Path(capture_dir) / "views" / OBSERVED_FILE, plant.skeleton))
        else:
            out = build_rung(self.rung, plant, species or meta.species, seed)
        write_reconstruction(out_dir, out.skeleton, mesh=TriMesh.concatenate([out.branch_mesh, out.leaf_mesh]),
                             leaves=out.leaves)


def ladder_method(spec: str) -> LadderMethod:
    """The method of a ``ladder:NAME`` spec."""
    return LadderMethod(spec[len(PREFIX):])
