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


def test_scan_spacing_sets_the_angular_step_and_the_median_spacing(plant):
    """The beam spacing comes from the angular step at the station distance (not thinning): step = spacing / d, and
    the cloud's median nearest-neighbour spacing lands near the spacing asked for (a flat surface facing the
    scanner would give it exactly; inclination widens it, overlapping stations narrow it)."""
    from plantbench.capture.scan import median_spacing, station_distance

    for spacing in (0.02, 0.05):
        opts = CaptureOptions(stations=3, scan_spacing=spacing, range_noise=0.0, dropout=0.0)
        scan = scan_plant(plant, opts, np.random.default_rng(0))
        d = station_distance(plant, opts)
        assert np.isclose(np.radians(scan.stations[0]["angular_step_deg"]), spacing / d)
        assert 0.7 * spacing < median_spacing(scan.points) < 1.4 * spacing
    # a denser scan holds about (ratio of spacings)^2 times the points
    n = [len(scan_plant(plant, CaptureOptions(scan_spacing=s, range_noise=0.0, dropout=0.0),
                        np.random.default_rng(0)).points) for s in (0.02, 0.04)]
    assert 3.0 < n[0] / n[1] < 5.0


def test_range_noise_grows_with_distance(plant):
    """sigma(r) = range_noise + range_noise_per_m * r, checked on the range residuals of a noiseless twin scan."""
    base = dict(angular_step_deg=0.15, dropout=0.0, scan_distance=6.0)
    clean = scan_plant(plant, CaptureOptions(**base, range_noise=0.0), np.random.default_rng(5))
    noisy = scan_plant(plant, CaptureOptions(**base, range_noise=0.001, range_noise_per_m=0.002),
                       np.random.default_rng(5))
    st = np.array(clean.stations[0]["position"])
    r = np.linalg.norm(clean.points - st, axis=1)
    dr = np.linalg.norm(noisy.points - st, axis=1) - r
    z = dr / (0.001 + 0.002 * r)
    assert abs(z.std() - 1.0) < 0.03 and abs(z.mean()) < 4 / np.sqrt(len(z))


def test_registration_error_moves_each_later_station_rigidly(plant):
    """Station 0 stays; every other station's points move by one rigid transform whose RMS displacement is of the
    order asked for; the misregistration is recorded (ground truth) and moves the station's position with it."""
    from plantbench.seeding import rng

    base = dict(stations=3, angular_step_deg=0.2, range_noise=0.0, dropout=0.0)
    exact = scan_plant(plant, CaptureOptions(**base), np.random.default_rng(1))
    rms = []
    for seed in range(8):
        moved = scan_plant(plant, CaptureOptions(**base, registration_error=0.01), np.random.default_rng(1),
                           registration_rng=rng(seed, "registration"))
        assert np.array_equal(moved.points[moved.station == 0], exact.points[exact.station == 0])
        assert "misregistration" not in moved.stations[0]
        for k in (1, 2):
            a, b = exact.points[exact.station == k], moved.points[moved.station == k]
            # rigid: pairwise distances kept, and a least-squares rigid fit (Kabsch, independent) explains it exactly
            ca, cb = a.mean(0), b.mean(0)
            u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
            r = (u @ np.diag([1, 1, np.sign(np.linalg.det(u @ vt))]) @ vt).T
            assert np.max(np.abs((a - ca) @ r.T + cb - b)) < 1e-9
            rec = moved.stations[k]["misregistration"]
            assert np.isclose(rec["rms"], np.sqrt(np.mean(np.sum((b - a) ** 2, axis=1))))
            assert np.allclose(moved.stations[k]["position"],
                               np.array(rec["true_position"]) @ np.array(rec["rotation"]).T + rec["offset"])
            rms.append(rec["rms"])
    assert 0.005 < np.sqrt(np.mean(np.square(rms))) < 0.02  # an RMS of ~1 cm over 16 draws


def test_registration_truth_stays_out_of_a_methods_input(tmp_path):
    """scan/registration.json is ground truth: written by the capture, not copied into a points or scan input."""
    from plantbench.capture import capture_case
    from plantbench.methods.inputs import prepare_inputs
    from tests.capture.plants import write_test_plant

    case = tmp_path / "case"
    write_test_plant(case, height=2.0)
    capture_case(case, {"views": 1, "width": 32, "height": 32, "spp": 1, "stations": 2, "scan_spacing": 0.05,
                        "registration_error": 0.01}, seed=1)
    doc = json.loads((case / "scan" / "registration.json").read_text())
    assert set(doc["stations"]) == {"1"} and doc["registration_error"] == 0.01
    stations = json.loads((case / "scan" / "stations.json").read_text())
    assert "misregistration" not in json.dumps(stations) and stations["scan_spacing"] == 0.05
    assert 0.03 < stations["median_spacing"] < 0.08
    dest = prepare_inputs(tmp_path / "in", case, "scan")
    assert sorted(p.name for p in (dest / "scan").iterdir()) == ["scan.ply", "stations.json"]
