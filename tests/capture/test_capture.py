"""capture_case: files, settings record, errors on bad input, atomic replacement, determinism."""

from __future__ import annotations

import json

import numpy as np
import pytest

from plantbench.capture import CaptureOptions, as_options, capture_case, is_complete
from plantbench.capture import capture as capture_mod
from plantbench.errors import InputError
from plantbench.suites import CaptureSettings
from tests.capture.conftest import SETTINGS
from tests.capture.plants import write_test_plant

TINY = CaptureOptions(views=2, width=32, height=24, spp=2, angular_step_deg=0.5, colmap_points=200)


def test_capture_writes_the_contract(captured):
    case, _ = captured
    v = case / "views"
    n = SETTINGS.views
    assert sorted(p.name for p in (v / "images").iterdir()) == [f"{i:04d}.png" for i in range(n)]
    assert len(list((v / "depth").glob("*.npy"))) == n and len(list((v / "instance").glob("*.png"))) == n
    from PIL import Image

    inst = np.array(Image.open(v / "instance" / "0000.png"))
    fol = np.array(Image.open(v / "foliage" / "0000.png"))
    assert fol.dtype == np.uint8 and np.array_equal(fol == 255, inst >= 2) and fol.any()
    for name in ("cameras.txt", "images.txt", "points3D.txt"):
        assert (v / "colmap" / name).is_file()
    doc = json.loads((v / "capture.json").read_text())
    assert doc["settings"] == SETTINGS.model_dump(mode="json") and doc["seed"] == 7
    assert doc["mitsuba_variant"] in ("llvm_ad_rgb", "scalar_rgb")
    assert is_complete(case)
    assert not [p for p in case.iterdir() if p.name.startswith(".")]  # no temporary folders left
    # leaf sizes: counted again here from the written instance maps, pixel by pixel
    n_leaves = doc["leaf_pixels"]["leaves"]
    counts = {}
    for i in range(n):
        for value in np.array(Image.open(v / "instance" / f"{i:04d}.png")).ravel().tolist():
            if value >= 2:
                counts[(value - 2, i)] = counts.get((value - 2, i), 0) + 1
    assert counts and doc["leaf_pixels"]["median_px"] == float(np.median(list(counts.values())))
    assert doc["leaf_pixels"]["visible"] == len({leaf for leaf, _ in counts})
    resolved = [leaf for leaf in range(n_leaves)
                if sum(counts.get((leaf, i), 0) >= doc["leaf_pixels"]["resolved_px"] for i in range(n)) >= 2]
    assert doc["leaf_pixels"]["resolved_2_views"] == len(resolved)


def test_settings_accept_suite_settings_and_reject_nonsense():
    suite = CaptureSettings(views=5, width=64, height=48)
    opts = as_options(suite)
    assert (opts.views, opts.width, opts.height) == (5, 64, 48)
    assert as_options(suite.model_dump(mode="json")) == opts
    assert as_options(None) == CaptureOptions()
    with pytest.raises(InputError, match="elevation"):
        as_options({"elevation": (50, 10)})
    with pytest.raises(InputError, match="unknown|bogus"):
        as_options({"bogus": 1})


def test_missing_or_corrupt_plant_is_a_clear_error(tmp_path):
    with pytest.raises(InputError, match="plant"):
        capture_case(tmp_path / "nowhere", TINY, seed=0)
    case = tmp_path / "case"
    write_test_plant(case, height=1.0, branches=2, leaves_per_branch=2)
    (case / "plant" / "leaves.ply").write_bytes(b"ply\nformat garbage\n")
    with pytest.raises(InputError, match="leaves.ply"):
        capture_case(case, TINY, seed=0)
    assert not (case / "views").exists() and not (case / "scan").exists()


def test_a_failed_capture_leaves_the_previous_one(tmp_path, monkeypatch):
    case = tmp_path / "case"
    write_test_plant(case, height=1.0, branches=2, leaves_per_branch=2)
    capture_case(case, TINY, seed=0)
    before = (case / "views" / "capture.json").read_bytes()

    def boom(*args, **kwargs):
        raise RuntimeError("disk full")

    monkeypatch.setattr(capture_mod, "write_transforms", boom)
    with pytest.raises(RuntimeError, match="disk full"):
        capture_case(case, TINY.model_copy(update={"views": 3}), seed=1)
    assert (case / "views" / "capture.json").read_bytes() == before
    assert len(list((case / "views" / "images").iterdir())) == 2
    assert not [p for p in case.iterdir() if p.name.startswith(".")]


def test_same_seed_same_bytes_and_no_scan_removes_scan(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    for c in (a, b):
        write_test_plant(c, height=1.0, branches=2, leaves_per_branch=2)
        capture_case(c, TINY, seed=5)
    for rel in ("views/images/0000.png", "views/depth/0001.npy", "views/instance/0000.png", "views/cameras.json",
                "views/colmap/points3D.txt", "views/transforms.json", "scan/scan.ply", "scan/stations.json"):
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel
    capture_case(a, TINY.model_copy(update={"scan": False}), seed=6)
    assert not (a / "scan").exists() and is_complete(a)
    img6 = np.load(a / "views" / "depth" / "0000.npy")
    assert img6.shape == (24, 32)
