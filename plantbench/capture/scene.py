"""The Mitsuba scene of a capture: a plain dict built by a pure function of the plant, the cameras and the options.

Contents (docs/design.md, Capture):

- branches: one mesh with a bark material, brown with per-vertex colour noise (3D sinusoid noise evaluated at the
  vertices, so it needs no UV parameterisation of the tubes);
- leaves: one two-sided mesh; each leaf gets UVs in its own leaf frame (``Leaf.transform``: the blade axis along
  +x, the width along y) into one tile of a texture atlas, so every leaf shows a midrib and lateral veins, and the
  tiles differ in hue, saturation and brightness (per-leaf colour variation); the underside is paler;
- ground: a large square at z = 0 (1000 plant sizes) with a tiling soil/grass texture whose features span many
  scales, so stereo can match on it;
- light: a ``directional`` sun and a uniform blue ``constant`` sky. Mitsuba 3.9 has a ``sunsky`` emitter (Z-up,
  usable as is), but a capture with it rendered 2.5x slower (3.1 s vs 1.2-1.7 s per 256x256 16-spp view of a
  250k-triangle maple) for no difference that matters to reconstruction.

All textures are procedural bitmaps drawn from the ``numpy.random.Generator`` passed in, so the same seed gives the
same scene. :func:`scene_dict` returns the dict (with ``mi.Mesh`` objects built from numpy arrays, and one
``perspective`` sensor per camera, keys ``sensor_NNNN``); ``mi.load_dict`` loads it.
"""

from __future__ import annotations

import numpy as np

from plantbench.cameras import Camera
from plantbench.capture.raycast import mitsuba_mesh
from plantbench.capture.settings import CaptureOptions
from plantbench.errors import InputError
from plantbench.plant import Plant

__all__ = [
    "LEAF_TILES",
    "WHITE_RADIANCE",
    "periodic_noise",
    "ground_texture",
    "leaf_atlas",
    "bark_colors",
    "leaf_texcoords",
    "ground_extent",
    "sun_direction",
    "light_dicts",
    "plant_bounds",
    "ground_triangles",
    "mitsuba_to_world",
    "sensor_dict",
    "scene_dict",
]

LEAF_TILES = 24
"""Colour variants in the leaf atlas (each leaf draws one)."""

WHITE_RADIANCE = 0.85
"""Radiance of a white, upward-facing Lambertian plane under the sun and sky (linear RGB, before sRGB encoding)."""

SKY_FRACTION = 0.3
"""Share of that radiance that comes from the sky (the rest from the sun)."""

SUN_COLOUR = (1.0, 0.96, 0.90)
SKY_COLOUR = (0.75, 0.90, 1.25)


def light_dicts(sun_elevation_deg: float, sun_azimuth_deg: float) -> dict:
    """Sun and sky: a ``directional`` sun plus a uniform (``constant``) blue sky, scaled so that a white horizontal
    Lambertian plane has radiance :data:`WHITE_RADIANCE`, :data:`SKY_FRACTION` of it from the sky.

    (Mitsuba 3.9's ``sunsky`` emitter was measured 2.5x slower to render with on this plant scene, for a visual
    difference that does not matter to reconstruction: see the capture notes in the module docstring.)
    """
    sun = sun_direction(sun_elevation_deg, sun_azimuth_deg)
    sky = WHITE_RADIANCE * SKY_FRACTION  # a uniform sky of radiance L gives a white plane radiance L
    irradiance = np.pi * WHITE_RADIANCE * (1 - SKY_FRACTION) / sun[2]  # E cos(theta) / pi = sun's share
    return {
        "sun": {"type": "directional", "direction": (-sun).tolist(),
                "irradiance": {"type": "rgb", "value": (irradiance * np.array(SUN_COLOUR)).tolist()}},
        "sky": {"type": "constant", "radiance": {"type": "rgb", "value": (sky * np.array(SKY_COLOUR)).tolist()}},
    }


# ------------------------------------------------------------------------------------------------ textures


def periodic_noise(rng: np.random.Generator, size: int, beta: float = 2.0, min_freq: float = 1.0) -> np.ndarray:
    """Tileable fractal noise with a power-law spectrum (power ~ f^-beta), zero mean, unit variance.

    Returns
    -------
    (size, size) float
    """
    white = rng.standard_normal((size, size))
    fx = np.fft.fftfreq(size) * size
    f = np.hypot(fx[:, None], fx[None, :])
    with np.errstate(divide="ignore"):
        amp = np.where(f >= min_freq, f ** (-beta / 2), 0.0)
    img = np.real(np.fft.ifft2(np.fft.fft2(white) * amp))
    return (img - img.mean()) / (img.std() + 1e-12)


def ground_texture(rng: np.random.Generator, size: int = 512) -> np.ndarray:
    """Soil and grass albedo, linear RGB in (0, 1).

    Returns
    -------
    (size, size, 3) float32
    """
    patches = 1.0 / (1.0 + np.exp(-2.5 * periodic_noise(rng, size, beta=3.0, min_freq=2.0) + 2.0))  # dry grass
    detail = periodic_noise(rng, size, beta=1.2, min_freq=4.0)  # fine-grained texture for matching
    clods = periodic_noise(rng, size, beta=2.0, min_freq=8.0)
    soil = np.array([0.30, 0.22, 0.15])
    grass = np.array([0.27, 0.26, 0.12])
    base = soil * (1 - patches[..., None]) + grass * patches[..., None]
    shade = np.clip(1.0 + 0.28 * detail + 0.18 * clods, 0.35, 1.8)
    pebbles = (periodic_noise(rng, size, beta=0.5, min_freq=16.0) > 2.2)[..., None] * np.array([0.20, 0.19, 0.17])
    return np.clip(base * shade[..., None] + pebbles, 0.01, 0.9).astype(np.float32)


def _hsv_to_rgb(h: np.ndarray, s: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Vectorised HSV (h in [0, 1)) to RGB; returns (..., 3)."""
    i = np.floor(h * 6).astype(int) % 6
    f = h * 6 - np.floor(h * 6)
    p, q, t = v * (1 - s), v * (1 - f * s), v * (1 - (1 - f) * s)
    table = np.stack([np.stack(c, -1) for c in ((v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q))])
    return np.take_along_axis(np.moveaxis(table, 0, -2), i[..., None, None], axis=-2)[..., 0, :]


def leaf_atlas(rng: np.random.Generator, tiles: int = LEAF_TILES, tile_w: int = 128, tile_h: int = 64
               ) -> tuple[np.ndarray, np.ndarray]:
    """Leaf texture atlas: ``tiles`` tiles side by side along u, each a blade with midrib and lateral veins.

    In a tile, u runs from the leaf base (0) to the tip (1) and v across the blade (0.5 on the midrib). Tiles differ
    in hue (yellow-green to blue-green), saturation and brightness.

    Returns
    -------
    front, back : (tile_h, tiles * tile_w, 3) float32, linear albedo of the upper and (paler) lower side
    """
    hue = rng.uniform(0.20, 0.36, tiles)  # 72..130 degrees
    sat = rng.uniform(0.55, 0.88, tiles)
    val = rng.uniform(0.20, 0.40, tiles)
    base = _hsv_to_rgb(hue, sat, val)  # (tiles, 3)
    u = (np.arange(tile_w) + 0.5) / tile_w
    v = (np.arange(tile_h) + 0.5) / tile_h
    uu, vv = np.meshgrid(u, v)
    off = np.abs(vv - 0.5)
    midrib = np.exp(-((off / 0.025) ** 2)) * (1 - 0.7 * uu)
    lateral = np.exp(-((np.sin(np.pi * 9 * (uu - 1.3 * off)) / 0.18) ** 2)) * np.clip(1 - off / 0.5, 0, 1) * 0.6
    veins = np.clip(midrib + lateral, 0, 1)
    noise = np.stack([periodic_noise(rng, max(tile_w, tile_h), beta=1.5, min_freq=2.0)[:tile_h, :tile_w]
                      for _ in range(tiles)])
    shade = np.clip(1.0 + 0.12 * noise, 0.6, 1.4)[..., None]
    vein_col = np.array([0.42, 0.48, 0.16])
    tile_img = base[:, None, None, :] * shade * (1 - 0.6 * veins[None, ..., None]) + 0.6 * veins[None, ..., None] * (
        0.5 * base[:, None, None, :] + 0.5 * vein_col)
    front = np.concatenate(list(tile_img), axis=1)
    grey = front.mean(axis=-1, keepdims=True)
    back = 1.35 * (0.6 * front + 0.4 * grey) + 0.02
    return np.clip(front, 0.005, 0.9).astype(np.float32), np.clip(back, 0.005, 0.9).astype(np.float32)


def bark_colors(rng: np.random.Generator, vertices: np.ndarray, scale: float) -> np.ndarray:
    """Per-vertex bark albedo: brown, modulated by a sum of random 3D sinusoids (wavelengths ~1-30 % of ``scale``),
    stretched along z like bark furrows.

    Parameters
    ----------
    vertices : (n, 3) float
    scale : float, plant size (height), metres

    Returns
    -------
    (n, 3) float32
    """
    k = 24
    dirs = rng.standard_normal((k, 3))
    dirs[:, 2] *= 0.3  # slower variation along the (mostly vertical) branch axis
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    wavelength = scale * np.exp(rng.uniform(np.log(0.01), np.log(0.3), k))
    phase = rng.uniform(0, 2 * np.pi, k)
    amp = wavelength / wavelength.sum()
    n = np.sin(vertices @ (dirs.T * (2 * np.pi / wavelength)) + phase) @ amp
    n = n / (np.abs(n).max() + 1e-12)
    base = np.array([0.30, 0.19, 0.11])
    tint = np.array([0.9, 1.0, 1.15])  # darker furrows are slightly redder
    col = base * (1 + 0.45 * n[:, None]) * np.where(n[:, None] < 0, tint, 1.0)
    return np.clip(col, 0.02, 0.6).astype(np.float32)


def leaf_texcoords(plant: Plant, tile_of_leaf: np.ndarray, tiles: int = LEAF_TILES
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Leaf mesh with atlas UVs: each vertex is mapped into its leaf's frame (``Leaf.transform``), u = x / length
    and v = y / width + 0.5, then into the leaf's tile of the atlas. Vertices shared by several leaves are split
    (the mesh is un-indexed); leaves without a :class:`Leaf` record get the tile's centre.

    Parameters
    ----------
    tile_of_leaf : (k,) int, atlas tile of each leaf id (k > max leaf id)

    Returns
    -------
    vertices : (n, 3) float, faces : (m, 3) int, uv : (n, 2) float
    """
    V, F, ids = plant.leaf_mesh.vertices, plant.leaf_mesh.faces, plant.leaf_mesh_ids
    vleaf = np.full(len(V), -1, np.int64)
    vleaf[F.ravel()] = np.repeat(ids, 3)
    if len(F) and np.any(vleaf[F] != ids[:, None]):
        V, F, vleaf = V[F].reshape(-1, 3), np.arange(3 * len(F)).reshape(-1, 3), np.repeat(ids, 3)
    n_ids = int(max(ids.max(initial=-1), max((lf.id for lf in plant.leaves), default=-1))) + 1
    inv = np.zeros((n_ids, 4, 4))
    size = np.zeros((n_ids, 2))
    for leaf in plant.leaves:
        inv[leaf.id] = np.linalg.inv(np.asarray(leaf.transform, float))
        size[leaf.id] = (leaf.length, leaf.width)
    known = (vleaf >= 0) & (size[np.maximum(vleaf, 0), 0] > 0)
    uv = np.full((len(V), 2), 0.5)
    if known.any():
        lv = vleaf[known]
        local = np.einsum("nij,nj->ni", inv[lv], np.concatenate([V[known], np.ones((known.sum(), 1))], 1))
        uv[known, 0] = np.clip(local[:, 0] / size[lv, 0], 0, 1)
        uv[known, 1] = np.clip(local[:, 1] / size[lv, 1] + 0.5, 0, 1)
    tile = tile_of_leaf[np.maximum(vleaf, 0)] if len(tile_of_leaf) else np.zeros(len(V), int)
    atlas_uv = np.stack([(tile + 0.03 + 0.94 * uv[:, 0]) / tiles, 0.03 + 0.94 * uv[:, 1]], axis=1)
    return V, F, atlas_uv


# ------------------------------------------------------------------------------------------------ geometry helpers


def plant_bounds(plant: Plant) -> tuple[np.ndarray, np.ndarray]:
    """(3,) min and max corners of the plant's surfaces (skeleton when there are none)."""
    parts = [m.vertices for m in (plant.branch_mesh, plant.leaf_mesh) if len(m.vertices)]
    if not parts:
        parts = [plant.skeleton.positions]
    pts = np.concatenate(parts)
    if not len(pts):
        raise InputError("the plant has no geometry to capture")
    return pts.min(axis=0), pts.max(axis=0)


def ground_extent(plant: Plant) -> tuple[np.ndarray, float, float]:
    """Centre (3,), half-size and texture tile size (metres) of the ground square at z = 0.

    The square reaches 1000 plant sizes out, so that the sky (which is black below the horizon) meets the ground
    within a fraction of a pixel of the true horizon.
    """
    lo, hi = plant_bounds(plant)
    size = float(max(np.max(hi - lo), 0.05))
    centre = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, 0.0])
    return centre, 1000.0 * size, max(0.4 * size, 0.05)


def ground_triangles(plant: Plant) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ground square as 2 triangles: vertices (4, 3), faces (2, 3) and texture coordinates (4, 2).

    The UVs are world x, y (relative to the centre) in tiles; the bitmap repeats. They stay small near the plant,
    where float32 precision matters (a single [0, 1] UV square scaled by the repeat count would quantise the
    texture near the plant).
    """
    c, half, tile = ground_extent(plant)
    corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], float) * half
    v = np.concatenate([c[:2] + corners, np.zeros((4, 1))], axis=1)
    return v, np.array([[0, 1, 2], [0, 2, 3]]), corners / tile


def sun_direction(elevation_deg: float, azimuth_deg: float) -> np.ndarray:
    """(3,) unit vector towards the sun in the Z-up world."""
    el, az = np.radians(elevation_deg), np.radians(azimuth_deg)
    return np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


def mitsuba_to_world(camera: Camera) -> np.ndarray:
    """(4, 4) camera-to-world matrix of the Mitsuba ``perspective`` sensor that sees what ``camera`` sees.

    Mitsuba's camera looks down its local +Z with local +X to the image's left and +Y up; OpenCV's looks down +Z
    with +X right and +Y down. So Mitsuba's local frame is OpenCV's with x and y negated:
    ``to_world = [R^T diag(-1, -1, 1) | C]`` with C the camera centre. (tests/capture/test_views.py checks this by
    projecting Mitsuba's own pixel-centre rays through the OpenCV camera.)
    """
    m = np.eye(4)
    m[:3, :3] = camera.R.T @ np.diag([-1.0, -1.0, 1.0])
    m[:3, 3] = camera.center
    return m


def sensor_dict(mi, camera: Camera, *, spp: int, seed: int = 0) -> dict:
    """A Mitsuba ``perspective`` sensor dict equivalent to the OpenCV ``camera`` (square pixels).

    The horizontal field of view follows from fx and the width; the principal point offset from (cx, cy): Mitsuba
    puts the principal point at the film centre (OpenCV pixel (W - 1) / 2, (H - 1) / 2) shifted by
    ``principal_point_offset_x * W`` pixels (and y likewise, both measured in the image's u and v directions).
    """
    K, w, h = camera.K, camera.width, camera.height
    if not np.isclose(K[0, 0], K[1, 1], rtol=1e-9) or abs(K[0, 1]) > 1e-12:
        raise InputError("Mitsuba's perspective sensor needs square pixels and no skew (fx == fy, s == 0)")
    fov = float(np.degrees(2 * np.arctan(0.5 * w / K[0, 0])))
    return {
        "type": "perspective",
        "fov": fov,
        "fov_axis": "x",
        "principal_point_offset_x": float(((w - 1) / 2 - K[0, 2]) / w),
        "principal_point_offset_y": float(((h - 1) / 2 - K[1, 2]) / h),
        "near_clip": 1e-3,
        "far_clip": 1e5,
        "to_world": mi.ScalarTransform4f(mitsuba_to_world(camera).tolist()),
        "film": {"type": "hdrfilm", "width": int(w), "height": int(h), "rfilter": {"type": "box"},
                 "pixel_format": "rgb"},
        "sampler": {"type": "independent", "sample_count": int(spp), "seed": int(seed)},
    }


# ------------------------------------------------------------------------------------------------ the scene


AOV_CHANNELS = "albedo:albedo,nn:sh_normal"
"""The guide images rendered beside the colour when the capture denoises (channels 0-2 albedo, 3-5 normals)."""

GUIDES_INTEGRATOR = {"type": "aov", "aovs": AOV_CHANNELS}
"""Mitsuba's ``aov`` integrator alone (no nested integrator): the albedo and shading-normal guides Open Image Denoise
takes, rendered by a second ``mi.render`` of the same sensor at the same samples as the colour. Nesting the path
tracer inside it instead doubled the render (1024 px, 4 spp, one thread: 9.2 s a view against 4.3 s for the path
tracer and 0.46 s for the guides alone; docs/tuning/mvs.md, "Denoising")."""


def _integrator(options: CaptureOptions) -> dict:
    """The path tracer (the guides of a denoising capture are a separate render: :data:`GUIDES_INTEGRATOR`)."""
    return {"type": "path", "max_depth": int(options.max_depth)}


def scene_dict(plant: Plant, cameras: list[Camera], options: CaptureOptions, rng: np.random.Generator,
               *, mi=None) -> dict:
    """The Mitsuba scene dict of ``plant`` seen by ``cameras`` (sensors ``sensor_0000`` ...), ready for
    ``mi.load_dict``. Pure: the same plant, cameras, options and generator state give the same dict contents.

    ``mi`` is the mitsuba module with a variant set (default: :func:`plantbench.backend.load_mitsuba`).
    """
    if mi is None:
        from plantbench.backend import load_mitsuba

        mi = load_mitsuba()
    lo, hi = plant_bounds(plant)
    height = float(max(hi[2], 1e-3))
    ground_img = ground_texture(rng)
    front, back = leaf_atlas(rng)
    bark = bark_colors(rng, plant.branch_mesh.vertices, height)
    n_ids = int(max(plant.leaf_mesh_ids.max(initial=-1), max((lf.id for lf in plant.leaves), default=-1))) + 1
    tile_of_leaf = rng.integers(0, LEAF_TILES, max(n_ids, 0))

    d: dict = {
        "type": "scene",
        "integrator": _integrator(options),
        **light_dicts(options.sun_elevation_deg, options.sun_azimuth_deg),
    }
    gv, gf, guv = ground_triangles(plant)
    ground_bsdf = mi.load_dict({"type": "diffuse", "reflectance": {
        "type": "bitmap", "bitmap": mi.Bitmap(ground_img), "raw": True}})
    d["ground"] = mitsuba_mesh(mi, "ground", gv, gf, texcoords=guv, bsdf=ground_bsdf)
    if len(plant.branch_mesh.faces):
        bsdf = mi.load_dict({"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": {
            "type": "mesh_attribute", "name": "vertex_color"}}})
        d["branches"] = mitsuba_mesh(mi, "branches", plant.branch_mesh.vertices, plant.branch_mesh.faces,
                                     attributes={"vertex_color": bark}, bsdf=bsdf)
    if len(plant.leaf_mesh.faces):
        V, F, uv = leaf_texcoords(plant, tile_of_leaf)
        bsdf = mi.load_dict({"type": "twosided",
                             "front": {"type": "diffuse", "reflectance": {
                                 "type": "bitmap", "bitmap": mi.Bitmap(front), "raw": True}},
                             "back": {"type": "diffuse", "reflectance": {
                                 "type": "bitmap", "bitmap": mi.Bitmap(back), "raw": True}}})
        d["leaves"] = mitsuba_mesh(mi, "leaves", V, F, texcoords=uv, bsdf=bsdf)
    for i, cam in enumerate(cameras):
        d[f"sensor_{i:04d}"] = sensor_dict(mi, cam, spp=options.spp)
    return d
