"""Leaf segmentation and fitting speed (issue 9) beside the raw library doing part of the same work:

- leaves: ``segment_and_fit`` on one plant (laurel at scale 0.3, ~1000 leaves), 20 views at 512x512, exact depth
  (the oracle mode, so the timing excludes multi-view stereo). Target: <= 60 s.
- slic: bare scikit-image ``rgb2lab`` + ``slic`` on the same 20 images at the same superpixel count, the first step
  of the pipeline, for scale.

Run ``pytest bench/test_bench_leaves.py --benchmark-only -s``; the last test prints the numbers.
"""

from __future__ import annotations

import numpy as np
import pytest

_results: dict[str, float] = {}
LEAF_LENGTH = 0.08  # laurel's leaves.length


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    from plantbench.capture import CaptureOptions, capture_case
    from plantbench.generate import generate_case

    folder = tmp_path_factory.mktemp("bench_leaves") / "case"
    generate_case("laurel", 1, folder, scale=0.3)
    capture_case(folder, CaptureOptions(views=20, width=512, height=512, spp=4, scan=False), seed=1)
    return folder


def test_bench_segment_and_fit(benchmark, capture):
    from reference_impl.leaves import segment_and_fit

    res = benchmark.pedantic(lambda: segment_and_fit(capture / "views", oracle_depth=True,
                                                     leaf_length_hint=LEAF_LENGTH, seed=0), rounds=1, iterations=1)
    _results["leaves"] = benchmark.stats.stats.min
    _results["count"] = len(res.leaves)
    _results.update({f"stage_{k}": v for k, v in res.stats["timings"].items()})
    assert len(res.leaves) > 0


def test_bench_bare_slic(benchmark, capture):
    from PIL import Image
    from skimage.color import rgb2lab
    from skimage.segmentation import slic

    from plantbench.cameras import read_cameras

    views = capture / "views"
    cams, names = read_cameras(views / "cameras.json")
    images = [np.asarray(Image.open(views / "images" / n).convert("RGB")) for n in names]
    depths = [np.load(views / "depth" / (n[:-4] + ".npy")) for n in names]
    counts = []
    for d, cam in zip(depths, cams, strict=True):  # the pipeline's superpixel count for this view
        fin = np.isfinite(d)
        zmed = float(np.median(d[fin]))
        leaf_px = 0.35 * LEAF_LENGTH**2 * cam.K[0, 0] * cam.K[1, 1] / zmed**2
        counts.append(int(fin.sum() / max(12.0, leaf_px / 40.0)))

    def run():
        for img, n in zip(images, counts, strict=True):
            slic(rgb2lab(img), n_segments=n, compactness=10.0, convert2lab=False, channel_axis=-1, start_label=1)

    benchmark.pedantic(run, rounds=1, iterations=1)
    _results["slic"] = benchmark.stats.stats.min


def test_report():
    if "leaves" not in _results or "slic" not in _results:
        pytest.skip("run the benchmarks first")
    print(f"\nleaves: {_results['leaves']:.1f} s for 20 views ({_results['count']} leaves; target <= 60 s); "
          f"bare SLIC on the same images {_results['slic']:.1f} s (ratio {_results['leaves'] / _results['slic']:.1f})")
    print({k: round(v, 2) for k, v in _results.items() if k.startswith("stage_")})
