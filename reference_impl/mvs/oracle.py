"""Oracle depth: the capture's exact depth maps plus noise, to separate stereo error from modelling error.

Being an explicitly named oracle, this mode reads ground truth: ``views/depth/NNNN.npy`` (z-depth, inf for sky),
``views/instance/NNNN.png`` (0 ground/sky: the oracle segments the plant exactly) and ``plant/plant.json`` (the
plant height that scales the noise).

Noise model: z' = z + N(0, sigma^2) independently per pixel, with ``sigma = noise x plant height``, so
``noise = 0.005`` is 0.5 % of the plant's height whatever its size (the noise-sweep suite's parameter). Normals
are computed from the noisy depth map (cross product of central differences of the back-projected points).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from plantbench.cameras import Camera
from plantbench.errors import InputError

__all__ = ["oracle_depths", "add_depth_noise", "normals_from_depth"]


def add_depth_noise(depth: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """``depth`` + N(0, sigma^2) on finite pixels (non-finite pixels unchanged), float32."""
    d = np.asarray(depth, np.float64)
    noisy = d + rng.normal(0.0, sigma, d.shape) if sigma > 0 else d.copy()
    return np.where(np.isfinite(d), noisy, d).astype(np.float32)


def normals_from_depth(depth: np.ndarray, cam: Camera) -> np.ndarray:
    """(h, w, 3) world unit normals facing the camera from a z-depth map (NaN where undefined)."""
    h, w = depth.shape
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(cam.K).T
    d = np.where(np.isfinite(depth), depth, np.nan).astype(np.float64)
    X = rays * d[..., None]
    dx = np.full_like(X, np.nan)
    dy = np.full_like(X, np.nan)
    dx[:, 1:-1] = X[:, 2:] - X[:, :-2]
    dy[1:-1] = X[2:] - X[:-2]
    n = np.cross(dx, dy)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    flip = np.einsum("hwc,hwc->hw", n, X) > 0
    n[flip] *= -1
    return (n.reshape(-1, 3) @ cam.R).reshape(h, w, 3).astype(np.float32)


def oracle_depths(
    capture_dir: str | Path, names: list[str], cameras: list[Camera], noise: float, rng: np.random.Generator
) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray], float]:
    """Noisy ground-truth depth, normals and plant masks of every view.

    Returns
    -------
    depths : list of (h, w) float32, NaN off the plant
    normals : list of (h, w, 3) float32 world normals
    masks : list of (h, w) bool, plant pixels (instance > 0)
    sigma : the noise standard deviation used, metres
    """
    from PIL import Image

    from plantbench.schemas import PlantJson, load_json

    case = Path(capture_dir)
    plant_json = load_json(case / "plant" / "plant.json", PlantJson)
    sigma = float(noise) * float(plant_json.height)
    depths, normals, masks = [], [], []
    for name, cam in zip(names, cameras, strict=True):
        stem = Path(name).stem
        dpath = case / "views" / "depth" / f"{stem}.npy"
        ipath = case / "views" / "instance" / f"{stem}.png"
        if not dpath.is_file() or not ipath.is_file():
            raise InputError("oracle depth needs the ground-truth depth and instance maps", path=dpath)
        depth = np.load(dpath)
        inst = np.asarray(Image.open(ipath))
        if depth.shape != (cam.height, cam.width) or inst.shape != depth.shape:
            raise InputError(f"depth/instance map shape {depth.shape} / {inst.shape} differs from the camera's",
                             path=dpath)
        mask = (inst > 0) & np.isfinite(depth)
        noisy = add_depth_noise(np.where(mask, depth, np.nan), sigma, rng)
        depths.append(noisy)
        normals.append(normals_from_depth(noisy, cam))
        masks.append(mask)
    return depths, normals, masks, sigma
