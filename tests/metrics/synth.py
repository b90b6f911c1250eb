"""Synthetic inputs for the metric tests and benchmarks: small random trees of straight-ish segments with radii,
their pruned / scaled / bent variants, and simple meshes. Independent of the plantbench generator."""

from __future__ import annotations

import numpy as np

from plantbench.plant import Skeleton, TriMesh
from plantbench.skeletons import branch_chains, children_lists


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    axis = axis / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)


def random_tree(rng: np.random.Generator, n_laterals: int = 20, *, seg_len: float = 0.05, trunk_segments: int = 12,
                radius: float = 0.02) -> Skeleton:
    """A random tree: a vertical trunk, then ``n_laterals`` lateral axes attached at random interior nodes, each
    leaving its parent axis at 30-60 degrees with a random roll and bending slightly along its length."""
    pos = [np.zeros(3)]
    rad = [radius]
    par = [-1]
    direction = [np.array([0.0, 0.0, 1.0])]

    def axis(start: int, d: np.ndarray, n: int, r0: float) -> None:
        node = start
        for i in range(n):
            d = d + rng.normal(0, 0.08, 3)
            d /= np.linalg.norm(d)
            pos.append(pos[node] + seg_len * d)
            rad.append(r0 * (1 - 0.6 * (i + 1) / n))
            par.append(node)
            direction.append(d)
            node = len(pos) - 1

    axis(0, np.array([0.0, 0.0, 1.0]), trunk_segments, radius)
    for _ in range(n_laterals):
        p = np.asarray(par)
        nkids = np.bincount(p[p >= 0], minlength=len(pos))
        cand = np.flatnonzero((nkids == 1) & (np.arange(len(pos)) > 0))
        node = int(rng.choice(cand))
        d0 = direction[node]
        perp = np.cross(d0, rng.normal(size=3))
        perp /= np.linalg.norm(perp)
        ang = np.radians(rng.uniform(30, 60))
        d = np.cos(ang) * d0 + np.sin(ang) * perp
        axis(node, d, int(rng.integers(3, 7)), 0.6 * rad[node])
    return Skeleton(np.array(pos), np.array(rad), np.array(par))


def subset(skel: Skeleton, keep: np.ndarray) -> Skeleton:
    """The skeleton restricted to nodes ``keep`` (a boolean mask closed under taking parents)."""
    idx = np.flatnonzero(keep)
    remap = np.full(len(skel), -1)
    remap[idx] = np.arange(len(idx))
    par = skel.parents[idx]
    return Skeleton(skel.positions[idx], skel.radii[idx], np.where(par >= 0, remap[np.maximum(par, 0)], -1))


def prune_terminal(skel: Skeleton, fraction: float, rng: np.random.Generator) -> Skeleton:
    """Remove ``fraction`` of the terminal branches (chains ending at a tip), the junction node kept.
    The order of removal is a fixed random permutation, so a larger fraction removes a superset."""
    chains = branch_chains(skel)
    kids = children_lists(skel)
    terminal = [c for c in chains if len(kids[int(c[-1])]) == 0 and skel.parents[int(c[0])] >= 0]
    order = rng.permutation(len(terminal))
    keep = np.ones(len(skel), bool)
    for i in order[: int(round(fraction * len(terminal)))]:
        keep[terminal[i][1:]] = False
    return subset(skel, keep)


def bend(skel: Skeleton, magnitude_deg: float, rng: np.random.Generator) -> Skeleton:
    """Rotate every non-trunk branch's subtree about its junction by magnitude * u_i around a random axis."""
    chains = branch_chains(skel)
    kids = children_lists(skel)
    pos = skel.positions.copy()
    for c in chains[1:]:
        axis = rng.normal(size=3)
        u = rng.uniform(0.5, 1.0)
        j = int(c[0])
        sub = [int(c[1])]
        for i in sub:
            sub.extend(kids[i].tolist())
        R = _rotation(axis, np.radians(magnitude_deg) * u)
        pos[sub] = (pos[sub] - pos[j]) @ R.T + pos[j]
    return Skeleton(pos, skel.radii, skel.parents)


def rotate_z(skel: Skeleton, angle: float, offset=(0.0, 0.0, 0.0)) -> Skeleton:
    R = _rotation(np.array([0.0, 0.0, 1.0]), angle)
    return Skeleton(skel.positions @ R.T + np.asarray(offset), skel.radii, skel.parents)


def scaled(skel: Skeleton, factor: float) -> Skeleton:
    return Skeleton(skel.positions * factor, skel.radii * factor, skel.parents)


def cylinder(radius: float = 0.1, height: float = 1.0, n_around: int = 16, n_up: int = 8) -> TriMesh:
    """An open cylinder around the z axis from z = 0 to ``height``."""
    th = np.linspace(0, 2 * np.pi, n_around, endpoint=False)
    z = np.linspace(0, height, n_up + 1)
    v = np.stack([np.tile(radius * np.cos(th), len(z)), np.tile(radius * np.sin(th), len(z)),
                  np.repeat(z, n_around)], axis=1)
    faces = []
    for i in range(n_up):
        for j in range(n_around):
            a, b = i * n_around + j, i * n_around + (j + 1) % n_around
            faces += [(a, b, b + n_around), (a, b + n_around, a + n_around)]
    return TriMesh(v, np.array(faces))


def tube_mesh(skel: Skeleton, sides: int = 6) -> TriMesh:
    """A prism of the node's radius around every edge (a crude generalised cylinder)."""
    meshes = []
    th = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    for a, b in skel.edges:
        p, q = skel.positions[a], skel.positions[b]
        d = (q - p) / np.linalg.norm(q - p)
        u = np.cross(d, [1.0, 0, 0] if abs(d[0]) < 0.9 else [0, 1.0, 0])
        u /= np.linalg.norm(u)
        w = np.cross(d, u)
        ring = np.cos(th)[:, None] * u + np.sin(th)[:, None] * w
        v = np.concatenate([p + skel.radii[a] * ring, q + skel.radii[b] * ring])
        f = [(j, (j + 1) % sides, sides + (j + 1) % sides) for j in range(sides)]
        f += [(j, sides + (j + 1) % sides, sides + j) for j in range(sides)]
        meshes.append(TriMesh(v, np.array(f)))
    return TriMesh.concatenate(meshes)


def synthetic_case(case_dir, rng: np.random.Generator, *, n_laterals: int = 6, n_views: int = 4, scan: bool = True,
                   size: int = 48):
    """Write a small case folder: plant/ (tree, tube branches, one quad leaf per tip), views/cameras.json and
    instance maps ray cast from the ground truth, and optionally scan/scan.ply. Returns the Plant."""
    from pathlib import Path

    from PIL import Image

    from plantbench.cameras import look_at, write_cameras
    from plantbench.io.plantio import write_plant
    from plantbench.io.ply import write_points
    from plantbench.metrics.surface import sample_surface
    from plantbench.plant import Leaf, Plant
    from plantbench.schemas import PlantCounts, PlantJson

    case_dir = Path(case_dir)
    skel = random_tree(rng, n_laterals, seg_len=0.08)
    branches = tube_mesh(skel)
    kids = children_lists(skel)
    tips = [i for i in range(len(skel)) if len(kids[i]) == 0]
    leaves, quads, ids = [], [], []
    for k, tip in enumerate(tips):
        T = np.eye(4)
        T[:3, 3] = skel.positions[tip]
        T[:3, :3] = _rotation(rng.normal(size=3), rng.uniform(0, 3))
        L, W = 0.06, 0.03
        corners = np.array([[0, -W / 2, 0, 1], [L, -W / 2, 0, 1], [L, W / 2, 0, 1], [0, W / 2, 0, 1]]) @ T.T
        quads.append(TriMesh(corners[:, :3], np.array([[0, 1, 2], [0, 2, 3]])))
        ids += [k, k]
        leaves.append(Leaf(k, tip, T, {}, L, W))
    leaf_mesh = TriMesh.concatenate(quads)
    plant = Plant(skel, branches, leaf_mesh, np.array(ids), leaves)
    everything = TriMesh.concatenate([branches, leaf_mesh])
    lo, hi = everything.vertices.min(0), everything.vertices.max(0)
    meta = PlantJson(species="test", family="synthetic", seed=0, parameters={},
                     counts=PlantCounts(nodes=len(skel), branches=len(branch_chains(skel)), leaves=len(leaves),
                                        roots=1, branch_triangles=len(branches.faces),
                                        leaf_triangles=len(leaf_mesh.faces)),
                     height=float(hi[2]), crown_extent=[*lo.tolist(), *hi.tolist()], mean_branch_length=0.1,
                     version="test")
    write_plant(case_dir, plant, meta)
    # cameras around the plant and exact instance maps (0 background, 1 wood, 2 + k leaf k)
    import open3d as o3d

    centre = 0.5 * (lo + hi)
    cams = [look_at(centre + 2.5 * np.array([np.cos(a), np.sin(a), 0.3]), centre, fov_x_deg=40, width=size,
                    height=size) for a in np.linspace(0, 2 * np.pi, n_views, endpoint=False)]
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(everything.vertices.astype(np.float32)),
                        o3d.core.Tensor(everything.faces.astype(np.uint32)))
    label = np.concatenate([np.ones(len(branches.faces), np.int64), 2 + np.array(ids)])
    (case_dir / "views" / "instance").mkdir(parents=True)
    names = []
    for i, cam in enumerate(cams):
        o, d = cam.pixel_rays()
        rays = np.concatenate([np.broadcast_to(o, d.shape), d], 1).astype(np.float32)
        prim = scene.cast_rays(o3d.core.Tensor(rays))["primitive_ids"].numpy().astype(np.int64)
        inst = np.where(prim == scene.INVALID_ID, 0, label[np.minimum(prim, len(label) - 1)])
        Image.fromarray(inst.reshape(size, size).astype(np.uint16)).save(case_dir / "views" / "instance" / f"{i:04d}.png")
        names.append(f"{i:04d}.png")
    write_cameras(case_dir / "views" / "cameras.json", cams, names)
    if scan:
        (case_dir / "scan").mkdir()
        pts, _ = sample_surface(everything, 20000, rng)
        write_points(case_dir / "scan" / "scan.ply", pts + rng.normal(0, 0.0005, pts.shape))
    return plant
