"""The registered ``mvs`` method end to end: bad input, oracle mode, estimated mode, options."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from plantbench.cameras import look_at, write_cameras
from plantbench.errors import InputError
from plantbench.io.plantio import read_reconstruction
from plantbench.io.ply import read_points
from plantbench.registry import methods
from reference_impl.mvs import MVSParams, synthetic
from reference_impl.mvs.oracle import add_depth_noise

from .conftest import analytic_distance


def _copy(case, tmp_path, name="c"):
    dst = tmp_path / name
    shutil.copytree(case, dst)
    return dst


def test_registered():
    m = methods.get("mvs")
    assert m.name == "mvs" and m.inputs == "views"


def test_one_view_is_an_error(case, tmp_path):
    c = _copy(case, tmp_path)
    doc = json.loads((c / "views" / "cameras.json").read_text())
    doc["cameras"] = doc["cameras"][:1]
    (c / "views" / "cameras.json").write_text(json.dumps(doc))
    with pytest.raises(InputError, match="at least 2 views"):
        methods.get("mvs").reconstruct(c, tmp_path / "out", seed=0)


def test_unreadable_image_is_an_error(case, tmp_path):
    c = _copy(case, tmp_path)
    (c / "views" / "images" / "0003.png").write_bytes(b"not a png at all")
    with pytest.raises(InputError, match="0003.png"):
        methods.get("mvs").reconstruct(c, tmp_path / "out", seed=0)


def test_views_without_overlap_are_an_error(case, tmp_path):
    c = _copy(case, tmp_path)
    names = [f"{i:04d}.png" for i in range(3)]
    cams = [look_at((0, 0, 1), t, fov_x_deg=40, width=128, height=128) for t in ((5, 0, 1), (0, 5, 1), (-5, 0.1, 1))]
    write_cameras(c / "views" / "cameras.json", cams, names)
    with pytest.raises(InputError, match="overlap|parallel|behind"):
        methods.get("mvs").reconstruct(c, tmp_path / "out", seed=0)


def test_unknown_option_is_an_error():
    with pytest.raises(InputError, match="unknown option"):
        MVSParams.from_options({"hypothesis": 3})
    with pytest.raises(InputError):
        MVSParams.from_options({"poses": "magic"})
    p = MVSParams.from_options({"points": 1000, "depth_params__hypotheses": 64, "ground__enabled": False})
    assert p.fusion.points == 1000 and p.depth_params.hypotheses == 64 and not p.ground.enabled


def test_noise_statistics(rng):
    depth = np.full((200, 300), 2.0, np.float32)
    depth[:10] = np.inf
    noisy = add_depth_noise(depth, 0.01, rng)
    diff = noisy[10:] - depth[10:]
    assert abs(diff.mean()) < 0.0005 and abs(diff.std() - 0.01) < 0.0005
    assert np.all(np.isinf(noisy[:10]))


def test_oracle_without_noise_lies_on_the_surface(case, tmp_path, scene):
    out = tmp_path / "oracle"
    methods.get("mvs").reconstruct(case, out, seed=0, depth="oracle", noise=0.0, points=10**7)
    pts, fields = read_points(out / "points.ply")
    assert {"nx", "ny", "nz", "red", "green", "blue"} <= set(fields)
    d = analytic_distance(scene, pts)
    assert np.max(d) < 1e-4  # float32 depth maps: exact up to rounding
    # plant only: the instance masks exclude the ground
    assert np.all(pts[:, 2] > 0.05)
    stats = json.loads((out / "mvs.json").read_text())
    assert stats["oracle"]["sigma_m"] == 0.0 and stats["points"] == len(pts)
    # known poses: the per-view depth maps are written for the leaf stage (depth only without write_depth)
    files = sorted((out / "depth").glob("*.npz"))
    assert len(files) == stats["views_used"] and not list((out / "depth").glob("*.tmp*"))
    with np.load(files[0]) as z:
        assert set(z.files) == {"depth"} and z["depth"].dtype == np.float32


def test_oracle_noise_is_a_fraction_of_plant_height(case, tmp_path, scene):
    out = tmp_path / "oracle_noisy"
    methods.get("mvs").reconstruct(case, out, seed=3, depth="oracle", noise=0.005, points=10**7)
    stats = json.loads((out / "mvs.json").read_text())
    height = synthetic.scene_height(scene)
    assert stats["oracle"]["sigma_m"] == pytest.approx(0.005 * height)
    pts, _ = read_points(out / "points.ply")
    d = analytic_distance(scene, pts, ground=False)
    # z-noise sigma moves points along the rays by sigma * |ray| >= sigma; the distance to the surface is that
    # displacement projected on the normal, so its RMS lies between ~0.3 and ~1.2 sigma for these views
    rms = np.sqrt(np.mean(d**2))
    assert 0.3 * stats["oracle"]["sigma_m"] < rms < 1.3 * stats["oracle"]["sigma_m"]


def test_estimated_cloud_is_accurate(case, tmp_path, scene):
    out = tmp_path / "est"
    # lighter than the defaults to keep the test fast: 64 planes, one PatchMatch iteration, 4 views per check
    methods.get("mvs").reconstruct(case, out, seed=0, points=20000, write_depth=True, depth_params__hypotheses=64,
                                   depth_params__pm_iterations=1, filter__consistency_views=4)
    rec = read_reconstruction(out)
    pts = rec.points
    assert 1000 < len(pts) <= 20000
    height = synthetic.scene_height(scene)
    d = analytic_distance(scene, pts)
    assert np.median(d) < 0.01 * height
    # the ground is removed: few points lie on z = 0
    assert np.mean(np.abs(pts[:, 2]) < 0.01 * height) < 0.05
    stats = json.loads((out / "mvs.json").read_text())
    assert stats["views_used"] == 16 and stats["points"] == len(pts)
    assert len(list((out / "depth").glob("*.npz"))) == 16
    with np.load(next((out / "depth").glob("*.npz"))) as z:
        assert {"depth", "raw_depth", "normal", "cost"} <= set(z.files)


def test_sfm_options_reach_their_group():
    p = MVSParams.from_options({"poses": "sfm", "sfm__guided_matching": False, "sfm__peak_threshold": 0.004})
    assert p.sfm.guided_matching is False and p.sfm.peak_threshold == 0.004 and p.sfm.domain_size_pooling
    with pytest.raises(InputError, match="sfm"):
        MVSParams.from_options({"sfm__no_such_option": 1})
