"""Synthetic leaf scenes: flat Bezier leaves ray-cast analytically into depth, id and colour images."""

from __future__ import annotations

import numpy as np
import pytest

from plantbench.cameras import Camera, look_at
from plantbench.geometry.leaf import BezierLeaf, leaf_points, silhouette_outline

LAUREL = BezierLeaf(sil_v1=0.15, sil_v2=0.5, sil_v3=0.85, sil_x1=0.18, sil_x2=0.22, sil_x3=0.1, axis1_z=0.03,
                    axis2_z=0.02)
PEACH = BezierLeaf(sil_v1=0.2, sil_v2=0.5, sil_v3=0.85, sil_x1=0.1, sil_x2=0.14, sil_x3=0.07, f_z2=0.02, g_z2=0.03)
FLAT = BezierLeaf(sil_v1=0.15, sil_v2=0.5, sil_v3=0.85, sil_x1=0.25, sil_x2=0.3, sil_x3=0.12)


def rotation(axis, angle) -> np.ndarray:
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def transform(rot: np.ndarray, pos) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = rot
    t[:3, 3] = pos
    return t


def surface_samples(omega, length, tr, nu=41, nv=81) -> np.ndarray:
    """Dense (u, v) grid of a leaf surface, world coordinates."""
    u, v = (a.ravel() for a in np.meshgrid(np.linspace(-1, 1, nu), np.linspace(0, 1, nv)))
    return (leaf_points(omega, u, v) * length) @ tr[:3, :3].T + tr[:3, 3]


def render_flat_leaves(leaves: list[tuple[BezierLeaf, float, np.ndarray]], camera: Camera, rng: np.random.Generator
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ray-cast flat, straight-axis Bezier leaves (a planar blade bounded by the silhouette): z-depth (inf: none),
    leaf index (-1: none) and an RGB image (a green per leaf, with texture noise; grey background)."""
    origin, dirs = camera.pixel_rays()
    n = len(dirs)
    best = np.full(n, np.inf)
    ids = np.full(n, -1)
    for k, (leaf, length, tr) in enumerate(leaves):
        sil = silhouette_outline(leaf.vector(), 512)
        normal, p0 = tr[:3, 2], tr[:3, 3]
        denom = dirs @ normal
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((p0 - origin) @ normal) / denom
        hit = origin + t[:, None] * dirs
        local = (hit - p0) @ tr[:3, :3] / length
        half = np.interp(local[:, 0], sil[:, 0], np.abs(sil[:, 1]), left=-1, right=-1)
        inside = (t > 0) & (np.abs(local[:, 1]) <= half) & (local[:, 0] >= 0) & (local[:, 0] <= 1)
        closer = inside & (t < best)
        best[closer] = t[closer]
        ids[closer] = k
    zdepth = np.where(ids >= 0, best * (dirs @ camera.R.T)[:, 2], np.inf)
    shade = rng.uniform(0.6, 1.0, len(leaves) + 1)
    rgb = np.tile(np.array([120, 120, 130], float), (n, 1))
    leafpx = ids >= 0
    rgb[leafpx] = np.array([60, 160, 50]) * shade[ids[leafpx], None] + rng.normal(0, 6, (leafpx.sum(), 3))
    h, w = camera.height, camera.width
    return zdepth.reshape(h, w), ids.reshape(h, w), np.clip(rgb, 0, 255).astype(np.uint8).reshape(h, w, 3)


def ring_cameras(count: int, *, radius: float, height: float, size: int, fov: float = 50.0) -> list[Camera]:
    cams = []
    for i in range(count):
        a = 2 * np.pi * i / count
        eye = (radius * np.cos(a), radius * np.sin(a), height)
        cams.append(look_at(eye, (0.0, 0.0, 0.15), fov_x_deg=fov, width=size, height=size))
    return cams


def scattered_leaves(count: int, rng: np.random.Generator, length: float = 0.1) -> list[tuple]:
    """``count`` flat leaves on a ring, tilted 20-40 degrees, far enough apart not to touch."""
    out = []
    for k in range(count):
        a = 2 * np.pi * k / count
        centre = np.array([0.18 * np.cos(a), 0.18 * np.sin(a), 0.1 + 0.06 * (k % 2)])
        yaw = rotation((0, 0, 1), a + rng.uniform(-0.3, 0.3))
        tilt = rotation((1, 0, 0), rng.uniform(0.35, 0.7))
        rot = yaw @ tilt
        base = centre - rot[:, 0] * length / 2
        out.append((FLAT, length, transform(rot, base)))
    return out


@pytest.fixture
def leaf_scene(tmp_path, rng):
    """A capture folder (views/images, views/cameras.json) of 6 flat leaves seen by 6 cameras, plus exact depth maps
    and leaf-id maps, and the leaves."""
    from PIL import Image

    from plantbench.cameras import write_cameras

    leaves = scattered_leaves(6, rng)
    cams = ring_cameras(6, radius=0.55, height=0.45, size=160)
    views = tmp_path / "views"
    (views / "images").mkdir(parents=True)
    depths, idmaps, names = [], [], []
    for i, cam in enumerate(cams):
        z, ids, rgb = render_flat_leaves(leaves, cam, rng)
        name = f"{i:04d}.png"
        Image.fromarray(rgb).save(views / "images" / name)
        depths.append(z)
        idmaps.append(ids)
        names.append(name)
    write_cameras(views / "cameras.json", cams, names)
    return views, depths, idmaps, leaves
