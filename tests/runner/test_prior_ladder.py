"""The no-data prior and the calibration ladder: what they read, what they write, deterministic per seed; the
calibration verdict on hand-made ladders."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from plantbench.errors import InputError
from plantbench.generate.case import grow_species
from plantbench.hints import load_hint, write_hint
from plantbench.io.plantio import read_reconstruction
from plantbench.io.ply import write_points
from plantbench.methods.inputs import is_oracle, reads_ground_truth
from plantbench.methods.ladder import RUNGS, build_rung, jitter, move_leaves, other_species, prune
from plantbench.methods.prior import SpeciesPrior, cloud_height, grow_prior
from plantbench.plant import TriMesh
from plantbench.report.calibration import LADDER, plant_checks, verdicts
from plantbench.seeding import rng as seeded


@pytest.fixture(scope="module")
def laurel():
    return grow_species("laurel", 1, scale=0.2)[0]


def test_prior_is_a_marked_oracle_that_reads_no_ground_truth():
    m = SpeciesPrior()
    assert is_oracle(m) and not reads_ground_truth(m) and m.inputs == "points"


def test_prior_refuses_without_a_hint(tmp_path):
    write_points(tmp_path / "points.ply", np.array([[0, 0, 0.0], [0, 0, 1.0]]))
    with pytest.raises(InputError, match="species hint"):
        SpeciesPrior().reconstruct(tmp_path, tmp_path / "out", seed=0)


def test_prior_takes_the_height_of_the_cloud_and_nothing_else(tmp_path):
    pts = np.random.default_rng(0).uniform([-0.3, -0.3, 0], [0.3, 0.3, 0.9], (5000, 3))
    write_points(tmp_path / "points.ply", pts)
    write_hint(tmp_path, load_hint("laurel"))
    SpeciesPrior().reconstruct(tmp_path, tmp_path / "a", seed=3)
    SpeciesPrior().reconstruct(tmp_path, tmp_path / "b", seed=3)
    SpeciesPrior().reconstruct(tmp_path, tmp_path / "c", seed=4)
    a, b, c = (read_reconstruction(tmp_path / k) for k in "abc")
    z = np.concatenate([a.skeleton.positions[:, 2], a.mesh.vertices[:, 2]])
    assert z.max() == pytest.approx(cloud_height(pts)) and np.quantile(pts[:, 2], 0.999) == cloud_height(pts)
    assert np.allclose(a.skeleton.positions[a.skeleton.roots][:, :2], 0, atol=1e-9)  # root at the origin
    for name in ("skeleton.ply", "mesh.ply", "leaves.json"):  # same seed, same bytes; another seed, another tree
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
    assert len(c.skeleton) != len(a.skeleton) or not np.allclose(c.skeleton.positions, a.skeleton.positions)
    assert len(a.leaves) > 0


def test_prior_grows_a_small_plant_of_the_species_for_a_small_height():
    full = grow_prior("laurel", 0, 10.0)
    small = grow_prior("laurel", 0, 0.3)
    assert full.height == pytest.approx(10.0) and small.height == pytest.approx(0.3)
    assert len(small.leaves) < len(full.leaves)  # not the full-size tree shrunk: fewer leaves of a small plant
    with pytest.raises(InputError):
        grow_prior("laurel", 0, 0.0)


def test_scaled_plant(laurel):
    s = laurel.scaled(2.0)
    assert s.height == pytest.approx(2 * laurel.height)
    assert np.allclose(s.skeleton.radii, 2 * laurel.skeleton.radii)
    assert np.allclose([lf.centroid for lf in s.leaves], 2 * np.array([lf.centroid for lf in laurel.leaves]))
    with pytest.raises(InputError):
        laurel.scaled(0.0)


def test_prune_keeps_orders_and_their_leaves(laurel):
    sk = laurel.skeleton
    for k in (0, 1, 2):
        p = prune(laurel, k)
        assert len(p.skeleton) == int((sk.order <= k).sum()) and p.skeleton.order.max() <= k
        assert p.skeleton.is_forest()
        kept = {lf.id for lf in laurel.leaves if sk.order[lf.node] <= k}
        assert {lf.id for lf in p.leaves} == kept
        assert set(np.unique(p.leaf_mesh_ids)) <= kept
        # kept nodes keep their positions: every pruned position is one of the originals
        assert np.isin(p.skeleton.positions.view([("", float)] * 3), sk.positions.view([("", float)] * 3)).all()


def test_jitter_moves_nodes_by_the_fraction_and_leaves_with_them(laurel):
    j = jitter(laurel, 0.01, seeded(0, "t"))
    off = j.skeleton.positions - laurel.skeleton.positions
    rms = np.sqrt((off ** 2).sum(1).mean())
    assert rms == pytest.approx(0.01 * laurel.height, rel=0.1)
    for a, b in list(zip(laurel.leaves, j.leaves))[:50]:
        assert np.allclose(b.centroid - a.centroid, off[a.node])
    assert len(j.branch_mesh.faces) > 0


def test_move_leaves_by_fraction_of_length(laurel):
    m = move_leaves(laurel, 0.25, seeded(0, "t"))
    d = np.linalg.norm([b.centroid - a.centroid for a, b in zip(laurel.leaves, m.leaves)], axis=1)
    assert np.allclose(d, [0.25 * lf.length for lf in laurel.leaves])
    assert np.array_equal(m.skeleton.positions, laurel.skeleton.positions)


def test_rungs_deterministic_per_seed(laurel):
    for name in ("jitter-0.5%", "leaves-25%", "prior-a"):
        a, b = build_rung(name, laurel, "laurel", 7), build_rung(name, laurel, "laurel", 7)
        assert np.array_equal(a.skeleton.positions, b.skeleton.positions)
        assert np.array_equal(TriMesh.concatenate([a.branch_mesh, a.leaf_mesh]).vertices,
                              TriMesh.concatenate([b.branch_mesh, b.leaf_mesh]).vertices)
    c = build_rung("jitter-0.5%", laurel, "laurel", 8)
    assert not np.array_equal(c.skeleton.positions, build_rung("jitter-0.5%", laurel, "laurel", 7).skeleton.positions)
    assert other_species("laurel") != "laurel"
    assert set(LADDER) == set(RUNGS)
    with pytest.raises(InputError, match="did you mean"):
        build_rung("jiter-0.5%", laurel, "laurel", 0)


def _ladder_table(values_per_case: dict[str, dict[str, float]], metric: str) -> pd.DataFrame:
    rows = [{"case": case, "method": f"ladder:{rung}", "metric": metric, "value": v, "status": "ok"}
            for case, rungs in values_per_case.items() for rung, v in rungs.items()]
    return pd.DataFrame(rows)


def test_verdict_on_hand_made_ladders():
    good = {"gt": 1.0, "orders<=3": 0.9, "orders<=2": 0.8, "orders<=1": 0.6, "prior-a": 0.3, "prior-b": 0.35,
            "jitter-0.25%": 0.98, "jitter-0.5%": 0.9, "jitter-1%": 0.7, "jitter-2%": 0.4}
    assert all(plant_checks(good, True).values())
    assert all(plant_checks(dict(good, **{"orders<=3": 1.0, "orders<=2": 1.0}), True).values())  # nothing to prune
    assert not plant_checks(dict(good, **{"orders<=1": 1.0}), True)["pruning monotone"]  # pruning must cost
    blind = dict(good, **{"orders<=1": 0.95})  # a metric that prefers the more pruned tree (one-way distance)
    assert not plant_checks(blind, True)["pruning monotone"]
    species_like = dict(good, **{"prior-a": 0.85, "prior-b": 0.9})  # the prior beats pruning: fails
    checks = plant_checks(species_like, True)
    assert not checks["orders<=2>prior"] and not checks["jitter-0.5%>prior"] and checks["jitter monotone"]
    t = _ladder_table({f"p{i}": (species_like if i == 0 else good) for i in range(10)}, "skeleton.vf1@1%")
    v = verdicts(t).set_index("metric").loc["skeleton.vf1@1%"]
    assert v["plants"] == 10 and v["passed"] == 9 and v["verdict"] == "discriminates"  # 9 of 10
    t = _ladder_table({f"p{i}": (species_like if i < 2 else good) for i in range(10)}, "skeleton.vf1@1%")
    assert verdicts(t).set_index("metric").loc["skeleton.vf1@1%", "verdict"] == "does not discriminate"
    # a lower-is-better metric: the same ladder mirrored
    t = _ladder_table({f"p{i}": {k: 1 - v for k, v in good.items()} for i in range(10)}, "mesh_to_surface.D_cm")
    assert verdicts(t).set_index("metric").loc["mesh_to_surface.D_cm", "verdict"] == "discriminates"
    missing = dict(good)
    del missing["prior-b"]
    assert not plant_checks(missing, True)["orders<=2>prior"]  # a missing value fails


def test_calibration_files_and_the_reports_note(tmp_path):
    from plantbench.report.calibration import LADDER_FILE, write_calibration
    from plantbench.report.report import calibration_note

    good = {"gt": 1.0, "orders<=3": 0.9, "orders<=2": 0.72, "orders<=1": 0.4, "prior-a": 0.76, "prior-b": 0.78,
            "jitter-0.25%": 0.6, "jitter-0.5%": 0.57, "jitter-1%": 0.55, "jitter-2%": 0.5}
    t = _ladder_table({f"p{i}": good for i in range(3)}, "stava.S_T").assign(species="s", family="f")
    verdict, files = write_calibration(t, tmp_path)
    assert (tmp_path / LADDER_FILE).is_file() and all(f.is_file() for f in files)
    assert verdict.set_index("metric").loc["stava.S_T", "verdict"] == "does not discriminate"
    back = pd.read_csv(tmp_path / LADDER_FILE)
    assert len(back) == len(t) and set(back["rung"]) == set(good)
    note = calibration_note(tmp_path)
    assert "0.77" in note and "0.72" in note and "0.57" in note
