"""Simulated laser scan: points lie on the visible surfaces with the right labels; noise, dropout, stations."""

from __future__ import annotations

import json

import numpy as np
import pytest

from plantbench.capture.scan import scan_plant, station_positions
from plantbench.capture.settings import CaptureOptions
from plantbench.io.ply import read_points
from tests.capture.conftest import SETTINGS, plant_distance
from tests.capture.plants import make_plant


@pytest.fixture(scope="module")
def plant():
    return make_plant(height=4.0)


def _o3d_first_hit(plant, origin, points):
    """Distance from ``origin`` to the first surface along the ray to each point (open3d, independent)."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    for m in (plant.branch_mesh, plant.leaf_mesh):
        scene.add_triangles(o3d.core.Tensor(m.vertices.astype(np.float32)), o3d.core.Tensor(m.faces.astype(np.uint32)))
    d = points - origin
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    rays = np.concatenate([np.broadcast_to(origin, d.shape), d], 1).astype(np.float32)
    return scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()


def test_noiseless_scan_points_are_first_hits_with_true_labels(plant):
    opts = CaptureOptions(stations=1, angular_step_deg=0.15, range_noise=0.0, dropout=0.0)
    scan = scan_plant(plant, opts, np.random.default_rng(0))
    assert len(scan.points) > 2000
    station = station_positions(plant, opts)[0]
    # on the surface, and the first surface seen from the station (occlusion is real)
    assert np.max(plant_distance(plant, scan.points)) < 1e-4
    t = _o3d_first_hit(plant, station, scan.points)
    assert np.percentile(np.abs(t - np.linalg.norm(scan.points - station, axis=1)), 99) < 1e-4
    # labels: leaf points lie on their own leaf, wood points on the branches
    leaf = scan.label == 1
    assert np.all(scan.leaf_id[~leaf] == -1) and np.all(scan.leaf_id[leaf] >= 0)
    assert 0.05 < leaf.mean() < 0.95
    from plantbench.plant import Plant, TriMesh

    for k in np.unique(scan.leaf_id[leaf])[:10]:
        sel = plant.leaf_mesh_ids == k
        one = Plant(plant.skeleton, TriMesh.empty(), TriMesh(plant.leaf_mesh.vertices, plant.leaf_mesh.faces[sel]),
                    np.full(sel.sum(), k))
        assert np.max(plant_distance(one, scan.points[scan.leaf_id == k])) < 1e-4
    wood = Plant(plant.skeleton, plant.branch_mesh, TriMesh.empty(), np.zeros(0, int))
    assert np.max(plant_distance(wood, scan.points[~leaf])) < 1e-4


def test_noise_and_dropout_statistics(plant):
    clean = scan_plant(plant, CaptureOptions(angular_step_deg=0.15, range_noise=0.0, dropout=0.1),
                       np.random.default_rng(3))
    noisy = scan_plant(plant, CaptureOptions(angular_step_deg=0.15, range_noise=0.004, dropout=0.1),
                       np.random.default_rng(3))
    rec = clean.stations[0]
    assert abs(rec["returns"] / rec["hits"] - 0.9) < 4 * np.sqrt(0.09 / rec["hits"])
    # same generator state: same beams survive; ranges differ by N(0, 0.004)
    assert len(clean.points) == len(noisy.points)
    st = np.array(rec["position"])
    dr = np.linalg.norm(noisy.points - st, axis=1) - np.linalg.norm(clean.points - st, axis=1)
    assert abs(dr.mean()) < 4 * 0.004 / np.sqrt(len(dr))
    assert 0.0037 < dr.std() < 0.0043


def test_stations_on_a_circle(plant):
    opts = CaptureOptions(stations=3, scan_distance=5.0, scanner_height=1.2, angular_step_deg=0.3)
    pos = station_positions(plant, opts)
    assert pos.shape == (3, 3) and np.allclose(pos[:, 2], 1.2)
    centre = pos[:, :2].mean(0)
    assert np.allclose(np.linalg.norm(pos[:, :2] - centre, axis=1), 5.0)
    scan = scan_plant(plant, opts, np.random.default_rng(0))
    assert set(np.unique(scan.station)) == {0, 1, 2}
    with pytest.raises(Exception, match="max_range|range"):
        CaptureOptions(max_range=-1)


def test_max_range_cuts_returns(plant):
    near = CaptureOptions(angular_step_deg=0.2, scan_distance=5.0, max_range=5.0, range_noise=0.0, dropout=0.0)
    scan = scan_plant(plant, near, np.random.default_rng(0))
    st = station_positions(plant, near)[0]
    assert len(scan.points) > 0 and np.linalg.norm(scan.points - st, axis=1).max() <= 5.0 + 1e-5


def test_scan_files(captured):
    case, _ = captured
    pts, fields = read_points(case / "scan" / "scan.ply")
    assert set(fields) == {"label", "leaf_id", "station"}
    doc = json.loads((case / "scan" / "stations.json").read_text())
    assert len(doc["stations"]) == SETTINGS.stations == len(np.unique(fields["station"]))
    assert doc["points"] == len(pts) and doc["angular_step_deg"] == SETTINGS.angular_step_deg


def test_too_fine_a_step_is_refused(plant):
    from plantbench.errors import InputError

    with pytest.raises(InputError, match="angular_step_deg"):
        scan_plant(plant, CaptureOptions(angular_step_deg=0.002, scan_distance=1.0), np.random.default_rng(0))
