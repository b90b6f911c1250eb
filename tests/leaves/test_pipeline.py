"""segment_and_fit end to end on synthetic captures with exact depth; bad input; the method's output files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from plantbench.cameras import read_cameras
from plantbench.errors import InputError
from plantbench.io.plantio import read_reconstruction
from reference_impl.leaves import LeafParams, Leaves, segment_and_fit, write_leaves

NOGROUND = LeafParams(ground=False)  # the synthetic scenes have no ground plane


def _centroids(leaves) -> np.ndarray:
    return np.array([tr[:3, :3] @ [length / 2, 0, 0] + tr[:3, 3] for _, length, tr in leaves])


def test_finds_each_leaf_once(leaf_scene):
    views, depths, _, truth = leaf_scene
    res = segment_and_fit(views, depths, leaf_length_hint=0.1, seed=0, params=NOGROUND)
    assert len(res.leaves) == len(truth)
    gt = _centroids(truth)
    d = np.linalg.norm(gt[:, None] - np.array([lf.centroid for lf in res.leaves])[None], axis=2)
    # each true leaf matched by exactly one fitted leaf within 1 cm (a tenth of its length)
    assert sorted(d.argmin(axis=0)) == list(range(len(truth)))
    assert d.min(axis=0).max() < 0.01
    for lf in res.leaves:
        assert 0.085 < lf.length < 0.115 and 0.03 < lf.width < 0.05
    assert res.skipped["duplicate"] > 0  # leaves seen in several views were de-duplicated
    assert 1 <= res.stats["fit_iterations_median"] <= 15


def test_leaf_size_is_estimated_without_a_hint(leaf_scene):
    views, depths, _, truth = leaf_scene
    res = segment_and_fit(views, depths, seed=0, params=NOGROUND)
    assert abs(res.stats["leaf_length"] - 0.1) < 0.025
    assert len(res.leaves) == len(truth)


def test_same_seed_same_leaves(leaf_scene):
    views, depths, _, _ = leaf_scene
    a = segment_and_fit(views, depths[:3] + [None] * 3, leaf_length_hint=0.1, seed=3, params=NOGROUND)
    b = segment_and_fit(views, depths[:3] + [None] * 3, leaf_length_hint=0.1, seed=3, params=NOGROUND)
    assert len(a.leaves) == len(b.leaves) > 0
    for x, y in zip(a.leaves, b.leaves, strict=True):
        np.testing.assert_array_equal(x.transform, y.transform)
        assert x.params == y.params


def test_views_without_depth_are_counted(leaf_scene):
    views, depths, _, _ = leaf_scene
    flat = [np.full_like(depths[0], np.inf)] + [None] * (len(depths) - 1)
    res = segment_and_fit(views, flat, leaf_length_hint=0.1, seed=0, params=NOGROUND)
    assert res.leaves == [] and res.skipped["view_without_depth"] == len(depths)


def test_bad_input(leaf_scene, tmp_path):
    views, depths, _, _ = leaf_scene
    with pytest.raises(InputError):
        segment_and_fit(views, seed=0)  # no depth source
    with pytest.raises(InputError):
        segment_and_fit(views, depths[:2], seed=0)  # wrong number of maps
    with pytest.raises(InputError):
        segment_and_fit(views, [d[:10] for d in depths], seed=0)  # wrong size
    with pytest.raises(InputError):
        segment_and_fit(tmp_path / "views" / "images", depths, seed=0)  # not a capture
    with pytest.raises(InputError):
        LeafParams(sigma=0)
    with pytest.raises(InputError):
        LeafParams.from_options({"no_such_option": 1})


def test_depth_dir_and_written_output(leaf_scene, tmp_path):
    views, depths, _, truth = leaf_scene
    ddir = tmp_path / "depth"
    ddir.mkdir()
    for i, d in enumerate(depths):
        np.savez_compressed(ddir / f"{i:04d}.npz", depth=d.astype(np.float32))
    res = segment_and_fit(views, depth_dir=ddir, leaf_length_hint=0.1, seed=0, params=NOGROUND)
    out = tmp_path / "out"
    write_leaves(out, res)
    rec = read_reconstruction(out)  # the harness's reader validates leaves.json against its schema
    assert len(rec.leaves) == len(res.leaves) == len(truth)
    np.testing.assert_allclose(rec.leaves[0].transform, res.leaves[0].transform)
    assert rec.points is not None and len(rec.points) > 0


def test_method_runs_alone_with_oracle_depth(leaf_scene, tmp_path):
    views, depths, _, truth = leaf_scene
    (views / "depth").mkdir()
    for i, d in enumerate(depths):
        np.save(views / "depth" / f"{i:04d}.npy", d.astype(np.float32))
    method = Leaves()
    assert method.name == "leaves" and method.inputs == "points"
    method.reconstruct(views.parent, tmp_path / "out", seed=0, depth="oracle", ground=False,
                       reference_leaf_length=0.1, delta_plane=0.02)
    rec = read_reconstruction(tmp_path / "out")
    assert rec.leaves is not None and len(rec.leaves) >= len(truth) - 1
    # each view's candidate map: labels on leaf pixels only, each candidate within one true leaf (a few boundary
    # pixels aside)
    from PIL import Image

    _, _, idmaps, _ = leaf_scene
    for i, ids in enumerate(idmaps):
        label = np.array(Image.open(tmp_path / "out" / "candidates" / f"{i:04d}.png"))
        assert label.dtype == np.uint16 and label.shape == ids.shape and label.max() > 0
        on = label > 0
        assert np.mean(ids[on] >= 0) > 0.98
        for k in np.unique(label[on]):
            owners = ids[label == k]
            assert np.mean(owners == np.bincount(owners[owners >= 0]).argmax()) > 0.9


def test_guo_takes_its_leaves_from_the_images(leaf_scene, tmp_path):
    """guo with leaves='segment': the leaf stage's fitted leaves (from capture_dir/depth, as the runner links the mvs
    stage's maps) become guo's leaves.json and the leaf part of its mesh, one per true leaf, on the true blades."""
    from scipy.spatial import cKDTree

    from plantbench.io.ply import write_points
    from reference_impl.guo import Guo
    from reference_impl.leaves.segment import backproject

    from .conftest import surface_samples

    views, depths, _, truth = leaf_scene
    cams, _ = read_cameras(views / "cameras.json")
    case = views.parent
    (case / "depth").mkdir()
    for i, d in enumerate(depths):
        np.savez_compressed(case / "depth" / f"{i:04d}.npz", depth=d.astype(np.float32))
    leaf_pts = np.concatenate([backproject(d, c)[0] for d, c in zip(depths, cams, strict=True)])
    stem = np.c_[np.zeros(400), np.zeros(400), np.linspace(-0.4, leaf_pts[:, 2].min(), 400)]
    write_points(case / "points.ply", np.concatenate([stem, leaf_pts[::5]]))
    Guo().reconstruct(case, tmp_path / "out", seed=0, leaves="segment", leaf__ground=False,
                      leaf__reference_leaf_length=0.1)
    rec = read_reconstruction(tmp_path / "out")
    assert len(rec.leaves) == len(truth)
    blades = np.concatenate([surface_samples(s.vector(), length, tr) for s, length, tr in truth])
    # the fitted blades are in the mesh: each truth blade sample has a mesh vertex within 1 cm (a tenth of a leaf)
    assert np.percentile(cKDTree(rec.mesh.vertices).query(blades)[0], 90) < 0.01
    assert all(0 <= lf.node < len(rec.skeleton.positions) for lf in rec.leaves)


def test_leaf_figure_draws_the_candidates_and_the_fitted_leaves(leaf_scene, tmp_path):
    """The report's leaf figure from a run folder whose leaves cell has candidate maps; none without them."""
    import json
    import shutil

    from PIL import Image

    from plantbench.report.report import leaf_figure

    views, depths, idmaps, _ = leaf_scene
    run = tmp_path / "run"
    cap = run / "cache" / "capture" / "c"
    shutil.copytree(views, cap / "views")
    (cap / "views" / "instance").mkdir()
    for i, ids in enumerate(idmaps):
        Image.fromarray(np.where(ids >= 0, ids + 2, 0).astype(np.uint16)).save(cap / "views" / "instance" / f"{i:04d}.png")
    (views / "depth").mkdir()
    for i, d in enumerate(depths):
        np.save(views / "depth" / f"{i:04d}.npy", d.astype(np.float32))
    out = run / "cache" / "method" / "m"
    Leaves().reconstruct(views.parent, out, seed=0, depth="oracle", ground=False, reference_leaf_length=0.1)
    cell = {"case": "c-1", "species": "c", "method": "leaves", "status": "ok", "sweep": None,
            "capture": "cache/capture/c", "recon": "cache/method/m"}
    (run / "cells.json").write_text(json.dumps([cell]))
    png = leaf_figure(run, tmp_path / "leaves.png")
    assert png is not None
    img = np.asarray(Image.open(png).convert("RGB")).astype(int)
    # four panels: the candidate and the fitted-leaf panels hold saturated colours (a grey image has none)
    sat = img.max(axis=2) - img.min(axis=2)
    assert img.shape[1] > 4 * 200 and (sat > 80).mean() > 0.01
    shutil.rmtree(out / "candidates")
    assert leaf_figure(run, tmp_path / "none.png") is None


def test_twig_is_not_a_leaf(tmp_path, rng):
    """Six leaves and a twig-like strip (a blade a fifth as wide, 12 cm long, among them): the strip is planar and
    segmented like a leaf, but its fitted blade is far narrower than the template, so it is skipped as
    not_leaf_shaped; with the check off it becomes a seventh leaf."""
    from PIL import Image

    from plantbench.cameras import write_cameras
    from plantbench.geometry.leaf import BezierLeaf

    from .conftest import FLAT, render_flat_leaves, ring_cameras, scattered_leaves, transform

    leaves = scattered_leaves(6, rng)
    strip = BezierLeaf(sil_v1=0.15, sil_v2=0.5, sil_v3=0.85, sil_x1=0.05, sil_x2=0.06, sil_x3=0.05)
    assert FLAT.sil_x2 / strip.sil_x2 == pytest.approx(5)
    rot = np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]])  # along +z (upright), blade facing +x
    twig = (strip, 0.12, transform(rot @ np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]), [0.0, 0.0, 0.05]))
    cams = ring_cameras(6, radius=0.55, height=0.45, size=240)
    views = tmp_path / "views"
    (views / "images").mkdir(parents=True)
    depths, names = [], []
    for i, cam in enumerate(cams):
        z, _, img = render_flat_leaves([*leaves, twig], cam, rng)
        names.append(f"{i:04d}.png")
        Image.fromarray(img).save(views / "images" / names[-1])
        depths.append(z)
    write_cameras(views / "cameras.json", cams, names)
    res = segment_and_fit(views, depths, leaf_length_hint=0.1, seed=0, params=NOGROUND)
    assert len(res.leaves) == len(leaves) and res.skipped["not_leaf_shaped"] >= 1
    gt = _centroids(leaves)
    got = np.array([lf.centroid for lf in res.leaves])
    assert np.linalg.norm(gt[:, None] - got[None], axis=2).min(axis=0).max() < 0.01  # the kept ones are the leaves
    off = segment_and_fit(views, depths, leaf_length_hint=0.1, seed=0,
                          params=LeafParams(ground=False, min_width_fraction=1e-6))
    assert len(off.leaves) == len(leaves) + 1 and off.skipped["not_leaf_shaped"] == 0


def test_speckles_smaller_than_the_fraction_of_a_leaf_lose_their_depth():
    """A 100 x 100 view, focal 100 px, at depth 2 m with a leaf 0.4 m long: 20 px long, so fraction 0.1 clears
    pieces under 40 px. A 7 x 7 block (49 px) stays, a 6 x 6 block (36 px) and a lone pixel go; pixels touching
    diagonally are one piece."""
    from plantbench.cameras import Camera
    from reference_impl.leaves.pipeline import _remove_speckles

    cam = Camera(K=np.array([[100.0, 0, 50], [0, 100, 50], [0, 0, 1]]), R=np.eye(3), t=np.zeros(3), width=100,
                 height=100)
    d = np.full((100, 100), np.nan)
    d[10:17, 10:17] = 2.0
    d[40:46, 40:46] = 2.0
    d[80, 80] = 2.0
    d[60:66, 60:66] = 2.0  # 36 px, joined diagonally to the 6 px below: 42 px, kept
    d[66:72, 66] = 2.0
    out, cleared = _remove_speckles([d, None], [cam, cam], 0.4, 0.1)
    assert out[1] is None and cleared == 36 + 1
    assert np.isfinite(out[0][10:17, 10:17]).all() and np.isfinite(out[0][60:66, 60:66]).all()
    assert np.isnan(out[0][40:46, 40:46]).all() and np.isnan(out[0][80, 80])


def test_a_fragment_lying_on_a_larger_fitted_blade_is_a_duplicate():
    from plantbench.geometry.leaf import BezierLeaf
    from plantbench.plant import Leaf
    from reference_impl.leaves.fit import LeafFit
    from reference_impl.leaves.pipeline import _drop_overlapping

    omega = BezierLeaf(sil_x1=0.25, sil_x2=0.3, sil_x3=0.12).vector()
    far = np.eye(4)
    far[:3, 3] = [1.0, 0.0, 0.0]
    big = LeafFit(omega, np.eye(4), 0.2, 0.06, 0.0, 3)
    other = LeafFit(omega, far, 0.2, 0.06, 0.0, 3)
    small = LeafFit(omega, np.eye(4), 0.06, 0.02, 0.0, 3)
    pts = big.surface(9, 17)
    frag = pts[(pts[:, 0] > 0.05) & (pts[:, 0] < 0.11)] + [0, 0, 0.005]  # on the big blade, 5 mm off
    leaves = [Leaf(i, -1, f.transform, {}, f.length, f.width) for i, f in enumerate((small, big, other))]
    skipped = {"duplicate": 0}
    kept, fits, _ = _drop_overlapping(leaves, [small, big, other], [frag, pts, other.surface(9, 17)], radius=0.01,
                                      fraction=0.8, skipped=skipped)
    assert skipped["duplicate"] == 1 and [f.length for f in fits] == [0.2, 0.2] and [lf.id for lf in kept] == [0, 1]
    skipped["duplicate"] = 0
    _drop_overlapping(leaves, [small, big, other], [frag + [0, 0, 0.02], pts, other.surface(9, 17)], radius=0.01,
                      fraction=0.8, skipped=skipped)
    assert skipped["duplicate"] == 0  # 2.5 cm above the blade: another leaf


def test_blades_longer_than_the_length_factor_are_not_leaves(leaf_scene):
    """The scene's leaves are 10 cm long: with the hint at 10 cm, a length limit of 1.5 leaf lengths keeps all six;
    at 0.5 (5 cm) each fitted blade is too long and skipped as not_leaf_shaped."""
    views, depths, _, truth = leaf_scene
    keep = segment_and_fit(views, depths, leaf_length_hint=0.1, seed=0,
                           params=LeafParams(ground=False, max_length_factor=1.5))
    assert len(keep.leaves) == len(truth) and keep.skipped["not_leaf_shaped"] == 0
    drop = segment_and_fit(views, depths, leaf_length_hint=0.1, seed=0,
                           params=LeafParams(ground=False, max_length_factor=0.5))
    assert len(drop.leaves) == 0 and drop.skipped["not_leaf_shaped"] >= len(truth)


def _flat_blades(rng, specs):
    """LeafFit, Leaf and a point set per (x0, x1, y0, y1, z): points on a flat rectangle of the plane z (2 mm grid
    with 0.5 mm noise off the plane)."""
    from plantbench.geometry.leaf import BezierLeaf
    from plantbench.plant import Leaf
    from reference_impl.leaves.fit import LeafFit

    omega = BezierLeaf(sil_x1=0.25, sil_x2=0.3, sil_x3=0.12).vector()
    fits, leaves, pts = [], [], []
    for i, (x0, x1, y0, y1, z) in enumerate(specs):
        xx, yy = np.meshgrid(np.arange(x0, x1, 0.002), np.arange(y0, y1, 0.002))
        p = np.stack([xx.ravel(), yy.ravel(), np.full(xx.size, z) + rng.normal(0, 0.0005, xx.size)], axis=1)
        tr = np.eye(4)
        tr[:3, 3] = [x0, (y0 + y1) / 2, z]
        fits.append(LeafFit(omega, tr, x1 - x0, y1 - y0, 0.0, 3))
        leaves.append(Leaf(i, -1, tr, {}, x1 - x0, y1 - y0))
        pts.append(p)
    return leaves, fits, pts


def test_a_piece_of_a_larger_blades_leaf_is_a_fragment(rng):
    """A blade in the plane of a larger one and touching it is a piece of the same leaf; a coplanar blade that does
    not touch it, or one touching it but tilted out of its plane, is another leaf."""
    from reference_impl.leaves.pipeline import _drop_fragments

    delta = 0.02  # pieces touch when some points are closer than 1 cm
    # 0: a leaf 20 cm long; 1: its tip, fitted apart (touching, coplanar); 2: a coplanar leaf 4 cm away (a gap);
    # 3: touching leaf 0's side but 3 cm higher at its far edge (tilted: not in the plane)
    leaves, fits, pts = _flat_blades(rng, [(0.0, 0.20, 0.0, 0.06, 0.0), (0.201, 0.26, 0.0, 0.06, 0.0),
                                           (0.0, 0.12, 0.10, 0.16, 0.0), (0.05, 0.15, -0.061, -0.001, 0.0)])
    tilt = pts[3]
    tilt[:, 2] = 0.5 * (-0.001 - tilt[:, 1])  # rises to 3 cm at y = -6.1 cm
    skipped = {"duplicate": 0}
    kept, kept_fits, kept_pts = _drop_fragments(leaves, fits, pts, delta=delta, leaf_length=0.2, fraction=0.95,
                                                skipped=skipped)
    assert skipped["duplicate"] == 1 and [lf.id for lf in kept] == [0, 1, 2]
    assert [f.length for f in kept_fits] == pytest.approx([0.2, 0.12, 0.1])  # the tip (6 cm) went
    # farther than a leaf length from the larger blade's centroid: not its piece
    skipped["duplicate"] = 0
    _drop_fragments(leaves, fits, pts, delta=delta, leaf_length=0.12, fraction=0.95, skipped=skipped)
    assert skipped["duplicate"] == 0


@pytest.mark.parametrize("counts", [[30, 40, 50_000, 60_000, 25, 21, 2_000, 90_000, 33], [5], [7, 7], [1, 2, 3, 4]])
def test_typical_blade_is_the_blade_of_the_median_point(counts):
    """min_point_fraction's reference: the size of the blade holding the median point (each point labelled with its
    blade's size), not the median blade, which the many small false blades of the first case would set."""
    from reference_impl.leaves.pipeline import _typical_points

    labels = np.sort(np.repeat(counts, counts))
    assert _typical_points(counts) == labels[(len(labels) + 1) // 2 - 1]
    if len(counts) > 5:
        assert _typical_points(counts) == 60_000 and np.median(counts) == 40


def test_few_views_and_few_points_filters(leaf_scene, tmp_path):
    """On the synthetic capture (six leaves, each seen by several of its six views) min_views = 2 keeps every leaf
    and min_views = 7 (more views than the capture has) none; min_point_fraction keeps blades of the typical size
    (the blade of the median point) and drops all but the largest when above 1; both are off by default."""
    views, depths, _, truth = leaf_scene
    base = segment_and_fit(views, depths, leaf_length_hint=0.1, seed=0, params=NOGROUND)
    assert base.skipped["few_views"] == 0 and LeafParams().min_views == 1 and LeafParams().min_point_fraction == 0
    two = segment_and_fit(views, depths, leaf_length_hint=0.1, seed=0, params=LeafParams(ground=False, min_views=2))
    assert len(two.leaves) == len(truth) and two.skipped["few_views"] == 0
    seven = segment_and_fit(views, depths, leaf_length_hint=0.1, seed=0,
                            params=LeafParams(ground=False, min_views=7))
    assert seven.leaves == [] and seven.skipped["few_views"] > 0
    half = segment_and_fit(views, depths, leaf_length_hint=0.1, seed=0,
                           params=LeafParams(ground=False, min_point_fraction=0.5))
    assert len(half.leaves) == len(truth)
    n = sorted(len(p) for p in base.points)
    typical = np.repeat(n, n)[(sum(n) + 1) // 2 - 1]  # the blade size of the median point
    big = segment_and_fit(views, depths, leaf_length_hint=0.1, seed=0,
                          params=LeafParams(ground=False, min_point_fraction=n[-1] / typical))
    assert [len(p) for p in big.points] == [n[-1]] * n.count(n[-1])
    write_leaves(tmp_path, big)  # the skip counts are plain integers (JSON)
    stats = json.loads((tmp_path / "leaves_stats.json").read_text())
    assert stats["skipped"]["few_points_after_icp"] == big.skipped["few_points_after_icp"] >= len(n) - n.count(n[-1])
    with pytest.raises(InputError, match="fragment_fraction"):
        LeafParams(fragment_fraction=1.5)
    with pytest.raises(InputError, match="min_views"):
        LeafParams(min_views=2.5)
