"""Leaf segmentation and fitting speed (issue 9) beside the raw scikit-image call it wraps:

- ``segment_and_fit`` on one plant (laurel at scale 0.3, ~1600 leaves), 20 views at 512x512, exact depth (the oracle
  mode, so the timing excludes multi-view stereo), vs bare scikit-image ``rgb2lab`` + ``slic`` on the same 20 images
  at the pipeline's superpixel counts (a fixture), the first step of the pipeline. Issue target: <= 60 s.
- its segmentation stage (SLIC on colour and depth, a plane per superpixel, the affinity graph; the stage timing the
  pipeline reports) vs the same bare SLIC.

Each ratio is printed and bounded. The bounds catch a regression on a noisy shared 2-core machine; the absolute
target is judged on a quiet one. Run ``pytest bench/test_bench_leaves.py --benchmark-only -s``.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

LEAF_LENGTH = 0.08  # laurel's leaves.length

MAX_PIPELINE_RATIO = 16.0
"""segment_and_fit / bare SLIC. Measured 6.5 on the shared 2-core machine (42.8 s against 6.6 s; ground, candidates,
ICP refinement and fitting ~1600 leaves are the rest of the pipeline); about 2.5x the measurement."""
MAX_SEGMENT_RATIO = 6.0
"""Segmentation stage / bare SLIC. Measured 2.35 (the 4-channel SLIC, a plane per superpixel and the affinity graph);
about 2.5x the measurement."""


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    from plantbench.capture import CaptureOptions, capture_case
    from plantbench.generate import generate_case

    folder = tmp_path_factory.mktemp("bench_leaves") / "case"
    generate_case("laurel", 1, folder, scale=0.3)
    capture_case(folder, CaptureOptions(views=20, width=512, height=512, spp=4, scan=False), seed=1)
    return folder


@pytest.fixture(scope="module")
def bare_slic_s(capture) -> float:
    """Seconds of bare ``rgb2lab`` + ``slic`` on the capture's 20 images at the superpixel count the pipeline uses
    for each view (``superpixels_per_leaf`` and ``min_superpixel_px`` of the default LeafParams)."""
    from PIL import Image
    from skimage.color import rgb2lab
    from skimage.segmentation import slic

    from plantbench.cameras import read_cameras

    views = capture / "views"
    cams, names = read_cameras(views / "cameras.json")
    images = [np.asarray(Image.open(views / "images" / n).convert("RGB")) for n in names]
    depths = [np.load(views / "depth" / (n[:-4] + ".npy")) for n in names]
    counts = []
    for d, cam in zip(depths, cams, strict=True):
        fin = np.isfinite(d)
        zmed = float(np.median(d[fin]))
        leaf_px = 0.35 * LEAF_LENGTH**2 * cam.K[0, 0] * cam.K[1, 1] / zmed**2
        counts.append(int(fin.sum() / max(12.0, leaf_px / 40.0)))
    t0 = time.perf_counter()
    for img, n in zip(images, counts, strict=True):
        slic(rgb2lab(img), n_segments=n, compactness=10.0, convert2lab=False, channel_axis=-1, start_label=1)
    return time.perf_counter() - t0


@pytest.mark.benchmark(group="leaves-20-views-512")
def test_segment_and_fit_vs_bare_slic(benchmark, capture, bare_slic_s):
    from reference_impl.leaves import segment_and_fit

    res = benchmark.pedantic(segment_and_fit, args=(capture / "views",),
                             kwargs={"oracle_depth": True, "leaf_length_hint": LEAF_LENGTH, "seed": 0},
                             rounds=1, iterations=1)
    assert len(res.leaves) > 0
    ours = benchmark.stats.stats.min
    stages = res.stats["timings"]
    ratio, segment_ratio = ours / bare_slic_s, stages["segment"] / bare_slic_s
    benchmark.extra_info.update(bare_slic_s=bare_slic_s, ratio=ratio, segment_ratio=segment_ratio,
                                leaves=len(res.leaves), **{f"stage_{k}": v for k, v in stages.items()})
    print(f"\nleaves: segment_and_fit {ours:.1f} s for 20 views ({len(res.leaves)} leaves; issue target <= 60 s) / "
          f"bare SLIC {bare_slic_s:.1f} s = {ratio:.1f} (bound {MAX_PIPELINE_RATIO}); segmentation stage "
          f"{stages['segment']:.1f} s / bare SLIC = {segment_ratio:.2f} (bound {MAX_SEGMENT_RATIO})")
    print({k: round(v, 2) for k, v in stages.items()})
    assert ratio <= MAX_PIPELINE_RATIO
    assert segment_ratio <= MAX_SEGMENT_RATIO
