"""The leaves report's depth measure against hand-counted pixels."""

from __future__ import annotations

import json

import numpy as np
import pytest

from plantbench.cameras import look_at, write_cameras


def test_leaf_depth_accuracy_counts_by_hand(tmp_path):
    """Two views of a plant 2 m high (tolerance 1 % = 2 cm): view 0 has 4 leaf pixels, one exact, one 1 cm off,
    one 3 cm off and one without a depth; view 1 has 2 leaf pixels, both exact, and wood pixels that never count."""
    from PIL import Image

    from plantbench.report.leaves import leaf_depth_accuracy
    from tests.capture.plants import write_test_plant

    case = tmp_path / "case"
    write_test_plant(case, height=2.0, branches=2, leaves_per_branch=1)
    height = json.loads((case / "plant" / "plant.json").read_text())["height"]
    cam = look_at((3.0, 0.0, 1.0), (0.0, 0.0, 1.0), fov_x_deg=40.0, width=4, height=2)
    views = case / "views"
    (views / "instance").mkdir(parents=True)
    (views / "depth").mkdir()
    write_cameras(views / "cameras.json", [cam, cam], ["0000.png", "0001.png"])
    exact = np.full((2, 4), 3.0, np.float32)
    inst0 = np.array([[2, 3, 4, 5], [0, 1, 1, 0]], np.uint16)
    inst1 = np.array([[2, 2, 1, 1], [0, 0, 0, 0]], np.uint16)
    tol = 0.01 * height
    est0 = np.array([[3.0, 3.0 + 0.5 * tol, 3.0 + 1.5 * tol, np.nan], [3, 3, 3, 3]], np.float32)
    est1 = np.full((2, 4), 3.0, np.float32)
    est1[0, 2] = np.nan  # a wood pixel without depth: not counted
    for i, inst in enumerate((inst0, inst1)):
        Image.fromarray(inst).save(views / "instance" / f"{i:04d}.png")
        np.save(views / "depth" / f"{i:04d}.npy", exact)
    (tmp_path / "est").mkdir()
    np.savez_compressed(tmp_path / "est" / "0000.npz", depth=est0)
    np.save(tmp_path / "est" / "0001.npy", est1)
    got = leaf_depth_accuracy(case, tmp_path / "est")
    assert got["views"] == 2 and got["leaf_pixels"] == 6
    assert got["within"] == pytest.approx(4 / 6) and got["kept"] == pytest.approx(5 / 6)
    assert got["within_of_kept"] == pytest.approx(4 / 5)
    assert got["within_median"] == pytest.approx(np.median([2 / 4, 1.0]))
    assert got["kept_median"] == pytest.approx(np.median([3 / 4, 1.0]))
