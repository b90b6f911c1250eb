"""Capture speed beside the raw libraries doing the same work (issue 4). Each benchmark times the raw library on the
same scene itself (a fixture), prints the ratio and fails beyond a bound:

- views: ``capture_case`` (scan off: placement, textures, scene, 20 path-traced 512x512 views at 16 spp, PNGs,
  exact maps, COLMAP model, transforms.json) vs a bare ``mi.load_dict`` + 20 x ``mi.render`` of the same scene dict
  at the same settings. Issue target: ratio <= 1.5.
- views at 1024 px (issue 64): ``capture_case`` at the multiview suites' capture (1024 px, 4 spp, denoised; scan
  off) vs the bare Mitsuba renders that capture needs: ``mi.load_dict`` + per view ``mi.render`` of the colour and
  ``mi.render`` of the denoiser's guides (the ``aov`` integrator alone), same scene, samples and seeds. The rest of
  the capture is Open Image Denoise, the exact maps, the PNGs and the files. Issue target: ratio <= 1.2.
- maps: the exact depth/instance maps of the 20 views alone, as a fraction of the bare render. Issue target: <= 10 %.
- scan: ``scan_plant`` (beam grid, casting, noise, dropout, labels) in beams per second vs open3d's
  ``RaycastingScene.cast_rays`` on the same mesh and the same beams. Issue target: >= 0.5x open3d's rays/s.

The bounds asserted are 2-3x the ratios measured and never tighter than the issue's targets: they catch a regression
on a noisy shared 2-core machine, where the targets themselves are judged on a quiet one. Run ``pytest bench/test_bench_capture.py --benchmark-only -s``.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from plantbench.capture import CaptureOptions, capture_case
from plantbench.io.plantio import read_plant

VIEWS = CaptureOptions(views=20, width=512, height=512, spp=16, scan=False)
VIEWS_1024 = CaptureOptions(views=20, width=1024, height=1024, spp=4, denoise=True, scan=False)
SCAN = CaptureOptions(angular_step_deg=0.02)

MAX_VIEWS_RATIO = 2.5
"""capture_case / bare Mitsuba render. Measured 1.09 on the shared 2-core machine (issue 4's target 1.5); about 2.3x
the measurement, so that only a real regression (a second render pass, a slow PNG or map path) fails."""
MAX_VIEWS_1024_RATIO = 2.0
"""capture_case at 1024 px, 4 spp denoised / the bare colour and guide renders (see the module docstring). Measured
1.51 on the 2-core Zen 5 (68.9 s against 45.8 s; 1.74 against the colour renders alone, 39.6 s): Open Image Denoise
(about 0.7 s a view on one thread), the exact maps and the PNGs on the bench's small plant; issue 64's target 1.2 is
not met."""
MAX_MAPS_FRACTION = 0.10
"""Exact maps / bare Mitsuba render. Measured 0.034 (issue 4's target 0.10, which is about 3x the measurement)."""
MIN_SCAN_SPEED = 0.25
"""scan_plant beams/s / open3d cast_rays rays/s. Measured 0.62 (issue 4's target >= 0.5); 2.5x below the
measurement."""


def _seconds(fn, rounds: int = 1) -> float:
    """Shortest wall time of ``rounds`` calls of ``fn``."""
    best = np.inf
    for _ in range(rounds):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def _against(benchmark, bare_s: float) -> tuple[float, float]:
    """The benchmark's best time and its ratio to the raw library's ``bare_s`` (both kept in its extra info)."""
    ours = benchmark.stats.stats.min
    benchmark.extra_info.update(bare_s=bare_s, ratio=ours / bare_s)
    return ours, ours / bare_s


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    """A generated pentagon maple when the generator is available, else the tests' synthetic 4 m plant."""
    folder = tmp_path_factory.mktemp("bench_capture") / "case"
    try:
        from plantbench.generate import generate_case

        generate_case("pentagon_maple", 0, folder, scale=0.5)
    except Exception:  # noqa: BLE001 - no generator: fall back to the synthetic plant
        from tests.capture.plants import write_test_plant

        write_test_plant(folder, height=4.0, branches=12, leaves_per_branch=40)
    return folder


@pytest.fixture(scope="module")
def scene_parts(case):
    from plantbench.backend import load_mitsuba
    from plantbench.capture.scene import scene_dict
    from plantbench.capture.views import place_cameras
    from plantbench.seeding import rng

    mi = load_mitsuba()
    plant, _ = read_plant(case)
    pts = np.concatenate([plant.branch_mesh.vertices, plant.leaf_mesh.vertices])
    cams = place_cameras(pts, VIEWS.views, elevation=VIEWS.elevation, fov_x_deg=VIEWS.fov_deg, width=VIEWS.width,
                         height=VIEWS.height, fill=VIEWS.fill)
    d = scene_dict(plant, cams, VIEWS, rng(0, "capture", "scene"), mi=mi)
    np.asarray(mi.render(mi.load_dict(d), sensor=0, spp=1))  # compile the kernels once, outside the timings
    return mi, plant, cams, d


@pytest.fixture(scope="module")
def bare_render_s(scene_parts) -> float:
    """Seconds of a bare ``mi.load_dict`` + one ``mi.render`` per view at the capture's settings (one round: ~3 min
    on 2 shared cores)."""
    mi, _, cams, d = scene_parts

    def bare():
        scene = mi.load_dict(d)
        imgs = [np.asarray(mi.render(scene, sensor=i, spp=VIEWS.spp, seed=i)) for i in range(len(cams))]
        assert imgs[0].shape == (512, 512, 3)

    return _seconds(bare)


@pytest.fixture(scope="module")
def loaded(scene_parts):
    """The render scene, loaded once, and the ground-truth caster that reuses its BVH (as capture_case does)."""
    from plantbench.capture.views import ground_truth_caster

    mi, plant, _, d = scene_parts
    scene = mi.load_dict(d)
    return scene, ground_truth_caster(plant, scene=scene, scene_dict=d)


@pytest.fixture(scope="module")
def scan_rays(scene_parts):
    """The beams of the default single-station scan at the bench's angular step, and the plant mesh."""
    from plantbench.capture.scan import beam_grid, station_positions

    _, plant, _, _ = scene_parts
    pos = station_positions(plant, SCAN)[0]
    dirs, _ = beam_grid(plant, pos, SCAN)
    verts = np.concatenate([plant.branch_mesh.vertices, plant.leaf_mesh.vertices])
    faces = np.concatenate([plant.branch_mesh.faces, plant.leaf_mesh.faces + len(plant.branch_mesh.vertices)])
    return pos, dirs, verts, faces


@pytest.fixture(scope="module")
def open3d_cast_s(scan_rays) -> float:
    """Seconds of open3d's ``RaycastingScene.cast_rays`` on the plant mesh and the scan's beams (the scene built
    beforehand; best of 3 after a warm-up)."""
    import open3d as o3d

    pos, dirs, verts, faces = scan_rays
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(verts.astype(np.float32)), o3d.core.Tensor(faces.astype(np.uint32)))
    rays = o3d.core.Tensor(np.concatenate([np.broadcast_to(pos, dirs.shape), dirs], 1).astype(np.float32))
    assert np.isfinite(scene.cast_rays(rays)["t_hit"].numpy()).any()
    return _seconds(lambda: scene.cast_rays(rays), rounds=3)


@pytest.mark.benchmark(group="capture-20-views-512-16spp")
def test_capture_views_vs_bare_mitsuba(benchmark, case, bare_render_s):
    benchmark.pedantic(capture_case, args=(case, VIEWS), kwargs={"seed": 0}, rounds=1, iterations=1)
    assert (case / "views" / "capture.json").is_file()
    ours, ratio = _against(benchmark, bare_render_s)
    print(f"\nviews: capture_case / bare mi.render = {ratio:.2f} ({ours:.1f} s vs {bare_render_s:.1f} s; "
          f"bound {MAX_VIEWS_RATIO}, issue target 1.5)")
    assert ratio <= MAX_VIEWS_RATIO


@pytest.mark.benchmark(group="capture-20-views-512-16spp")
def test_exact_maps_vs_bare_mitsuba(benchmark, scene_parts, loaded, bare_render_s):
    from plantbench.capture.views import exact_maps, ground_truth_caster, ground_truth_mesh

    _, plant, cams, d = scene_parts
    scene, _ = loaded

    def maps():
        gt = ground_truth_mesh(plant)
        caster = ground_truth_caster(plant, scene=scene, scene_dict=d)
        return [exact_maps(c, gt, caster) for c in cams]

    out = benchmark.pedantic(maps, rounds=3, iterations=1, warmup_rounds=1)
    assert out[0].depth.shape == (512, 512)
    ours, fraction = _against(benchmark, bare_render_s)
    print(f"\nmaps: exact maps / bare mi.render = {100 * fraction:.1f} % ({ours:.2f} s vs {bare_render_s:.1f} s; "
          f"bound {100 * MAX_MAPS_FRACTION:.0f} %, issue target 10 %)")
    assert fraction <= MAX_MAPS_FRACTION


@pytest.mark.benchmark(group="scan")
def test_scan_vs_open3d_cast_rays(benchmark, scene_parts, loaded, scan_rays, open3d_cast_s):
    from plantbench.capture.scan import scan_plant

    _, plant, _, _ = scene_parts
    _, caster = loaded  # capture_case scans with the render scene's BVH, as open3d's scene here is prebuilt too
    scan = benchmark.pedantic(scan_plant, args=(plant, SCAN, np.random.default_rng(0), caster), rounds=3,
                              iterations=1, warmup_rounds=1)
    beams = scan.stations[0]["beams"]
    assert beams == len(scan_rays[1])
    ours, ratio = _against(benchmark, open3d_cast_s)
    speed = 1.0 / ratio  # as many beams as rays
    print(f"\nscan: {beams / ours / 1e6:.1f} M beams/s vs open3d {beams / open3d_cast_s / 1e6:.1f} M rays/s = "
          f"{speed:.2f}x ({beams} beams; bound >= {MIN_SCAN_SPEED}, issue target >= 0.5)")
    assert speed >= MIN_SCAN_SPEED


@pytest.mark.benchmark(group="capture-20-views-1024-4spp-denoised")
def test_capture_views_1024_denoised_vs_bare_mitsuba(benchmark, case, scene_parts):
    from plantbench.capture.scene import GUIDES_INTEGRATOR, scene_dict
    from plantbench.capture.views import place_cameras
    from plantbench.seeding import rng

    mi, plant, _, _ = scene_parts
    o = VIEWS_1024
    pts = np.concatenate([plant.branch_mesh.vertices, plant.leaf_mesh.vertices])
    cams = place_cameras(pts, o.views, elevation=o.elevation, fov_x_deg=o.fov_deg, width=o.width, height=o.height,
                         fill=o.fill)
    d = scene_dict(plant, cams, o, rng(0, "capture", "scene"), mi=mi)
    guides = mi.load_dict(GUIDES_INTEGRATOR)
    colour_s = []

    def bare():
        scene = mi.load_dict(d)
        t0 = time.perf_counter()
        imgs = [np.asarray(mi.render(scene, sensor=i, spp=o.spp, seed=i)) for i in range(len(cams))]
        colour_s.append(time.perf_counter() - t0)
        aux = [np.asarray(mi.render(scene, sensor=i, spp=o.spp, seed=i, integrator=guides)) for i in range(len(cams))]
        assert imgs[0].shape == (1024, 1024, 3) and aux[0].shape == (1024, 1024, 6)

    bare_s = _seconds(bare)
    benchmark.pedantic(capture_case, args=(case, o), kwargs={"seed": 0}, rounds=1, iterations=1)
    assert (case / "views" / "capture.json").is_file()
    ours, ratio = _against(benchmark, bare_s)
    benchmark.extra_info.update(bare_colour_s=colour_s[0], ratio_to_colour=ours / colour_s[0])
    print(f"\nviews at 1024 px, 4 spp denoised: capture_case / bare colour + guide renders = {ratio:.2f} ({ours:.1f} s "
          f"vs {bare_s:.1f} s; the colour renders alone {colour_s[0]:.1f} s, ratio {ours / colour_s[0]:.2f}; bound "
          f"{MAX_VIEWS_1024_RATIO}, issue target 1.2)")
    assert ratio <= MAX_VIEWS_1024_RATIO
