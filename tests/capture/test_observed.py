"""Observed wood (plantbench.capture.observed) against analytic cases: a vertical cylinder seen by pinhole cameras
whose exact depth and instance maps are ray-cast here in closed form, and a scan that returns from half of it."""

import numpy as np
import pytest

from plantbench.cameras import look_at
from plantbench.capture import observed as ob
from plantbench.metrics.skeleton import skeleton_prf, skeleton_samples
from plantbench.plant import Skeleton

R, H = 0.1, 1.0  # cylinder radius and length (metres), axis on z from 0 to H


def _cylinder(n: int = 11) -> Skeleton:
    z = np.linspace(0.0, H, n)
    pos = np.stack([np.zeros(n), np.zeros(n), z], 1)
    return Skeleton(pos, np.full(n, R), np.arange(-1, n - 1), np.zeros(n, np.int64))


def _maps(cam, *, leaf_below: float | None = None):
    """Exact z-depth and instance maps of the cylinder (ray-cylinder intersection per pixel centre); with
    ``leaf_below``, a leaf plane (instance 2) half-way to the camera hides every pixel whose ray meets the cylinder
    below that height."""
    v, u = np.mgrid[0:cam.height, 0:cam.width]
    pix = np.stack([u.ravel(), v.ravel(), np.ones(u.size)], 1).astype(float)
    d_cam = pix @ np.linalg.inv(cam.K).T  # z = 1 in camera coordinates
    d = d_cam @ cam.R  # world direction with camera z = 1
    c = cam.center
    a = d[:, 0] ** 2 + d[:, 1] ** 2
    b = 2 * (c[0] * d[:, 0] + c[1] * d[:, 1])
    cc = c[0] ** 2 + c[1] ** 2 - R**2
    disc = b**2 - 4 * a * cc
    with np.errstate(invalid="ignore", divide="ignore"):
        s = (-b - np.sqrt(disc)) / (2 * a)  # nearest hit, s = z-depth since the camera z of d is 1
    zhit = c[2] + s * d[:, 2]
    hit = (disc >= 0) & (s > 0) & (zhit >= 0) & (zhit <= H)
    depth = np.where(hit, s, np.inf)
    inst = hit.astype(np.uint16)
    if leaf_below is not None:
        hide = hit & (zhit < leaf_below)
        depth = np.where(hide, 0.5 * s, depth)
        inst = np.where(hide, np.uint16(2), inst)
    return depth.reshape(cam.height, cam.width), inst.reshape(cam.height, cam.width)


def _camera(azimuth_deg: float, distance: float = 2.0, width: int = 400):
    a = np.radians(azimuth_deg)
    eye = np.array([distance * np.cos(a), distance * np.sin(a), 0.5 * H])
    return look_at(eye, [0.0, 0.0, 0.5 * H], fov_x_deg=50.0, width=width, height=width)


def test_one_view_sees_the_arc_in_front_of_it():
    """From a camera at distance D, the bark visible is the arc cos(theta) > R / D: a share acos(R / D) / pi (at
    1600 px, where the silhouette's pixels, whose centres miss the bark, are a small part of the arc)."""
    sk = _cylinder()
    cam = _camera(0.0, width=1600)
    samples = ob.wood_samples(sk, step=0.01, around=128)
    seen = ob.observed_in_views(samples, [cam], *map(lambda m: [m], _maps(cam)), min_views=1)
    share = ob.edge_shares(samples, seen, len(sk.edges))
    expected = np.arccos(R / 2.0) / np.pi
    assert share == pytest.approx(np.full(len(sk.edges), expected), abs=0.01)
    assert ob.observed_share(sk, share) == pytest.approx(expected, abs=0.01)


def test_two_views_observe_the_arc_both_see():
    """Two cameras 90 degrees apart (min_views 2): only the bark facing both, an arc of pi/2 - 2 asin(R/D) wide
    (each camera sees cos(theta) > R/D)."""
    sk = _cylinder()
    cams = [_camera(0.0, width=1600), _camera(90.0, width=1600)]
    maps = [_maps(c) for c in cams]
    samples = ob.wood_samples(sk, step=0.01, around=128)
    seen = ob.observed_in_views(samples, cams, [m[0] for m in maps], [m[1] for m in maps])
    expected = (2 * np.arccos(R / 2.0) - np.pi / 2) / (2 * np.pi)
    assert ob.observed_share(sk, ob.edge_shares(samples, seen, len(sk.edges))) == pytest.approx(expected, abs=0.01)


def test_a_leaf_in_front_hides_the_wood_behind_it():
    sk = _cylinder()
    cams = [_camera(0.0), _camera(30.0)]
    maps = [_maps(c, leaf_below=0.5 * H) for c in cams]
    samples = ob.wood_samples(sk, step=0.01, around=64)
    share = ob.edge_shares(samples, ob.observed_in_views(samples, cams, [m[0] for m in maps], [m[1] for m in maps]),
                           len(sk.edges))
    mid_z = 0.5 * (sk.positions[sk.edges[:, 0], 2] + sk.positions[sk.edges[:, 1], 2])
    assert np.all(share[mid_z < 0.45 * H] == 0)
    assert np.all(share[mid_z > 0.55 * H] > 0.2)


def test_a_branch_narrower_than_a_pixel_is_not_observed():
    sk = _cylinder()
    cams = [_camera(0.0, 2.2, width=9), _camera(20.0, 2.2, width=9)]  # 2 R f / z < 1 px; the centre pixel hits
    maps = [_maps(c) for c in cams]
    samples = ob.wood_samples(sk, step=0.01)
    f = cams[0].K[0, 0]
    assert 2 * R * f / (2.2 - R) < 1.0
    assert not ob.observed_in_views(samples, cams, [m[0] for m in maps], [m[1] for m in maps]).any()
    seen = ob.observed_in_views(samples, cams, [m[0] for m in maps], [m[1] for m in maps], min_diameter_px=0.5)
    assert seen.any()


def test_scan_returns_observe_the_bark_near_them():
    sk = _cylinder()
    samples = ob.wood_samples(sk, step=0.01, around=32)
    front = samples.points[(samples.normals[:, 0] > 0) & (samples.points[:, 2] > 0.5 * H)]
    seen = ob.observed_in_scan(samples, front + 0.001, tolerance=0.01)
    share = ob.edge_shares(samples, seen, len(sk.edges))
    assert ob.observed_share(sk, share) == pytest.approx(0.25, abs=0.03)
    assert not ob.observed_in_scan(samples, np.zeros((0, 3)), 0.01).any()


def test_observed_file_round_trip_and_mismatch(tmp_path):
    from plantbench.errors import InputError

    sk = _cylinder()
    share = np.linspace(0, 1, len(sk.edges))
    ob.write_observed(tmp_path / ob.OBSERVED_FILE, sk, share, {"min_views": 2})
    assert np.allclose(ob.read_observed(tmp_path / ob.OBSERVED_FILE, sk), share, atol=1e-6)
    with pytest.raises(InputError, match="edges"):
        ob.read_observed(tmp_path / ob.OBSERVED_FILE, _cylinder(5))
    (tmp_path / "bad.npz").write_bytes(b"no zip")
    with pytest.raises(InputError, match="bad.npz"):
        ob.read_observed(tmp_path / "bad.npz", sk)


def _two_limbs() -> Skeleton:
    """A 1 m stem with two 0.5 m limbs at its top, one to +x and one to -x (thinner)."""
    pos = np.array([[0, 0, 0], [0, 0, 0.5], [0, 0, 1.0], [0.5, 0, 1.0], [-0.5, 0, 1.0]], float)
    return Skeleton(pos, np.array([0.05, 0.05, 0.04, 0.02, 0.02]), np.array([-1, 0, 1, 2, 2]), np.zeros(5, np.int64))


def _naive_hidden_recall(gt: Skeleton, pred: Skeleton, share: np.ndarray, tau: float) -> float:
    """Volume-weighted recall over the hidden edges' samples farther than ``tau`` plus the sample spacing from every
    observed edge's sample, one ground-truth sample at a time."""
    g, p = skeleton_samples(gt), skeleton_samples(pred)
    pts = g.points[:g.edge_samples]
    seen = share[g.edge] >= 0.5
    gap = g.length[:g.edge_samples].max()  # the sample spacing (the observed edges' end nodes lie within it)
    beyond = np.array([np.min(np.linalg.norm(pts[seen] - q, axis=1)) >= tau + gap for q in pts])
    w = g.weights(True)[:g.edge_samples] * (~seen & beyond)
    near = np.array([np.min(np.linalg.norm(p.points - q, axis=1)) < tau for q in pts])
    return float(w[near].sum() / w.sum())


def test_truth_cut_to_its_observed_wood_scores_observation_1_inference_0():
    """The calibration rung: the truth without its hidden limb has vf1_observed 1 and vrecall_hidden 0 (the hidden
    limb's first centimetre, within 1 % of the height of the fork, counts in neither recall); the whole truth 1 and 1;
    recall over the hidden wood as a naive loop computes it."""
    gt = _two_limbs()
    share = np.array([1.0, 1.0, 0.6, 0.3])  # edges (0-1, 1-2, 2-3, 2-4): the -x limb hidden
    cut = Skeleton(gt.positions[:4], gt.radii[:4], gt.parents[:4], np.zeros(4, np.int64))
    scores = skeleton_prf(gt, cut, height=1.0, gt_observed=share)
    assert scores["vf1_observed@1%"] == pytest.approx(1.0)
    assert scores["vrecall_hidden@1%"] == 0.0
    assert scores["vf1@1%"] < 0.99
    whole = skeleton_prf(gt, gt, height=1.0, gt_observed=share)
    assert whole["vf1_observed@1%"] == pytest.approx(1.0) and whole["vrecall_hidden@1%"] == pytest.approx(1.0)
    half = Skeleton(np.array([[0, 0, 1.0], [-0.25, 0, 1.0]]), np.array([0.02, 0.02]), np.array([-1, 0]),
                    np.zeros(2, np.int64))  # the hidden limb's first half alone
    got = skeleton_prf(gt, half, height=1.0, gt_observed=share)
    assert got["vrecall_hidden@1%"] == pytest.approx(_naive_hidden_recall(gt, half, share, 0.01))

    def cone(x):  # the wood of the hidden limb's first x metres (r from 0.04 to 0.02 m over its 0.5 m), / pi
        a, b = 0.04, 0.02 / 0.5
        return a * a * x - a * b * x * x + b * b * x**3 / 3

    # from 1 cm (beyond the fork's tolerance) to 26 cm (the half and the tolerance beyond it), of 1 to 50 cm
    assert got["vrecall_hidden@1%"] == pytest.approx((cone(0.26) - cone(0.01)) / (cone(0.5) - cone(0.01)), abs=0.01)
    assert skeleton_prf(gt, half, height=1.0, gt_observed=np.ones(4))["vrecall_hidden@1%"] is None


def test_breast_height_observed_reads_the_stem_edge_at_1_3_m():
    from plantbench.metrics.evaluate import _breast_height_observed

    n = 7  # a 3 m stem, nodes every 0.5 m: the edge 1.0-1.5 m (the 3rd) crosses breast height
    pos = np.stack([np.zeros(n), np.zeros(n), np.linspace(0.0, 3.0, n)], 1)
    stem = Skeleton(pos, np.full(n, 0.1), np.arange(-1, n - 1), np.zeros(n, np.int64))
    share = np.ones(n - 1)
    assert _breast_height_observed(stem, share, 1.3) == 1.0
    share[2] = 0.4
    assert _breast_height_observed(stem, share, 1.3) == 0.0
    assert _breast_height_observed(stem, share, 1.0) == 1.0  # 1.0 m lies on the 2nd edge's end (the first to cross)
    assert _breast_height_observed(stem, share, 3.5) is None


def test_observed_figure_colours_by_the_suites_source(captured, tmp_path, monkeypatch):
    """A capture with views and a scan: the figure of a scan suite colours the true skeleton by what the scan
    observed, that of a views suite by what the views observed (the file each suite's metrics read)."""
    import plantbench.capture.observed as observed_module
    from plantbench.report.observation import observed_figure

    case, _ = captured
    assert (case / "scan" / ob.OBSERVED_FILE).is_file() and (case / "views" / ob.OBSERVED_FILE).is_file()
    read = []
    real = observed_module.read_observed
    monkeypatch.setattr(observed_module, "read_observed", lambda path, sk: read.append(path) or real(path, sk))
    out = observed_figure({"case": case}, tmp_path / "observed.png", source="scan")
    assert out is not None and out.is_file()
    assert [p.parent.name for p in read] == ["scan"]
    read.clear()
    assert observed_figure({"case": case}, tmp_path / "views.png") is not None
    assert [p.parent.name for p in read] == ["views"]
    with pytest.raises(ValueError, match="source"):
        observed_figure({"case": case}, tmp_path / "bad.png", source="lidar")
