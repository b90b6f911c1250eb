"""Multi-view capture: camera placement, path-traced colour, and exact per-pixel ground truth.

- :func:`place_cameras`: ``n`` views on a Fibonacci band between two elevations (equal-area in the band, golden
  angle in azimuth: Guo et al. 2018's "views spread uniformly around the plant"), all aimed at the centre of the plant's
  bounding box, each at the distance where the plant's projection just fills ``fill`` of the frame.
- :func:`render_colour`: Mitsuba's path tracer (one scene with a sensor per view, rendered view by view).
- :func:`exact_maps`: one ray through each pixel centre of the canonical OpenCV camera (no anti-aliasing), cast
  against the merged mesh (branches, leaves, ground): z-depth (metres, inf where the ray escapes), instance id
  (0 ground/background, 1 wood, 2 + k leaf k) and optionally the world-space normal facing the camera.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from plantbench.cameras import Camera, look_at
from plantbench.capture.raycast import RayCaster
from plantbench.capture.scene import ground_triangles
from plantbench.errors import InputError
from plantbench.plant import Plant, check_shape

__all__ = ["GOLDEN_ANGLE", "view_directions", "place_cameras", "render_colour", "to_srgb8", "GroundTruthMesh",
           "ground_truth_parts", "ground_truth_mesh", "ground_truth_caster", "ExactMaps", "exact_maps"]

GOLDEN_ANGLE = np.pi * (3.0 - np.sqrt(5.0))


def view_directions(n: int, elevation: tuple[float, float]) -> np.ndarray:
    """Unit directions from the target to ``n`` cameras on a Fibonacci band.

    The sine of the elevation is uniform over the band (equal area on the sphere) and the azimuth advances by the
    golden angle, so any consecutive subset is also spread evenly.

    Returns
    -------
    (n, 3) float
    """
    lo, hi = np.radians(elevation[0]), np.radians(elevation[1])
    i = np.arange(n)
    el = np.arcsin(np.sin(lo) + (i + 0.5) / n * (np.sin(hi) - np.sin(lo)))
    az = i * GOLDEN_ANGLE
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)


def place_cameras(points: np.ndarray, n: int, *, elevation: tuple[float, float], fov_x_deg: float, width: int,
                  height: int, fill: float = 0.9) -> list[Camera]:
    """Cameras looking at the centre of ``points``' bounding box, each as close as it can be while every point
    projects inside the central ``fill`` fraction of the frame (both axes).

    Parameters
    ----------
    points : (m, 3) float, the plant's surface vertices
    """
    pts = check_shape("camera placement points", points, (-1, 3), "f")
    if not len(pts):
        raise InputError("cannot place cameras around an empty plant")
    target = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    rel = pts - target
    tan_x = fill * np.tan(np.radians(fov_x_deg) / 2)
    tan_y = tan_x * height / width
    cams = []
    for w in view_directions(n, elevation):
        axes = look_at(target + w, target, fov_x_deg=fov_x_deg, width=width, height=height).R
        x, y, z = rel @ axes[0], rel @ axes[1], rel @ axes[2]
        # a point at camera depth d + z must satisfy |x| <= tan_x (d + z) and |y| <= tan_y (d + z)
        d = max(float(np.max(np.abs(x) / tan_x - z)), float(np.max(np.abs(y) / tan_y - z)),
                float(np.max(-z)) + 1e-3)
        cams.append(look_at(target + d * w, target, fov_x_deg=fov_x_deg, width=width, height=height))
    return cams


def render_colour(scene, view: int, *, spp: int, seed: int, mi, guides=None) -> np.ndarray:
    """Path-trace view ``view`` of a loaded scene (its sensors in view order). With ``guides`` (the loaded
    :data:`plantbench.capture.scene.GUIDES_INTEGRATOR`: a denoising capture) the albedo and normal guides are rendered
    by it at the same sensor, samples and seed, and the colour is denoised with Intel Open Image Denoise (its RT
    filter, high quality, HDR input, the guides prefiltered by the filter).

    Returns
    -------
    (h, w, 3) float32 linear RGB
    """
    img = np.asarray(mi.render(scene, sensor=view, spp=spp, seed=seed), np.float32)[..., :3]
    if guides is None:
        return img
    import pyoidn

    aux = np.asarray(mi.render(scene, sensor=view, spp=spp, seed=seed, integrator=guides), np.float32)
    albedo, normal = (np.ascontiguousarray(aux[..., k:k + 3]) for k in (0, 3))
    return np.asarray(pyoidn.denoise(np.maximum(np.ascontiguousarray(img), 0.0), np.clip(albedo, 0.0, 1.0),
                                     np.clip(normal, -1.0, 1.0), hdr=True, quality="high"), np.float32)


def to_srgb8(linear: np.ndarray) -> np.ndarray:
    """Linear RGB to 8-bit sRGB (clipped), (h, w, 3) uint8."""
    x = np.clip(np.nan_to_num(linear, nan=0.0), 0.0, 1.0)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.round(s * 255).astype(np.uint8)


@dataclass(frozen=True)
class GroundTruthMesh:
    """Everything a pixel ray can hit, merged into one mesh.

    vertices : (n, 3) float; faces : (m, 3) int
    instance : (m,) int, per face: 0 ground, 1 wood, 2 + k leaf k
    """

    vertices: np.ndarray
    faces: np.ndarray
    instance: np.ndarray

    def face_normals(self) -> np.ndarray:
        a, b, c = (self.vertices[self.faces[:, i]] for i in range(3))
        n = np.cross(b - a, c - a)
        return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)


def ground_truth_parts(plant: Plant, *, ground: bool = True) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """[(vertices, faces, per-face instance)] for the branches (1), the leaves (2 + leaf id) and, when ``ground``,
    the ground square (0), in this order (the order of :func:`ground_truth_mesh`'s faces and of the casters)."""
    parts = [(plant.branch_mesh.vertices, plant.branch_mesh.faces, np.ones(len(plant.branch_mesh.faces), np.int64)),
             (plant.leaf_mesh.vertices, plant.leaf_mesh.faces, 2 + plant.leaf_mesh_ids)]
    if ground:
        gv, gf, _ = ground_triangles(plant)
        parts.append((gv, gf, np.zeros(2, np.int64)))
    return parts


def ground_truth_mesh(plant: Plant, *, ground: bool = True) -> GroundTruthMesh:
    """Branches (instance 1), leaves (2 + leaf id) and, when ``ground``, the ground square (0) as one mesh."""
    parts = ground_truth_parts(plant, ground=ground)
    offsets = np.cumsum([0] + [len(p[0]) for p in parts[:-1]])
    return GroundTruthMesh(np.concatenate([p[0] for p in parts]),
                           np.concatenate([p[1] + o for p, o in zip(parts, offsets)]),
                           np.concatenate([p[2] for p in parts]))


def ground_truth_caster(plant: Plant, *, scene=None, scene_dict: dict | None = None) -> RayCaster:
    """A :class:`RayCaster` over :func:`ground_truth_parts` (faces indexed as in :func:`ground_truth_mesh`).

    With the loaded render ``scene`` and the ``scene_dict`` it was loaded from (and the llvm variant), casting
    reuses the render scene's acceleration structure.
    """
    parts = [(v, f) for v, f, _ in ground_truth_parts(plant)]
    if scene is None or scene_dict is None:
        return RayCaster(parts)
    shapes = [scene_dict.get(k) if len(f) else None for k, (_, f) in zip(("branches", "leaves", "ground"), parts)]
    return RayCaster(parts, scene=scene, shapes=shapes)


@dataclass(frozen=True)
class ExactMaps:
    """Per-pixel ground truth of one view (rays through pixel centres, no anti-aliasing).

    depth : (h, w) float32, z-depth in metres (along the optical axis), inf where the ray hits nothing
    instance : (h, w) uint16, 0 ground or nothing, 1 wood, 2 + k leaf k
    normal : (h, w, 3) float32 or None, world-space unit normal of the hit face, facing the camera (0 on a miss)
    """

    depth: np.ndarray
    instance: np.ndarray
    normal: np.ndarray | None

    @property
    def foliage(self) -> np.ndarray:
        """(h, w) bool: pixels showing a leaf."""
        return self.instance >= 2


def exact_maps(camera: Camera, gt: GroundTruthMesh, caster: RayCaster, *, normals: bool = False) -> ExactMaps:
    """Cast one ray through every pixel centre of ``camera`` against ``gt`` (through ``caster``, whose face indices
    are ``gt``'s, e.g. :func:`ground_truth_caster`)."""
    origin, dirs = camera.pixel_rays()
    t, prim = caster.cast(origin, dirs)
    hit = prim >= 0
    h, w = camera.height, camera.width
    z = np.full(len(t), np.inf)
    z[hit] = t[hit] * (dirs[hit] @ camera.R[2])
    inst = np.zeros(len(t), np.uint16)
    inst[hit] = gt.instance[prim[hit]]
    normal = None
    if normals:
        fn = gt.face_normals()[prim[hit]]
        fn *= -np.sign(np.einsum("ij,ij->i", fn, dirs[hit]))[:, None]
        normal = np.zeros((len(t), 3), np.float32)
        normal[hit] = fn
        normal = normal.reshape(h, w, 3)
    return ExactMaps(z.astype(np.float32).reshape(h, w), inst.reshape(h, w), normal)
