"""Depth and normals of one view of the analytic scene against its exact depth."""

from __future__ import annotations

import numpy as np
import pytest

from plantbench.errors import InputError
from reference_impl.mvs.neighbours import depth_range, scene_centre
from reference_impl.mvs.params import DepthParams
from reference_impl.mvs.patchmatch import estimate_depth, sweep_depths, to_gray


@pytest.fixture(scope="module")
def estimate(views, ring):
    ref, srcs = 0, [1, 15, 2, 14]
    near, far = depth_range(ring[ref], scene_centre(ring), 1.25)
    dm = estimate_depth(views[ref][0], [views[j][0] for j in srcs], ring[ref], [ring[j] for j in srcs],
                        (near, far), DepthParams(), rng=np.random.default_rng(0))
    sweep_only = estimate_depth(views[ref][0], [views[j][0] for j in srcs], ring[ref], [ring[j] for j in srcs],
                                (near, far), DepthParams(), rng=np.random.default_rng(0), refine=False)
    gt = views[ref][1]
    inside = np.isfinite(gt) & (gt > near) & (gt < far)
    return dm, sweep_only, gt, inside


def test_depth_matches_exact_depth(estimate, views):
    dm, _, gt, inside = estimate
    got = np.isfinite(dm.depth) & inside
    assert got.sum() > 0.6 * inside.sum()  # most textured in-range pixels get a depth
    rel = np.abs(dm.depth[got] - gt[got]) / gt[got]
    # 128 px views: a pixel spans ~1.7 cm at 2.6 m, so 1 % depth error is about one pixel of disparity
    assert np.median(rel) < 0.01
    assert np.mean(rel < 0.02) > 0.7
    on_objects = got & (views[0][2] == 1)
    assert np.median(np.abs(dm.depth[on_objects] - gt[on_objects]) / gt[on_objects]) < 0.005


def test_patchmatch_refines_the_sweep(estimate):
    dm, sweep, gt, inside = estimate
    both = np.isfinite(dm.depth) & np.isfinite(sweep.depth) & inside
    err_pm = np.median(np.abs(dm.depth[both] - gt[both]) / gt[both])
    err_sw = np.median(np.abs(sweep.depth[both] - gt[both]) / gt[both])
    assert err_pm <= err_sw * 1.05


def test_normals_of_the_ground(estimate, views):
    dm, _, gt, inside = estimate
    ground = inside & (views[0][2] == 0) & np.isfinite(dm.depth)
    cosang = dm.normal[ground] @ np.array([0.0, 0.0, 1.0])
    assert np.median(cosang) > np.cos(np.radians(20))


def test_unmatched_pixels_are_nan(estimate):
    dm, _, _, _ = estimate
    assert np.all(np.isnan(dm.normal[np.isnan(dm.depth)]))
    assert dm.depth.dtype == np.float32 and dm.normal.shape == dm.depth.shape + (3,)


def test_sweep_depths_uniform_in_inverse_depth():
    d = sweep_depths(2.0, 8.0, 5)
    assert d[0] == pytest.approx(8.0) and d[-1] == pytest.approx(2.0)
    assert np.allclose(np.diff(1 / d), (1 / 2.0 - 1 / 8.0) / 4)
    with pytest.raises(InputError):
        sweep_depths(3.0, 2.0, 4)


def test_to_gray_weights():
    img = np.zeros((2, 2, 3), np.uint8)
    img[..., 1] = 255
    assert np.allclose(to_gray(img), 0.587, atol=1e-6)


def test_estimate_depth_rejects_bad_input(views, ring):
    with pytest.raises(InputError):
        estimate_depth(views[0][0], [], ring[0], [], (1.0, 4.0), rng=np.random.default_rng(0))
    with pytest.raises(InputError):
        estimate_depth(views[0][0][:64], [views[1][0]], ring[0], [ring[1]], (1.0, 4.0),
                       rng=np.random.default_rng(0))
    with pytest.raises(InputError, match="coarse_scale"):
        estimate_depth(views[0][0], [views[1][0]], ring[0], [ring[1]], (1.0, 4.0), DepthParams(coarse_scale=0),
                       rng=np.random.default_rng(0))


def test_packed_bilinear_lookup_matches_scipy(rng):
    """The one-gather bilinear lookup of the cost kernels (2 x 2 blocks of 15-bit levels in 64-bit words) against
    scipy's map_coordinates (order 1, border replicated) on the float image, including points outside the image; a
    non-finite coordinate reads inside the image and gives NaN (the cost kernels reject it)."""
    from scipy.ndimage import map_coordinates

    from reference_impl.mvs.patchmatch import _bilinear_packed, _drjit, _Packed

    dr, jl = _drjit()
    h, w = 37, 53
    img = rng.uniform(-2.0, 3.0, (h, w))
    packed = _Packed.pack(jl, img)
    u = np.concatenate([rng.uniform(-3, w + 2, 500), [np.nan, np.inf, -np.inf, 0.0, w - 1.0]]).astype(np.float32)
    v = np.concatenate([rng.uniform(-3, h + 2, 500), [1.0, 2.0, 3.0, np.nan, h - 1.0]]).astype(np.float32)
    levels = np.asarray(_bilinear_packed(dr, jl, packed, jl.Float(u), jl.Float(v)))
    val = packed.offset + packed.scale * levels
    fin = np.isfinite(u) & np.isfinite(v)
    ref = map_coordinates(img, [v[fin], u[fin]], order=1, mode="nearest")
    np.testing.assert_allclose(val[fin], ref, atol=5.0 / 32767 + 1e-6)  # half a level of the 5-wide range, + float32
    assert np.isfinite(val[~np.isnan(u) & ~np.isnan(v)]).all()
    assert np.isnan(val[np.isnan(u) | np.isnan(v)]).all()


def _naive_plane_cost(ref, srcs, ref_cam, src_cams, x, y, d, n_cam, p: DepthParams):
    """The bilateral-weighted ZNCC cost of one pixel's plane, sample by sample: ray-plane intersection, projection,
    scipy bilinear lookup, weighted ZNCC per source, mean of the top_k best."""
    from scipy.ndimage import map_coordinates

    kinv = np.linalg.inv(ref_cam.K)
    rho = d * n_cam @ (kinv @ [x, y, 1.0])
    r = p.pm_radius
    offs = [(ox, oy) for oy in range(-r, r + 1) for ox in range(-r, r + 1) if not p.pm_checker or (ox + oy) % 2 == 0]
    rv = np.array([ref[y + oy, x + ox] for ox, oy in offs])
    wt = np.exp(-((rv - ref[y, x]) ** 2) / (2 * p.bilateral_sigma_color**2)
                - np.array([ox * ox + oy * oy for ox, oy in offs]) / (2 * p.bilateral_sigma_space**2))
    wt /= wt.sum()
    costs = []
    for src, cam in zip(srcs, src_cams):
        r_rel = cam.R @ ref_cam.R.T
        t_rel = cam.t - r_rel @ ref_cam.t
        sv, ok = [], True
        for ox, oy in offs:
            ray = kinv @ [x + ox, y + oy, 1.0]
            X = ray * rho / (n_cam @ ray)
            xs = cam.K @ (r_rel @ X + t_rel)
            u, v = xs[0] / xs[2], xs[1] / xs[2]
            if ox == 0 and oy == 0:
                ok = xs[2] > 0 and -0.5 <= u <= src.shape[1] - 0.5 and -0.5 <= v <= src.shape[0] - 0.5
            sv.append(map_coordinates(src, [[v], [u]], order=1, mode="nearest")[0])
        sv = np.array(sv)
        mr, ms = wt @ rv, wt @ sv
        cov = wt @ (rv * sv) - mr * ms
        var_r, var_s = wt @ rv**2 - mr**2, wt @ sv**2 - ms**2
        costs.append(1.0 - cov / np.sqrt(var_r * var_s + 1e-8) if ok else 2.0)
    return float(np.mean(np.sort(costs)[: p.top_k]))


@pytest.mark.parametrize("checker", [False, True])
def test_plane_cost_matches_naive(views, ring, rng, checker):
    """The PatchMatch cost kernel (per-pixel homographies, packed lookups, precomputed window weights) against the
    sample-by-sample computation, for random slanted planes at random pixels away from the border."""
    from reference_impl.mvs.patchmatch import _drjit, _Engine

    dr, jl = _drjit()
    p = DepthParams(pm_checker=checker)
    srcs_i = [1, 15, 2, 14]
    ref = to_gray(views[0][0])
    srcs = [to_gray(views[j][0]) for j in srcs_i]
    eng = _Engine(ref, srcs, ring[0], [ring[j] for j in srcs_i], p)
    m = 60
    x = rng.integers(3, ring[0].width - 3, m)
    y = rng.integers(3, ring[0].height - 3, m)
    gt = views[0][1][y, x]
    d = np.where(np.isfinite(gt), gt, 3.0) * rng.uniform(0.97, 1.03, m)
    n = rng.normal(size=(m, 3)) * [0.4, 0.4, 1.0]
    n[:, 2] = -np.abs(n[:, 2])  # facing the camera (camera looks along +z)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    win = eng._window(jl.UInt32((x + y * ring[0].width).astype(np.uint32)))
    got = np.asarray(eng._plane_cost(win, jl.Float(d), jl.Float(n[:, 0]), jl.Float(n[:, 1]), jl.Float(n[:, 2])))
    want = np.array([_naive_plane_cost(ref, srcs, ring[0], [ring[j] for j in srcs_i], x[i], y[i], d[i], n[i], p)
                     for i in range(m)])
    assert np.ptp(want) > 0.3  # the test planes are not all alike
    np.testing.assert_allclose(got, want, atol=5e-4)


def test_sweep_costs_match_numpy(views, ring):
    """The sweep's per-source costs of one plane (packed source lookups, products quantised into 16-bit fields
    summed four sources at a time) against float warping with scipy and a scipy box filter."""
    from scipy.ndimage import map_coordinates, uniform_filter

    from reference_impl.mvs.patchmatch import _Engine, _normalised

    p = DepthParams()
    srcs_i = [1, 15, 2, 14]
    ref = to_gray(views[0][0])
    srcs = [to_gray(views[j][0]) for j in srcs_i]
    cams = [ring[j] for j in srcs_i]
    eng = _Engine(ref, srcs, ring[0], cams, p)
    d = float(np.nanmedian(views[0][1]))
    got = [np.asarray(c).reshape(ref.shape) for c in eng.sweep_costs(1.0 / d)]
    h, w = ref.shape
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    ref_hat = _normalised(ref, p.sweep_window, p.min_texture)
    for j, (src, cam) in enumerate(zip(srcs, cams)):
        r_rel = cam.R @ ring[0].R.T
        t_rel = cam.t - r_rel @ ring[0].t
        X = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(ring[0].K).T * d  # points on the plane z = d
        xs = (X @ r_rel.T + t_rel) @ cam.K.T
        us, vs = xs[..., 0] / xs[..., 2], xs[..., 1] / xs[..., 2]
        inside = (xs[..., 2] > 0) & (us >= -0.5) & (us <= w - 0.5) & (vs >= -0.5) & (vs <= h - 0.5)
        warped = map_coordinates(_normalised(src, p.sweep_window, p.min_texture), [vs, us], order=1, mode="nearest")
        prod = np.where(inside, warped * ref_hat, -1.0)
        want = 1.0 - uniform_filter(prod, p.sweep_window, mode="nearest")
        err = np.abs(got[j] - want)
        assert np.ptp(want) > 1.0
        step = 2 * eng._PROD_RANGE / (65535 // p.sweep_window**2 - 1)  # one quantisation level of a product
        assert err.max() < 0.5 * step + 1e-4  # at most half a level (products outside +-8 do not occur here)


def test_scaled_camera_maps_pixel_centres(ring, rng):
    """A point's pixel in the camera of the image downsampled by f is (u + 0.5) / f - 0.5."""
    from reference_impl.mvs.patchmatch import _scaled_camera

    pts = rng.normal(0, 0.3, (50, 3))
    uv, _ = ring[0].project(pts)
    uv2, _ = _scaled_camera(ring[0], 2).project(pts)
    np.testing.assert_allclose(uv2, (uv + 0.5) / 2 - 0.5, atol=1e-9)


def test_upsampled_planes_continue_each_coarse_plane(ring):
    """A tilted plane seen by the coarse camera comes back at full resolution with its exact depth at every pixel."""
    from reference_impl.mvs.patchmatch import _scaled_camera, _upsample_planes

    fine = ring[0]
    coarse = _scaled_camera(fine, 2)
    n = np.array([0.2, -0.3, -1.0])
    n /= np.linalg.norm(n)
    rho = -2.5  # plane n . X = rho in the camera frame, ~2.5 m ahead

    def plane_depth(cam):
        u, v = np.meshgrid(np.arange(cam.width, dtype=float), np.arange(cam.height, dtype=float))
        rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(cam.K).T
        return rho / (rays @ n)

    normals = np.broadcast_to(n, (coarse.height, coarse.width, 3)).astype(np.float32)
    cost = np.zeros((coarse.height, coarse.width), np.float32)
    d, nn, _ = _upsample_planes(plane_depth(coarse).astype(np.float32), normals, cost, coarse, fine, 2)
    np.testing.assert_allclose(d, plane_depth(fine), rtol=1e-5)
    assert d.shape == (fine.height, fine.width) and np.allclose(nn, n, atol=1e-6)


def test_coarse_to_fine_matches_exact_depth(views, ring):
    """Coarse to fine (half-resolution sweep and PatchMatch, then checkerboard PatchMatch with random depths at full
    resolution) on the analytic scene; its 128 px views are below the default ``coarse_min_size``, so it is
    lowered."""
    ref, srcs = 0, [1, 15, 2, 14]
    near, far = depth_range(ring[ref], scene_centre(ring), 1.25)
    p = DepthParams(coarse_min_size=32)
    dm = estimate_depth(views[ref][0], [views[j][0] for j in srcs], ring[ref], [ring[j] for j in srcs], (near, far),
                        p, rng=np.random.default_rng(0))
    gt = views[ref][1]
    got = np.isfinite(dm.depth) & np.isfinite(gt) & (gt > near) & (gt < far)
    assert got.sum() > 0.5 * (np.isfinite(gt) & (gt > near) & (gt < far)).sum()
    rel = np.abs(dm.depth[got] - gt[got]) / gt[got]
    assert np.median(rel) < 0.01 and np.mean(rel < 0.02) > 0.6


def test_small_views_run_at_full_resolution(views, ring):
    """Below ``coarse_min_size`` (128 px views, coarse level 64 px) the default is the full-resolution path: the same
    depth map as ``coarse_scale=1``; a coarse_min_size below 1 is refused."""
    ref, srcs = 0, [1, 15]
    near, far = depth_range(ring[ref], scene_centre(ring), 1.25)
    args = (views[ref][0], [views[j][0] for j in srcs], ring[ref], [ring[j] for j in srcs], (near, far))
    a = estimate_depth(*args, DepthParams(), rng=np.random.default_rng(3))
    b = estimate_depth(*args, DepthParams(coarse_scale=1), rng=np.random.default_rng(3))
    c = estimate_depth(*args, DepthParams(coarse_min_size=32), rng=np.random.default_rng(3))
    np.testing.assert_array_equal(a.depth, b.depth)
    assert not np.array_equal(np.isnan(a.depth), np.isnan(c.depth))  # the coarse path is another computation
    with pytest.raises(InputError, match="coarse_min_size"):
        estimate_depth(*args, DepthParams(coarse_min_size=0), rng=np.random.default_rng(3))


def test_random_depths_find_surfaces_no_plane_holds(views, ring):
    """From planes that are all wrong (every pixel at the far end of the range, where no surface is), PatchMatch's
    propagation and small perturbations cannot reach the scene; the random-depth candidate of the fine level of
    coarse to fine does."""
    from reference_impl.mvs.patchmatch import _Engine

    ref, srcs = 0, [1, 15, 2, 14]
    near, far = depth_range(ring[ref], scene_centre(ring), 1.25)
    eng = _Engine(to_gray(views[ref][0]), [to_gray(views[j][0]) for j in srcs], ring[ref], [ring[j] for j in srcs],
                  DepthParams(pm_iterations=2))
    h, w = views[ref][1].shape
    depth0 = np.full((h, w), 0.98 * far, np.float32)
    normal0 = np.broadcast_to(np.array([0.0, 0.0, -1.0], np.float32), (h, w, 3)).copy()
    gt = views[ref][1]
    scene = np.isfinite(gt) & (gt > near) & (gt < 0.9 * far)
    found = {}
    for random_depth in (False, True):
        d, _, _ = eng.patchmatch(depth0, normal0, near, far, np.random.default_rng(1), random_depth=random_depth)
        found[random_depth] = np.mean(np.abs(d[scene] - gt[scene]) < 0.02 * gt[scene])
    assert found[False] < 0.01 and found[True] > 0.2, found  # measured 0.0001 and 0.30


def test_propagation_regions():
    """ACMH's adaptive checkerboard: 4 V-shaped near regions of 7 samples and 4 strips of 11 reaching 23 pixels, one
    per direction, every sample on the other colour of the checkerboard; 'four' is the 4 adjacent pixels."""
    from reference_impl.mvs.patchmatch import propagation_regions

    assert sorted(map(tuple, propagation_regions("four"))) == [((-1, 0),), ((0, -1),), ((0, 1),), ((1, 0),)]
    regions = propagation_regions("adaptive")
    assert sorted(len(r) for r in regions) == [7] * 4 + [11] * 4
    samples = [s for r in regions for s in r]
    assert len(set(samples)) == len(samples) == 72  # no sample in two regions
    assert all((dx + dy) % 2 == 1 for dx, dy in samples)
    assert max(max(abs(dx), abs(dy)) for dx, dy in samples) == 23
    assert set(samples) == {(-dy, dx) for dx, dy in samples}  # symmetric under a quarter turn
    for r in regions:  # each region lies in one direction: the sum of its samples points one way
        sx, sy = np.sum(r, axis=0)
        assert (sx == 0) != (sy == 0)
    with pytest.raises(InputError, match="propagation"):
        propagation_regions("eight")
    with pytest.raises(InputError, match="propagation"):
        estimate_depth(np.zeros((32, 32)), [np.zeros((32, 32))], *_two_cameras(), (1.0, 2.0),
                       DepthParams(propagation="eight"), rng=np.random.default_rng(0))


def _two_cameras():
    from plantbench.cameras import look_at

    return (look_at((0, -3, 1), (0, 0, 1), fov_x_deg=40, width=32, height=32),
            [look_at((0.5, -3, 1), (0, 0, 1), fov_x_deg=40, width=32, height=32)])


def test_adaptive_propagation_carries_planes_farther(views, ring):
    """From planes that are right on every 24th column only (the rest at the far end of the range), one PatchMatch
    iteration with 4-neighbour propagation spreads them by a pixel or two per half-sweep; the adaptive checkerboard
    reaches 23 pixels and covers most of the scene."""
    from reference_impl.mvs.patchmatch import _Engine

    ref, srcs = 0, [1, 15, 2, 14]
    near, far = depth_range(ring[ref], scene_centre(ring), 1.25)
    gt = views[ref][1]
    h, w = gt.shape
    scene = np.isfinite(gt) & (gt > near) & (gt < 0.9 * far)
    seeded = scene & (np.arange(w)[None, :] % 24 == 0)
    depth0 = np.where(seeded, gt, 0.98 * far).astype(np.float32)
    normal0 = np.broadcast_to(np.array([0.0, 0.0, -1.0], np.float32), (h, w, 3)).copy()
    found = {}
    for kind in ("four", "adaptive"):
        eng = _Engine(to_gray(views[ref][0]), [to_gray(views[j][0]) for j in srcs], ring[ref],
                      [ring[j] for j in srcs], DepthParams(propagation=kind))
        d, _, _ = eng.patchmatch(depth0, normal0, near, far, np.random.default_rng(1), iterations=1)
        found[kind] = np.mean(np.abs(d[scene] - gt[scene]) < 0.02 * gt[scene])
    assert found["four"] < 0.4 and found["adaptive"] > found["four"] + 0.25, found  # measured 0.16 and 0.65


def test_reprojection_error_matches_naive(views, ring, rng):
    """The geometric-consistency term against a numpy computation with the cameras' own projection: the pixel's
    plane point projected into the source, the source's depth at the nearest pixel back-projected and projected into
    the reference; truncated at ``geometric_max_px``. With the source's exact depth a plane at the exact depth
    reprojects within a pixel."""
    from reference_impl.mvs.patchmatch import _drjit, _Engine

    dr, jl = _drjit()
    p = DepthParams()
    ref_cam, src_cam = ring[0], ring[1]
    src_depth = views[1][1]
    eng = _Engine(to_gray(views[0][0]), [to_gray(views[1][0])], ref_cam, [src_cam], p)
    eng.set_geometry([src_depth])
    m = 400
    x = rng.integers(0, ref_cam.width, m).astype(float)
    y = rng.integers(0, ref_cam.height, m).astype(float)
    gt = views[0][1][y.astype(int), x.astype(int)]
    d = np.where(np.isfinite(gt), gt, 3.0) * np.where(rng.random(m) < 0.5, 1.0, rng.uniform(0.9, 1.1, m))
    # the reference pixel's point and its projection into the source
    X = (np.stack([x, y, np.ones(m)], 1) @ np.linalg.inv(ref_cam.K).T) * d[:, None]
    Xw = (X - ref_cam.t) @ ref_cam.R
    uv, _ = src_cam.project(Xw)
    inside = (uv[:, 0] >= -0.5) & (uv[:, 0] <= src_cam.width - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] <= src_cam.height - 0.5)
    got = np.asarray(eng._reprojection_error(0, jl.Float(uv[:, 0]), jl.Float(uv[:, 1]), jl.Float(x), jl.Float(y),
                                             jl.Bool(inside)))
    want = np.full(m, p.geometric_max_px)
    for i in np.flatnonzero(inside):
        ui = int(np.clip(np.round(uv[i, 0]), 0, src_cam.width - 1))
        vi = int(np.clip(np.round(uv[i, 1]), 0, src_cam.height - 1))
        ds = src_depth[vi, ui]
        if not (np.isfinite(ds) and ds > 0):
            continue
        Xs = np.linalg.inv(src_cam.K) @ [ui, vi, 1.0] * ds
        back, z = ref_cam.project(((Xs - src_cam.t) @ src_cam.R)[None])
        if z[0] > 0:
            want[i] = min(np.hypot(back[0, 0] - x[i], back[0, 1] - y[i]), p.geometric_max_px)
    np.testing.assert_allclose(got, want, atol=2e-3)
    exact = inside & (d == np.where(np.isfinite(gt), gt, 3.0)) & np.isfinite(gt)
    assert np.median(want[exact]) < 1.0 and np.mean(want[~exact & inside] == p.geometric_max_px) > 0.3


def test_geometric_pass_keeps_consistent_depth(views, ring):
    """The geometric-consistency pass from the photometric planes, its sources' depth maps exact: the share of
    pixels within 1 % of the exact depth rises, and a start without planes is an InputError."""
    from reference_impl.mvs.patchmatch import refine_geometric

    ref, srcs = 0, [1, 15, 2, 14]
    near, far = depth_range(ring[ref], scene_centre(ring), 1.25)
    args = (views[ref][0], [views[j][0] for j in srcs], ring[ref], [ring[j] for j in srcs])
    p = DepthParams(geometric_iterations=2)
    photo = estimate_depth(*args, (near, far), p, rng=np.random.default_rng(0))
    geo = refine_geometric(*args, photo, [views[j][1] for j in srcs], (near, far), p, rng=np.random.default_rng(1))
    gt = views[ref][1]
    scene = np.isfinite(gt) & (gt > near) & (gt < far)

    def share(dm):
        return np.mean(np.abs(dm.depth[scene] - gt[scene]) < 0.01 * gt[scene])

    assert share(geo) > share(photo) + 0.05, (share(photo), share(geo))  # measured 0.75 -> 0.89
    assert geo.planes is not None and np.all(np.isnan(geo.depth) | np.isfinite(geo.planes[0]))
    sweep = estimate_depth(*args, (near, far), p, rng=np.random.default_rng(0), refine=False)
    with pytest.raises(InputError, match="planes"):
        refine_geometric(*args, sweep, [views[j][1] for j in srcs], (near, far), p, rng=np.random.default_rng(1))


@pytest.mark.parametrize(("size", "sweep", "step", "sigma"), [
    ((256, 256), 5, 1, 3.0), ((512, 384), 5, 1, 3.0), ((1024, 767), 5, 1, 3.0), ((1024, 768), 9, 2, 6.0),
    ((1024, 1024), 9, 2, 6.0), ((2048, 2048), 17, 4, 12.0), ((4000, 3000), 25, 6, 18.0)])
def test_windows_scale_with_the_view(size, sweep, step, sigma):
    """The 512 px windows, s = round(shorter side / 512) times larger above it (hand-computed: 2 (5 // 2) s + 1,
    s x 1 px, s x 3 px); the PatchMatch sample count and everything else unchanged."""
    p = DepthParams().for_view(*size)
    assert (p.sweep_window, p.pm_step, p.bilateral_sigma_space) == (sweep, step, sigma)
    assert (p.pm_radius, p.hypotheses, p.max_cost) == (DepthParams().pm_radius, 128, DepthParams().max_cost)
    assert p.for_view(*size) == p  # scaled once: the result is pinned at its sizes
    assert p.background_span == (0.5 if sweep > 5 else 0.0)  # the background search where the windows scale


@pytest.mark.parametrize(("given", "size", "expected"), [
    (None, (512, 512), 0.0), (None, (1024, 1024), 0.5), (None, (2048, 1536), 0.5), (0.0, (1024, 1024), 0.0),
    (0.25, (512, 512), 0.25)])
def test_background_span_follows_the_view_unless_given(given, size, expected):
    """Automatic (None): 0.5 where the windows run at twice their 512 px size or more, 0 below; a given value is
    kept at every size; window_scale = 1 (windows pinned) keeps the automatic span at 0."""
    assert DepthParams(background_span=given).for_view(*size).background_span == expected
    assert DepthParams(window_scale=1).for_view(2048, 2048).background_span == 0.0
    with pytest.raises(InputError, match="background_span"):
        DepthParams(background_span=-0.1)


def test_window_scale_option():
    p = DepthParams(window_scale=1, pm_step=2, sweep_window=7, background_span=0.0)
    assert p.for_view(1024, 1024) is p
    q = DepthParams(window_scale=3).for_view(256, 256)
    assert (q.sweep_window, q.pm_step, q.bilateral_sigma_space) == (13, 3, 9.0)
    with pytest.raises(InputError, match="window_scale"):
        DepthParams(window_scale=-1).for_view(512, 512)
