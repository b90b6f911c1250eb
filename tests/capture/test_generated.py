"""Capture of a plant from plantbench.generate (integration): leaf frames give sensible atlas UVs and the cameras
put leaf centroids on their own leaf pixels."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from plantbench.cameras import read_cameras
from plantbench.capture import CaptureOptions, capture_case
from plantbench.io.plantio import read_plant

generate = pytest.importorskip("plantbench.generate")


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    case = tmp_path_factory.mktemp("generated") / "case"
    generate.generate_case("pentagon_maple", 0, case, scale=0.15)
    capture_case(case, CaptureOptions(views=3, width=128, height=128, spp=2, angular_step_deg=0.3,
                                      colmap_points=500), seed=0)
    return case


def test_leaf_frames_map_blades_into_their_tile(generated):
    from plantbench.capture.scene import LEAF_TILES, leaf_texcoords

    plant, _ = read_plant(generated)
    tiles = np.arange(len(plant.leaves)) % LEAF_TILES
    V, F, uv = leaf_texcoords(plant, tiles)
    # un-clipped blade coordinates span the tile: u over ~[0.03, 0.97] (base to tip) of the tile's width
    vleaf = np.full(len(V), -1)
    vleaf[F.ravel()] = np.repeat(plant.leaf_mesh_ids, 3)
    local_u = uv[:, 0] * LEAF_TILES - tiles[vleaf]
    assert np.all((local_u >= 0.03 - 1e-9) & (local_u <= 0.97 + 1e-9))
    assert np.ptp(local_u) > 0.9 and np.ptp(uv[:, 1]) > 0.8


def test_leaf_centroids_land_on_their_leaf(generated):
    plant, _ = read_plant(generated)
    cams, _ = read_cameras(generated / "views" / "cameras.json")
    pts = np.array([lf.centroid for lf in plant.leaves])
    ids = np.array([2 + lf.id for lf in plant.leaves])
    hits = checked = 0
    for i, cam in enumerate(cams):
        depth = np.load(generated / "views" / "depth" / f"{i:04d}.npy")
        inst = np.array(Image.open(generated / "views" / "instance" / f"{i:04d}.png"))
        uv, z = cam.project(pts)
        px = np.round(uv).astype(int)
        ok = (px[:, 0] >= 0) & (px[:, 1] >= 0) & (px[:, 0] < cam.width) & (px[:, 1] < cam.height) & (z > 0)
        k = np.flatnonzero(ok)
        d = depth[px[k, 1], px[k, 0]]
        vis = np.abs(d - z[k]) <= 0.3 * z[k] / cam.K[0, 0]
        checked += vis.sum()
        hits += (inst[px[k, 1], px[k, 0]][vis] == ids[k][vis]).sum()
    assert checked > 20
    assert hits / checked > 0.97  # curved blades: a centroid can sit a hair off its own (bent) surface
