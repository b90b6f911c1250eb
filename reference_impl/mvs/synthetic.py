"""An analytic textured test scene, ray cast exactly in numpy: the ground truth that the depth engine is tested on.

The scene is a ground plane z = 0 plus spheres (and optionally tilted discs), all carrying a 3-D solid value-noise
texture, so every surface point has a well-defined colour independent of the viewpoint (Lambertian, no lighting).
Images are rendered with 2 x 2 supersampling (anti-aliased like a renderer with a box filter); depth is the exact
z-depth at the pixel centre (OpenCV convention: pixel (u, v)'s centre at integer (u, v)). No renderer is involved,
so the test of the depth engine does not depend on the capture stage.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from plantbench.cameras import Camera, look_at

__all__ = ["Scene", "default_scene", "ring_cameras", "render", "solid_texture", "scene_height", "write_case"]


@dataclass(frozen=True)
class Scene:
    """Spheres and discs above a ground plane.

    spheres : (k, 4) float, centre x y z and radius
    discs : (m, 7) float, centre x y z, unit normal x y z, radius
    ground : bool, whether the plane z = 0 is present (infinite)
    texture_seed : int, seed of the solid texture's lattice values
    """

    spheres: np.ndarray
    discs: np.ndarray = field(default_factory=lambda: np.zeros((0, 7)))
    ground: bool = True
    texture_seed: int = 0


def default_scene() -> Scene:
    """A 'plant-sized' scene about 1 m tall: a few spheres and tilted discs (leaf-like) above textured ground."""
    spheres = np.array([[0.0, 0.0, 0.45, 0.3], [0.25, -0.2, 0.9, 0.15], [-0.25, 0.15, 0.85, 0.18]])
    n1 = np.array([0.3, 0.2, 1.0]) / np.linalg.norm([0.3, 0.2, 1.0])
    n2 = np.array([-0.6, 0.1, 0.8]) / np.linalg.norm([-0.6, 0.1, 0.8])
    discs = np.array([[0.35, 0.3, 0.6, *n1, 0.14], [-0.35, -0.3, 0.5, *n2, 0.16]])
    return Scene(spheres, discs)


def ring_cameras(
    n: int, *, radius: float = 3.0, target=(0.0, 0.0, 0.5), elevations=(15.0, 35.0), fov_x_deg: float = 45.0,
    width: int = 256, height: int = 256,
) -> list[Camera]:
    """``n`` cameras spread uniformly on a ring around ``target``, elevation alternating between ``elevations``."""
    cams = []
    for i in range(n):
        az = 2 * np.pi * i / n
        el = np.radians(elevations[i % len(elevations)])
        eye = np.asarray(target) + radius * np.array([np.cos(az) * np.cos(el), np.sin(az) * np.cos(el), np.sin(el)])
        cams.append(look_at(eye, target, fov_x_deg=fov_x_deg, width=width, height=height))
    return cams


def solid_texture(points: np.ndarray, seed: int = 0) -> np.ndarray:
    """RGB in [0, 1] of a 4-octave 3-D value noise (cells 8, 4, 2, 1 cm) at ``points`` (n, 3) -> (n, 3)."""
    table = np.random.Generator(np.random.PCG64(seed)).random((4096, 3))
    out = np.zeros((len(points), 3))
    total = 0.0
    for cell, amp in ((0.08, 1.0), (0.04, 0.8), (0.02, 0.6), (0.01, 0.4)):
        q = points / cell
        i0 = np.floor(q).astype(np.int64)
        f = q - i0
        f = f * f * (3 - 2 * f)
        acc = np.zeros((len(points), 3))
        for dx in (0, 1):
            for dy in (0, 1):
                for dz in (0, 1):
                    ix, iy, iz = i0[:, 0] + dx, i0[:, 1] + dy, i0[:, 2] + dz
                    h = ((ix * 73856093) ^ (iy * 19349663) ^ (iz * 83492791)) & 4095
                    w = (f[:, 0] if dx else 1 - f[:, 0]) * (f[:, 1] if dy else 1 - f[:, 1]) * (f[:, 2] if dz else 1 - f[:, 2])
                    acc += w[:, None] * table[h]
        out += amp * acc
        total += amp
    return np.clip(out / total * 1.6 - 0.3, 0.0, 1.0)


def _intersect(scene: Scene, origin: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ray parameter t of the first hit (inf for a miss) and what was hit (-1 nothing, 0 ground, 1 an object);
    ``dirs`` (n, 3) need not be unit."""
    t = np.full(len(dirs), np.inf)
    if scene.ground:
        dz = dirs[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            tg = -origin[2] / dz
        t = np.where((tg > 1e-9) & np.isfinite(tg), np.minimum(t, tg), t)
    t_ground = t.copy()
    a = np.einsum("ij,ij->i", dirs, dirs)
    for cx, cy, cz, r in scene.spheres:
        oc = origin - np.array([cx, cy, cz])
        b = dirs @ oc
        c = oc @ oc - r * r
        disc = b * b - a * c
        ok = disc >= 0
        s = np.sqrt(np.where(ok, disc, 0.0))
        t0 = (-b - s) / a
        t = np.where(ok & (t0 > 1e-9), np.minimum(t, t0), t)
    for cx, cy, cz, nx, ny, nz, r in scene.discs:
        n = np.array([nx, ny, nz])
        c = np.array([cx, cy, cz])
        den = dirs @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            td = ((c - origin) @ n) / den
        hit = origin + td[:, None] * dirs
        ok = np.isfinite(td) & (td > 1e-9) & (np.linalg.norm(hit - c, axis=1) <= r)
        t = np.where(ok, np.minimum(t, td), t)
    what = np.where(np.isfinite(t), np.where(t < t_ground, 1, 0), -1)
    return t, what


def render(scene: Scene, camera: Camera, *, supersample: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Render one view.

    Returns
    -------
    image : (height, width, 3) uint8, anti-aliased colour (black where a ray misses)
    depth : (height, width) float32, exact z-depth at pixel centres, inf on a miss
    instance : (height, width) uint16, 1 on an object (sphere or disc), 0 on the ground or sky (as the capture's
        instance maps: 0 background)
    """
    w, h = camera.width, camera.height
    kinv = np.linalg.inv(camera.K)
    origin = camera.center
    ss = max(int(supersample), 1)
    offs = (np.arange(ss) + 0.5) / ss - 0.5
    colour = np.zeros((h * w, 3))
    for oy in offs:
        for ox in offs:
            u, v = np.meshgrid(np.arange(w) + ox, np.arange(h) + oy)
            d_cam = np.stack([u.ravel(), v.ravel(), np.ones(u.size)], 1) @ kinv.T
            dirs = d_cam @ camera.R
            t, _ = _intersect(scene, origin, dirs)
            hit = np.isfinite(t)
            col = np.zeros((h * w, 3))
            col[hit] = solid_texture(origin + t[hit, None] * dirs[hit], scene.texture_seed)
            colour += col
    colour /= ss * ss
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    d_cam = np.stack([u.ravel(), v.ravel(), np.ones(u.size)], 1) @ kinv.T  # z component 1: t is the z-depth
    t, what = _intersect(scene, origin, d_cam @ camera.R)
    image = np.round(colour.reshape(h, w, 3) * 255).astype(np.uint8)
    return image, t.reshape(h, w).astype(np.float32), (what == 1).reshape(h, w).astype(np.uint16)


def scene_height(scene: Scene) -> float:
    """Top of the objects above the ground (the 'plant height' of the synthetic scene)."""
    tops = [s[2] + s[3] for s in scene.spheres] + [d[2] + d[6] * np.hypot(d[3], d[4]) for d in scene.discs]
    return float(max(tops)) if tops else 0.0


def write_case(case_dir, scene: Scene, cameras: list[Camera], *, supersample: int = 2) -> None:
    """A case folder as the capture stage writes it (views/images, cameras.json, depth, instance, plus a minimal
    plant/plant.json carrying the scene height), for tests of the method on exact ground truth."""
    from pathlib import Path

    from PIL import Image

    from plantbench.cameras import write_cameras
    from plantbench.io.atomic import write_json

    case = Path(case_dir)
    for sub in ("images", "depth", "instance"):
        (case / "views" / sub).mkdir(parents=True, exist_ok=True)
    names = []
    for i, cam in enumerate(cameras):
        img, depth, inst = render(scene, cam, supersample=supersample)
        name = f"{i:04d}.png"
        Image.fromarray(img).save(case / "views" / "images" / name)
        np.save(case / "views" / "depth" / f"{i:04d}.npy", depth)
        Image.fromarray(inst).save(case / "views" / "instance" / name)
        names.append(name)
    write_cameras(case / "views" / "cameras.json", cameras, names)
    (case / "plant").mkdir(parents=True, exist_ok=True)
    write_json(case / "plant" / "plant.json", {
        "format": "plantbench.plant/1", "species": "synthetic", "family": "analytic", "seed": 0, "parameters": {},
        "counts": {"nodes": 0, "branches": 0, "leaves": 0, "roots": 0, "branch_triangles": 0, "leaf_triangles": 0},
        "height": scene_height(scene), "crown_extent": [0, 0, 0, 0, 0, 0], "mean_branch_length": 0.0,
        "version": "synthetic",
    })
