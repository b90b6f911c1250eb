"""Denoised renders against a high-spp reference, on the plant's pixels (issue 49's capture question).

usage: python scripts/denoise_study.py CASE_DIR OUT.csv [--size 512] [--view 0] [--reference-spp 256]
       [--settings 4:0,16:0,4:1,16:1]  (spp:denoise pairs)

Renders one view of the case's plant (the capture's own scene, cameras and lighting: plantbench.capture) at each
setting and at ``--reference-spp`` without denoising, and writes one row per setting: seconds for the render (and the
denoiser), the RMS error against the reference over the plant's pixels (wood and leaves, from the exact instance map)
in 8-bit sRGB levels, the same over the wood pixels alone, and the thin-branch contrast: over the wood pixels that
touch a non-plant pixel (the edges of every branch, all of a branch one or two pixels wide), the mean absolute
difference between the pixel and the mean of its non-plant 3 x 3 neighbours, as a share of the reference's (1: the
branch stands out from what is behind it as much as in the reference; a denoiser that blurs a twig into the ground
gives less). Beside OUT.csv, OUT_SIZE.png shows the same 96 x 96 px crop (where the branch edges are densest) of
the reference and of each setting.
"""

from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import numpy as np
from scipy.ndimage import uniform_filter

from plantbench.backend import load_mitsuba
from plantbench.capture import views as cv
from plantbench.capture.scene import GUIDES_INTEGRATOR, scene_dict
from plantbench.capture.settings import CaptureOptions
from plantbench.io.plantio import read_plant
from plantbench.seeding import rng


def edge_contrast(img: np.ndarray, wood: np.ndarray, plant: np.ndarray) -> tuple[float, np.ndarray]:
    """Mean |pixel - mean of its non-plant 3 x 3 neighbours| over the wood pixels with such a neighbour, and those
    pixels' mask. img : (h, w, 3) float."""
    back = (~plant).astype(np.float64)
    nb = uniform_filter(back, 3, mode="constant") * 9.0
    edge = wood & (nb > 0)
    if not edge.any():
        return float("nan"), edge
    grey = img.astype(np.float64).mean(axis=2)
    mean_back = uniform_filter(grey * back, 3, mode="constant") * 9.0 / np.maximum(nb, 1.0)
    return float(np.mean(np.abs(grey - mean_back)[edge])), edge


def save_crops(path: Path, images: list[np.ndarray], settings: list[tuple[int, bool]], edge: np.ndarray,
               size: int = 96) -> None:
    """One row: the crop of each image where the edge mask is densest."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    dens = uniform_filter(edge.astype(np.float64), size)
    y, x = np.unravel_index(np.argmax(dens), dens.shape)
    y0 = int(np.clip(y - size // 2, 0, edge.shape[0] - size))
    x0 = int(np.clip(x - size // 2, 0, edge.shape[1] - size))
    fig, axs = plt.subplots(1, len(images), figsize=(2.2 * len(images), 2.5))
    for k, (ax, img, (spp, den)) in enumerate(zip(axs, images, settings, strict=True)):
        ax.imshow(img[y0:y0 + size, x0:x0 + size].astype(np.uint8), interpolation="nearest")
        ax.set_title(("reference " if k == 0 else "") + f"{spp} spp" + (" denoised" if den else ""), fontsize=8)
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("case", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--view", type=int, default=0)
    ap.add_argument("--views", type=int, default=20, help="views of the capture the view is taken from")
    ap.add_argument("--reference-spp", type=int, default=256)
    ap.add_argument("--settings", default="4:0,16:0,4:1,16:1")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    mi = load_mitsuba()
    plant, _ = read_plant(a.case)
    surface = np.concatenate([plant.branch_mesh.vertices, plant.leaf_mesh.vertices])
    settings = [(a.reference_spp, False)] + [(int(s), d == "1") for s, d in (x.split(":") for x in a.settings.split(","))]
    o = CaptureOptions(views=a.views, width=a.size, height=a.size, scan=False)
    cams = cv.place_cameras(surface, o.views, elevation=o.elevation, fov_x_deg=o.fov_deg, width=o.width,
                         height=o.height, fill=o.fill)
    # one scene for every setting: the render takes its spp, and a denoised setting renders the guides beside it
    d = scene_dict(plant, cams, o, rng(a.seed, "capture", "scene"), mi=mi)
    scene = mi.load_dict(d)
    guides = mi.load_dict(GUIDES_INTEGRATOR)
    maps = cv.exact_maps(cams[a.view], cv.ground_truth_mesh(plant), cv.ground_truth_caster(plant, scene=scene,
                                                                                         scene_dict=d))
    images, seconds = [], []
    for spp, denoise in settings:
        t0 = time.perf_counter()
        img = cv.to_srgb8(cv.render_colour(scene, a.view, spp=spp, seed=a.seed + a.view, mi=mi,
                                            guides=guides if denoise else None))
        seconds.append(time.perf_counter() - t0)
        images.append(img.astype(np.float64))
        print(f"{spp} spp{' denoised' if denoise else ''}: {seconds[-1]:.1f} s", flush=True)
    plant_px = maps.instance >= 1
    wood = maps.instance == 1
    ref = images[0]
    c_ref, edge = edge_contrast(ref, wood, plant_px)
    rows = []
    for (spp, denoise), img, sec in zip(settings, images, seconds, strict=True):
        err = img - ref
        c, _ = edge_contrast(img, wood, plant_px)
        rows.append({"size": a.size, "spp": spp, "denoise": int(denoise), "seconds": round(sec, 2),
                     "rmse_plant": float(np.sqrt(np.mean(err[plant_px] ** 2))),
                     "rmse_wood": float(np.sqrt(np.mean(err[wood] ** 2))),
                     "rmse_wood_edges": float(np.sqrt(np.mean(err[edge] ** 2))),
                     "edge_contrast_rel": c / c_ref, "plant_px": int(plant_px.sum()), "wood_edge_px": int(edge.sum())})
    a.out.parent.mkdir(parents=True, exist_ok=True)
    save_crops(a.out.with_name(f"{a.out.stem}_{a.size}.png"), images, settings, edge)
    new = not a.out.exists()
    with open(a.out, "a", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        if new:
            w.writeheader()
        w.writerows(rows[1:])
    for r in rows[1:]:
        print(r)


if __name__ == "__main__":
    main()
