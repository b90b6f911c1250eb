"""The sample views copied next to a report: at most SAMPLE_VIEW_PX on the longer side, area-averaged."""

from __future__ import annotations

import json

import numpy as np
from PIL import Image

from plantbench.report.report import SAMPLE_VIEW_PX, _sample_views


def test_sample_views_are_area_averaged_down_to_the_report_size(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    rng = np.random.default_rng(0)
    sizes = {"big": (1024, 768), "small": (256, 256)}
    cells = []
    for case, (w, h) in sizes.items():
        img_dir = tmp_path / case / "views" / "images"
        img_dir.mkdir(parents=True)
        Image.fromarray(rng.integers(0, 256, (h, w, 3), dtype=np.uint8)).save(img_dir / "0000.png")
        cells.append({"case": case, "capture": f"../{case}", "recon": f"../{case}"})
    (run / "cells.json").write_text(json.dumps(cells))
    out = tmp_path / "report"
    (out / "figures").mkdir(parents=True)
    rels = _sample_views(run, out)
    assert rels == ["figures/view_big.png", "figures/view_small.png"]
    big = np.asarray(Image.open(out / rels[0]), np.float64)
    assert big.shape == (384, SAMPLE_VIEW_PX, 3)
    src = np.asarray(Image.open(tmp_path / "big" / "views" / "images" / "0000.png"), np.float64)
    box = src.reshape(384, 2, 512, 2, 3).mean(axis=(1, 3))  # a 2 x 2 box mean: what area averaging gives
    assert np.abs(big - box).max() <= 0.5 + 1e-9
    assert (out / rels[1]).read_bytes() == (tmp_path / "small" / "views" / "images" / "0000.png").read_bytes()
