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


def test_max_size_matches_at_a_reduced_size_and_writes_depth_at_the_views_size(case, tmp_path, scene):
    """max_size 96 on 128 px views: depth estimated on area-downscaled views whose scaled cameras project the scene
    where the downscaled image shows it (the cloud stays on the analytic surfaces), the depth maps written at 128 px."""
    from reference_impl.mvs.method import downscale_views, load_views

    images, cameras, _ = load_views(case)
    small, cams, s = downscale_views(images, cameras, 96)
    assert s == 0.75 and small[0].shape == (96, 96, 3) and (cams[0].width, cams[0].height) == (96, 96)
    # a point projects to s (u + 0.5) - 0.5 in the downscaled view
    x = np.array([0.1, -0.2, 0.5])
    uv = lambda c: (c.K @ (c.R @ x + c.t))[:2] / (c.K @ (c.R @ x + c.t))[2]  # noqa: E731
    assert np.allclose(uv(cams[0]), 0.75 * (uv(cameras[0]) + 0.5) - 0.5)
    assert downscale_views(images, cameras, 128)[1][0] is cameras[0]  # small enough: unchanged
    out = tmp_path / "small"
    methods.get("mvs").reconstruct(case, out, seed=0, points=20000, max_size=96, depth_params__hypotheses=64,
                                   depth_params__pm_iterations=1, filter__consistency_views=4)
    pts = read_reconstruction(out).points
    assert len(pts) > 500 and np.median(analytic_distance(scene, pts)) < 0.015 * synthetic.scene_height(scene)
    stats = json.loads((out / "mvs.json").read_text())
    assert stats["working_scale"] == 0.75
    with np.load(next((out / "depth").glob("*.npz"))) as z:
        assert z["depth"].shape == (128, 128)
    with pytest.raises(InputError, match="max_size"):
        MVSParams(max_size=10)
    assert MVSParams().max_size == 1024 and MVSParams(max_size=0).max_size == 0


def test_sfm_options_reach_their_group():
    p = MVSParams.from_options({"poses": "sfm", "sfm__guided_matching": False, "sfm__peak_threshold": 0.004})
    assert p.sfm.guided_matching is False and p.sfm.peak_threshold == 0.004 and p.sfm.domain_size_pooling
    with pytest.raises(InputError, match="sfm"):
        MVSParams.from_options({"sfm__no_such_option": 1})


def test_plant_points_keep_leaves_when_the_budget_barely_binds():
    """The floater test links points within max(3 voxels, 1 % of the scene scale): when the pre-ground budget is
    only just exceeded, the voxels are tiny, and 3 voxels alone cut every leaf off its branch and dropped it."""
    from reference_impl.mvs.method import plant_points

    rng = np.random.default_rng(5)
    ground = np.column_stack([rng.uniform(-2, 2, (60000, 2)), rng.normal(0, 0.002, 60000)])
    trunk = np.column_stack([rng.normal(0, 0.003, (3000, 2)), rng.uniform(0.05, 2.0, 3000)])
    # 40 leaves of 40 points (~1 cm across), their centres 3.5 cm from the trunk's axis and 4 cm apart in height,
    # alternating sides: each is linked to the trunk at 5 cm (1 % of a 5 m scene), none at a few millimetres
    z = 0.3 + 0.04 * np.arange(40)
    side = np.where(np.arange(40) % 2 == 0, 1.0, -1.0)
    centres = np.column_stack([0.035 * side, np.zeros(40), z])
    leaves = (centres[:, None, :] + rng.normal(0, 0.003, (40, 40, 3))).reshape(-1, 3)
    pts = np.vstack([ground, trunk, leaves])
    col = np.vstack([np.tile([120, 100, 80], (len(ground), 1)), np.tile([90, 60, 40], (len(trunk), 1)),
                     np.tile([40, 140, 40], (len(leaves), 1))]).astype(np.uint8)
    nrm = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    params = MVSParams.from_options({"points": int(len(pts) / 4 / 1.05)})  # pre-ground budget 5 % short
    out, _, _, _, plane, n_down = plant_points(pts, nrm, col, scale=5.0, params=params, remove_ground=True, seed=0)
    assert n_down <= 4 * params.fusion.points < len(pts)  # the first downsampling bound (by a few %)
    assert plane is not None and abs(plane.normal[2]) > 0.99
    nearest = np.linalg.norm(centres[:, None, :] - out[None], axis=2).min(1)
    assert np.all(nearest < 0.01)  # every leaf survives
    assert np.mean(out[:, 2] < 0.02) < 0.01  # the ground is gone


def test_geometric_pass_runs_over_every_view(scene):
    """depth_maps with the geometric-consistency pass on an 8-view ring of the analytic scene: every view is refined
    after all photometric maps exist, the raw planes are released afterwards (with the pass off too), and the share
    of pixels within 1 % of the exact depth rises."""
    from reference_impl.mvs.method import depth_maps

    ring = synthetic.ring_cameras(8, width=96, height=96, radius=2.6)
    rendered = [synthetic.render(scene, c, supersample=1) for c in ring]
    images = [r[0] for r in rendered]
    share = {}
    for g in (0, 1):
        p = MVSParams.from_options({"depth_params__geometric_iterations": g, "depth_params__propagation": "adaptive"})
        maps, _, _ = depth_maps(images, ring, p, seed=0)
        assert all(m.planes is None for m in maps)
        share[g] = np.mean([np.mean(np.abs(m.depth - r[1])[np.isfinite(r[1])] < 0.01 * r[1][np.isfinite(r[1])])
                            for m, r in zip(maps, rendered, strict=True)])
    assert share[1] > share[0] > 0.25, share  # measured 0.32 -> 0.35
