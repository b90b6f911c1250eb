"""Small synthetic plants for the capture tests (independent of plantbench.generate): a tapered trunk with a few
straight branches, each branch carrying flat elliptic leaves."""

from __future__ import annotations

import numpy as np

from plantbench.io.plantio import write_plant
from plantbench.plant import Leaf, Plant, Skeleton, TriMesh
from plantbench.schemas import PlantCounts, PlantJson


def tube(p0, p1, r0, r1, sides=10) -> TriMesh:
    """Open truncated cone from p0 (radius r0) to p1 (radius r1), normals outwards."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    axis = (p1 - p0) / np.linalg.norm(p1 - p0)
    a = np.cross(axis, [1.0, 0, 0] if abs(axis[0]) < 0.9 else [0, 1.0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(axis, a)
    ang = 2 * np.pi * np.arange(sides) / sides
    ring = np.cos(ang)[:, None] * a + np.sin(ang)[:, None] * b
    v = np.concatenate([p0 + r0 * ring, p1 + r1 * ring])
    i = np.arange(sides)
    j = (i + 1) % sides
    f = np.concatenate([np.stack([i, j, sides + j], 1), np.stack([i, sides + j, sides + i], 1)])
    return TriMesh(v, f)


def ellipse_leaf(transform, length, width, n=12) -> TriMesh:
    """Flat elliptic blade in the leaf frame (base at origin, axis +x, width along y), fan-triangulated."""
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    outline = np.stack([0.5 * length * (1 + np.cos(t)), 0.5 * width * np.sin(t), np.zeros(n)], 1)
    local = np.concatenate([[[0.5 * length, 0, 0]], outline])
    v = (np.c_[local, np.ones(len(local))] @ np.asarray(transform).T)[:, :3]
    f = np.stack([np.zeros(n, int), 1 + np.arange(n), 1 + (np.arange(n) + 1) % n], 1)
    return TriMesh(v, f)


def make_plant(height: float = 4.0, branches: int = 6, leaves_per_branch: int = 6, seed: int = 0) -> Plant:
    rng = np.random.default_rng(seed)
    s = height / 4.0
    trunk_top = np.array([0, 0, height * 0.8])
    pos = [np.zeros(3), trunk_top]
    radii = [0.08 * s, 0.04 * s]
    parents = [-1, 0]
    order = [0, 0]
    meshes = [tube(pos[0], pos[1], radii[0], radii[1])]
    leaf_meshes, leaf_ids, leaves = [], [], []
    for k in range(branches):
        az = 2 * np.pi * k / branches + 0.3
        z0 = height * (0.35 + 0.45 * k / max(branches - 1, 1))
        base = np.array([0, 0, z0])
        d = np.array([np.cos(az), np.sin(az), 0.6])
        d /= np.linalg.norm(d)
        tip = base + d * height * 0.35
        pos += [base, tip]
        n0 = len(pos) - 2
        radii += [0.03 * s, 0.01 * s]
        parents += [0, n0]
        order += [1, 1]
        meshes.append(tube(base, tip, 0.03 * s, 0.01 * s, sides=8))
        for j in range(leaves_per_branch):
            at = base + (tip - base) * (0.3 + 0.7 * j / max(leaves_per_branch - 1, 1))
            side = np.cross(d, rng.normal(0, 1, 3))  # leaves stand off the branch, perpendicular to it
            side[2] = abs(side[2]) * 0.3
            ax = side / np.linalg.norm(side)
            up = np.array([0, 0, 1.0]) + rng.normal(0, 0.3, 3)
            y = np.cross(up, ax)
            y /= np.linalg.norm(y)
            z = np.cross(ax, y)
            T = np.eye(4)
            T[:3, :3] = np.stack([ax, y, z], 1)
            T[:3, 3] = at + ax * 0.05 * s  # petiole: the blade starts clear of the branch
            length, width = 0.22 * s, 0.11 * s
            lid = len(leaves)
            leaves.append(Leaf(lid, n0 + 1, T, {}, length, width))
            m = ellipse_leaf(T, length, width)
            leaf_meshes.append(m)
            leaf_ids.append(np.full(len(m.faces), lid))
    skel = Skeleton(np.array(pos), np.array(radii), np.array(parents), np.array(order))
    return Plant(skel, TriMesh.concatenate(meshes), TriMesh.concatenate(leaf_meshes), np.concatenate(leaf_ids),
                 leaves, {"species": "test"})


def write_test_plant(case_dir, plant: Plant | None = None, **kw) -> Plant:
    plant = plant or make_plant(**kw)
    lo = np.concatenate([plant.branch_mesh.vertices, plant.leaf_mesh.vertices]).min(0)
    hi = np.concatenate([plant.branch_mesh.vertices, plant.leaf_mesh.vertices]).max(0)
    meta = PlantJson(
        species="test", family="test", seed=0, parameters={},
        counts=PlantCounts(nodes=len(plant.skeleton), branches=len(plant.skeleton.roots), leaves=len(plant.leaves),
                           roots=1, branch_triangles=len(plant.branch_mesh.faces),
                           leaf_triangles=len(plant.leaf_mesh.faces)),
        height=float(hi[2]), crown_extent=[*lo.tolist(), *hi.tolist()], mean_branch_length=1.0, version="test")
    write_plant(case_dir, plant, meta)
    return plant
