"""Every shipped points method gives the same reconstruction for its input cloud's points in another order (the
variability study's `order` run; docs/tuning/determinism.md), through the registered method and its input folder."""

from __future__ import annotations

import numpy as np
import pytest

from plantbench.geometry.clouds import canonical_order
from plantbench.io.ply import read_points, write_points
from plantbench.methods.api import method_from_spec
from plantbench.methods.inputs import (
    PERTURB_ENV,
    InputPerturbation,
    input_perturbation,
    perturb_points,
    prepare_inputs,
)
from tests.baselines.synthetic import random_tree, sample_surface


@pytest.fixture(scope="module")
def clouds(tmp_path_factory):
    """A small synthetic tree's cloud, as written and with its rows shuffled (each with the species hint)."""
    from plantbench.hints import load_hint, write_hint

    rng = np.random.default_rng(11)
    pts = sample_surface(rng, random_tree(rng, height=1.2, levels=2, segment=0.04), 12000, noise=0.001,
                         ground=1500, ground_radius=0.8)
    out = {}
    for name, cloud in (("as-written", pts), ("shuffled", pts[rng.permutation(len(pts))])):
        d = tmp_path_factory.mktemp(name)
        write_points(d / "points.ply", cloud)
        write_hint(d, load_hint("laurel"))
        out[name] = d
    return out


@pytest.mark.parametrize("name", ["livny", "xu", "guo", "prior"])
def test_a_shuffled_cloud_gives_the_same_reconstruction(clouds, tmp_path, name):
    method = method_from_spec(name)
    for which, folder in clouds.items():
        method.reconstruct(folder, tmp_path / which, seed=3, species="laurel")
    written = sorted(p.name for p in (tmp_path / "as-written").iterdir() if p.suffix in (".ply", ".json"))
    assert "skeleton.ply" in written
    for f in written:
        if f.endswith("guo.json"):  # its timings differ from run to run
            continue
        assert (tmp_path / "as-written" / f).read_bytes() == (tmp_path / "shuffled" / f).read_bytes(), f


def test_canonical_order_is_the_sort_of_cells_then_coordinates():
    rng = np.random.default_rng(2)
    pts = rng.uniform(-0.01, 0.01, (400, 3))
    pts[:50] = pts[50:100]  # exact duplicates
    order = canonical_order(pts)
    naive = sorted(range(len(pts)), key=lambda i: (*np.floor(pts[i] / 1e-3), *pts[i]))
    np.testing.assert_array_equal(pts[order], pts[naive])
    shuffled = pts[rng.permutation(len(pts))]
    np.testing.assert_array_equal(shuffled[canonical_order(shuffled)], pts[order])
    # a 1e-6 m move swaps only points of one cell or of neighbouring cells: the order stays local in space
    moved = pts + rng.uniform(-1e-6, 1e-6, pts.shape)
    same_place = np.linalg.norm(moved[canonical_order(moved)] - pts[order], axis=1)
    assert np.mean(same_place < 1e-5) > 0.9


def test_the_study_perturbs_a_points_method_input(tmp_path, monkeypatch):
    rng = np.random.default_rng(5)
    pts = rng.uniform(0, 1, (500, 3)).astype(np.float32).astype(np.float64)  # points.ply holds float32
    (tmp_path / "points").mkdir()
    write_points(tmp_path / "points" / "points.ply", pts)
    (tmp_path / "case").mkdir()

    def given(spec):
        monkeypatch.setenv(PERTURB_ENV, spec)
        dest = tmp_path / spec.replace(":", "_")
        prepare_inputs(dest, tmp_path / "case", "points", points_dir=tmp_path / "points")
        return read_points(dest / "points.ply")[0]

    shuffled = given("order:1")
    assert not np.array_equal(shuffled, pts)
    np.testing.assert_array_equal(np.sort(shuffled, axis=0), np.sort(pts, axis=0))
    moved = given("jitter:1e-6:1")
    assert 0 < np.abs(moved - pts).max() <= 1e-6 + 6e-8 and np.abs(moved - pts).mean() > 2e-7  # float32 steps
    monkeypatch.setenv(PERTURB_ENV, "jitter:1e-6:1")
    again = prepare_inputs(tmp_path / "again", tmp_path / "case", "points", points_dir=tmp_path / "points")
    np.testing.assert_array_equal(moved, read_points(again / "points.ply")[0])  # seeded: the same draw again
    monkeypatch.setenv(PERTURB_ENV, "jitter:x")
    with pytest.raises(Exception, match=PERTURB_ENV):
        input_perturbation()
    cols = np.arange(5)
    p2, c2 = perturb_points(pts[:5], InputPerturbation("order", 4), "k", columns=cols)
    np.testing.assert_array_equal(p2, pts[:5][c2])


def test_leaves_give_the_same_leaves_for_a_shuffled_cloud(tmp_path):
    """The leaf method reads the views and the mvs stage's depth maps beside the cloud, not the cloud's order."""
    from PIL import Image

    from plantbench.cameras import write_cameras
    from plantbench.hints import load_hint, write_hint
    from tests.leaves.conftest import render_flat_leaves, ring_cameras, scattered_leaves

    rng = np.random.default_rng(4)
    leaves = scattered_leaves(4, rng)
    cams = ring_cameras(4, radius=0.55, height=0.45, size=128)
    rendered = [render_flat_leaves(leaves, cam, rng) for cam in cams]
    surface = rng.uniform(-0.1, 0.1, (3000, 3)) + [0, 0, 0.2]
    out = {}
    for which, cloud in (("as-written", surface), ("shuffled", surface[rng.permutation(len(surface))])):
        d = tmp_path / which / "input"
        (d / "views" / "images").mkdir(parents=True)
        (d / "depth").mkdir()
        names = []
        for i, (z, _, rgb) in enumerate(rendered):
            names.append(f"{i:04d}.png")
            Image.fromarray(rgb).save(d / "views" / "images" / names[-1])
            np.save(d / "depth" / f"{i:04d}.npy", z)
        write_cameras(d / "views" / "cameras.json", cams, names)
        write_points(d / "points.ply", cloud)
        write_hint(d, load_hint("laurel"))
        method_from_spec("leaves").reconstruct(d, tmp_path / which / "out", seed=2, species="laurel")
        out[which] = tmp_path / which / "out"
    assert (out["as-written"] / "leaves.json").read_text().count('"id"') >= 1
    for f in ("leaves.json", "points.ply"):
        assert (out["as-written"] / f).read_bytes() == (out["shuffled"] / f).read_bytes(), f


def test_a_perturbed_input_is_another_method_job_on_the_same_capture(monkeypatch):
    """The study's order and jitter runs re-run the methods, never the plant, capture or mvs stage."""
    from plantbench.runner.plan import make_plan
    from plantbench.suites import load_suite

    def keys():
        plan = make_plan(load_suite("quick"))
        return {kind: {k for k, j in plan.jobs.items() if j.kind == kind and j.params.get("method") != "mvs"}
                for kind in ("plant", "capture", "method")}

    monkeypatch.delenv(PERTURB_ENV, raising=False)
    plain = keys()
    monkeypatch.setenv(PERTURB_ENV, "jitter:1e-6:1")
    jittered = keys()
    assert plain["plant"] == jittered["plant"] and plain["capture"] == jittered["capture"]
    assert plain["method"] and not plain["method"] & jittered["method"]
