"""Dense depth for one 512 x 512 reference view with 4 neighbours and 128 depth hypotheses (plane sweep + PatchMatch,
Dr.Jit LLVM), beside a bare OpenCV StereoSGBM on one rectified pair of the same views (256 disparities, SGBM_3WAY).
The default (coarse to fine: half-resolution sweep and PatchMatch, then full-resolution PatchMatch with a
checkerboard window and random depths, DepthParams.coarse_scale) and the full-resolution configuration
(``coarse_scale=1``: sweep and PatchMatch with the dense 5 x 5 window at 512 px) are both timed.

The views come from the capture in ``$PLANTBENCH_MVS_CASE`` when set (a case folder with views/), else from the
analytic textured scene of reference_impl.mvs.synthetic (20 views on a ring, 512 px; 5 of them rendered).
The Dr.Jit kernels are compiled (or loaded from the kernel cache) in a warm-up call outside the timing.

Each plantbench timing is printed as a ratio to the bare SGBM pair (best of 3) and fails beyond a bound 2-3x the
ratio measured on the 2-core development machine (the default: MAX_DEFAULT_RATIO; full resolution: MAX_FULL_RATIO):
SGBM matches one pair on one disparity axis, our depth four neighbours with slanted planes, so the ratio is large but
its drift is what a regression looks like.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pytest

from reference_impl.mvs.neighbours import depth_range, scene_centre, select_neighbours
from reference_impl.mvs.params import DepthParams
from reference_impl.mvs.patchmatch import estimate_depth

MAX_DEFAULT_RATIO = 80.0  # measured 37.8 (1.79 s vs 0.047 s) with another job on the second core
MAX_FULL_RATIO = 200.0  # measured 73.4


@pytest.fixture(scope="module")
def views():
    """(reference image, [4 source images], reference camera, [source cameras], depth range, ground-truth depth)."""
    case = os.environ.get("PLANTBENCH_MVS_CASE")
    if case:
        from reference_impl.mvs.method import load_views

        images, cams, names = load_views(case)
        nb = select_neighbours(cams)
        ref = 0
        gt = np.load(Path(case) / "views" / "depth" / f"{Path(names[ref]).stem}.npy")
        imgs = {i: images[i] for i in [ref, *nb[ref]]}
    else:
        from reference_impl.mvs import synthetic

        cams = synthetic.ring_cameras(20, width=512, height=512)
        nb = select_neighbours(cams)
        ref = 0
        scene = synthetic.default_scene()
        rendered = {i: synthetic.render(scene, cams[i], supersample=1) for i in [ref, *nb[ref]]}
        imgs = {i: r[0] for i, r in rendered.items()}
        gt = rendered[ref][1]
    rng_ = depth_range(cams[ref], scene_centre(cams), DepthParams().depth_margin)
    return imgs[ref], [imgs[j] for j in nb[ref]], cams[ref], [cams[j] for j in nb[ref]], rng_, gt


def _sgbm(views):
    """A bare OpenCV StereoSGBM matcher and the rectified pair (reference and its first neighbour) it matches."""
    import cv2

    ref, srcs, cam, src_cams, _, _ = views
    other = src_cams[0]
    r_rel = other.R @ cam.R.T
    t_rel = (other.t - r_rel @ cam.t).reshape(3, 1)  # stereoRectify wants (3, 1) (docs/design.md, Platform notes)
    size = (cam.width, cam.height)
    r1, r2, p1, p2, _, _, _ = cv2.stereoRectify(cam.K, np.zeros(5), other.K, np.zeros(5), size, r_rel, t_rel,
                                                flags=0, alpha=-1)
    m1 = cv2.initUndistortRectifyMap(cam.K, np.zeros(5), r1, p1, size, cv2.CV_32FC1)
    m2 = cv2.initUndistortRectifyMap(other.K, np.zeros(5), r2, p2, size, cv2.CV_32FC1)
    left = cv2.remap(cv2.cvtColor(ref, cv2.COLOR_RGB2GRAY), *m1, cv2.INTER_LINEAR)
    right = cv2.remap(cv2.cvtColor(srcs[0], cv2.COLOR_RGB2GRAY), *m2, cv2.INTER_LINEAR)
    bs = 5
    sgbm = cv2.StereoSGBM_create(minDisparity=-128, numDisparities=256, blockSize=bs, P1=8 * bs * bs,
                                 P2=32 * bs * bs, disp12MaxDiff=1, uniquenessRatio=10, speckleWindowSize=100,
                                 speckleRange=2, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    return sgbm, left, right


@pytest.fixture(scope="module")
def sgbm_s(views):
    """Best of 3 seconds of the bare SGBM pair: the raw-library yardstick of the plantbench timings."""
    sgbm, left, right = _sgbm(views)
    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        sgbm.compute(left, right)
        best = min(best, time.perf_counter() - t0)
    return best


def _depth(benchmark, views, params, sgbm_s, bound):
    ref, srcs, cam, src_cams, rng_, gt = views
    estimate_depth(ref, srcs, cam, src_cams, rng_, params, rng=np.random.default_rng(0))  # kernels compiled/loaded
    dm = benchmark.pedantic(
        estimate_depth, args=(ref, srcs, cam, src_cams, rng_, params), kwargs={"rng": np.random.default_rng(0)},
        rounds=3, iterations=1,
    )
    ok = np.isfinite(dm.depth) & np.isfinite(gt)
    rel = np.abs(dm.depth[ok] - gt[ok]) / gt[ok]
    ours = benchmark.stats.stats.min
    benchmark.extra_info.update(
        matched=float(ok.mean()), median_rel_error=float(np.median(rel)), within_1pct=float(np.mean(rel < 0.01)),
        bare_sgbm_s=sgbm_s, ratio=ours / sgbm_s,
    )
    print(f"\ndepth of one 512 px view / bare SGBM pair = {ours / sgbm_s:.1f} ({ours:.2f} s vs {sgbm_s:.3f} s; "
          f"bound {bound:.0f})")
    assert ok.any()
    assert ours / sgbm_s <= bound


@pytest.mark.benchmark(group="dense-depth-512")
def test_plantbench_depth_4_neighbours_128_planes(benchmark, views, sgbm_s):
    _depth(benchmark, views, DepthParams(hypotheses=128), sgbm_s, MAX_DEFAULT_RATIO)


@pytest.mark.benchmark(group="dense-depth-512")
def test_plantbench_depth_full_resolution(benchmark, views, sgbm_s):
    _depth(benchmark, views, DepthParams(hypotheses=128, coarse_scale=1), sgbm_s, MAX_FULL_RATIO)


@pytest.mark.benchmark(group="dense-depth-512")
def test_bare_opencv_sgbm_one_rectified_pair(benchmark, views):
    sgbm, left, right = _sgbm(views)
    disp = benchmark(sgbm.compute, left, right)
    benchmark.extra_info["matched"] = float(np.mean(disp > sgbm.getMinDisparity() * 16))


MAX_COUNTS_RATIO = 3.0  # measured 1.1 (test_plantbench_consistency_counts)


@pytest.fixture(scope="module")
def ring_depths():
    """Exact depth maps of the analytic scene's 20 ring views (512 px): the multi-view filter's input."""
    from reference_impl.mvs import synthetic

    cams = synthetic.ring_cameras(20, width=512, height=512)
    scene = synthetic.default_scene()
    return [synthetic.render(scene, c, supersample=1)[1] for c in cams], cams


def _projections(depths, cams, views):
    """The floor of the filter's work: every pixel with a depth back-projected and projected into each of its
    neighbours, and each neighbour's pixels projected back (numpy and BLAS, nothing tested or gathered)."""
    from reference_impl.mvs.filtering import _backproject

    world = [_backproject(d, c) for d, c in zip(depths, cams, strict=True)]
    for i, cam in enumerate(cams):
        for j in views[i]:
            cams[j].project(world[i][0])
            cam.project(world[j][0])


@pytest.mark.benchmark(group="mvs-filter")
def test_plantbench_consistency_counts(benchmark, ring_depths):
    """The multi-view consistency test (8 neighbours, 3 x 3 search) on 20 exact 512 px depth maps, beside the bare
    numpy projections it needs, done one after the other. Measured 1.1 (2.18 s vs 1.90 s, 2 cores; the numpy
    implementation before the compiled pair kernel took 14.8 s on the same maps, about 7.8)."""
    from reference_impl.mvs.filtering import consistency_counts, nearest_views

    depths, cams = ring_depths
    views = nearest_views(cams, 8)
    consistency_counts(depths[:2], cams[:2], views=[[1], [0]], reproj_px=2.0, rel_depth=0.01)  # kernel compiled
    t0 = time.perf_counter()
    _projections(depths, cams, views)
    bare = time.perf_counter() - t0
    sup, _ = benchmark.pedantic(consistency_counts, args=(depths, cams),
                                kwargs={"views": views, "reproj_px": 2.0, "rel_depth": 0.01, "search_radius": 1},
                                rounds=2, iterations=1)
    ours = benchmark.stats.stats.min
    benchmark.extra_info.update(bare_projections_s=bare, ratio=ours / bare)
    print(f"\nconsistency counts / bare projections = {ours / bare:.1f} ({ours:.2f} s vs {bare:.2f} s; bound "
          f"{MAX_COUNTS_RATIO:.0f})")
    finite = [np.isfinite(d) for d in depths]
    assert np.mean(np.concatenate([(s >= 1)[f] for s, f in zip(sup, finite, strict=True)])) > 0.9  # exact depth agrees
    assert ours / bare <= MAX_COUNTS_RATIO


MAX_STAGE_1024_RATIO = 60.0
"""The whole mvs stage at 1024 px on one thread / the bare SGBM pairs (see the test). Measured 33.8 on the 2-core Zen 5 (158.6 s against 4.69 s; a cercis in
no suite at 1024 px, the other core idle; issue 64's target, 100 s a plant, is not met)."""


@pytest.fixture(scope="module")
def case_1024(tmp_path_factory):
    """A capture at the multiview suites' settings (20 views, 1024 px, 4 spp denoised, no scan): the case in
    ``$PLANTBENCH_MVS_CASE_1024`` when set, else a cercis (seed 7, in no suite) generated and captured here (about
    2 min on 2 cores)."""
    case = os.environ.get("PLANTBENCH_MVS_CASE_1024")
    if case:
        return Path(case)
    from plantbench.capture import CaptureOptions, capture_case
    from plantbench.generate import generate_case

    folder = tmp_path_factory.mktemp("bench_mvs_1024") / "case"
    generate_case("cercis", 7, folder)
    capture_case(folder, CaptureOptions(views=20, width=1024, height=1024, spp=4, denoise=True, scan=False), seed=0)
    return folder


def _bare_sgbm_pairs(case: Path) -> float:
    """Seconds of a bare OpenCV StereoSGBM (one thread, 256 disparities, SGBM_3WAY) on each view and its first
    neighbour, rectified beforehand: 20 pairs at the views' size."""
    import cv2

    from reference_impl.mvs.method import load_views

    images, cams, _ = load_views(case)
    nb = select_neighbours(cams)
    pairs = [_sgbm((images[i], [images[nb[i][0]]], cams[i], [cams[nb[i][0]]], None, None)) for i in range(len(cams))]
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        t0 = time.perf_counter()
        for sgbm, left, right in pairs:
            sgbm.compute(left, right)
        return time.perf_counter() - t0
    finally:
        cv2.setNumThreads(threads)


@pytest.mark.benchmark(group="mvs-stage-1024")
def test_mvs_stage_at_1024_px_on_one_thread(benchmark, case_1024, tmp_path):
    """The whole stage with its defaults (``plantbench reconstruct CASE --method mvs`` on one thread: the depth
    search of the 20 views, the filter, fusion and the ground) beside a bare SGBM on one rectified pair per view
    (the raw library's stereo matching of the same views, on one disparity axis where ours sweeps slanted planes over
    four neighbours). Issue 64's target: <= 100 s a plant; the ratio is asserted, the seconds printed."""
    import subprocess
    import sys

    bare = _bare_sgbm_pairs(case_1024)
    env = {**os.environ, "PLANTBENCH_THREADS": "1"}
    cmd = [str(Path(sys.executable).parent / "plantbench"), "reconstruct", str(case_1024), "--method", "mvs"]

    def stage():
        out = tmp_path / f"mvs-{time.monotonic_ns()}"
        subprocess.run([*cmd, "--out", str(out)], env=env, check=True, capture_output=True)
        return out

    out = benchmark.pedantic(stage, rounds=1, iterations=1)
    import json

    timings = json.loads((out / "mvs.json").read_text())["timings"]
    ours = timings["total"]  # inside the process: without the interpreter's start and imports
    benchmark.extra_info.update(stage_s=ours, bare_sgbm_pairs_s=bare, ratio=ours / bare, **{
        f"{k}_s": v for k, v in timings.items() if k != "total"})
    print(f"\nmvs stage at 1024 px, one thread: {ours:.1f} s (depth {timings['depth']:.1f}, filter "
          f"{timings['filter']:.1f}; issue target 100 s) / bare SGBM on 20 pairs {bare:.2f} s = {ours / bare:.1f} "
          f"(bound {MAX_STAGE_1024_RATIO:.0f})")
    assert ours / bare <= MAX_STAGE_1024_RATIO
