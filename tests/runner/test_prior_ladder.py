"""The no-data prior and the calibration ladder: what they read, what they write, deterministic per seed; the
calibration verdict on hand-made ladders."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from plantbench.errors import InputError
from plantbench.generate.case import grow_species
from plantbench.geometry.clouds import cloud_base
from plantbench.hints import load_hint, write_hint
from plantbench.io.plantio import read_reconstruction
from plantbench.io.ply import write_points
from plantbench.methods.inputs import is_oracle, reads_ground_truth
from plantbench.methods.ladder import (
    OBSERVED_RUNG,
    RUNGS,
    add_twigs,
    build_rung,
    cut_to_observed,
    jitter,
    move_leaves,
    other_species,
    prune,
    tangle,
)
from plantbench.methods.prior import SpeciesPrior, cloud_height, grow_prior
from plantbench.plant import TriMesh
from plantbench.report.calibration import LADDER, STRUCTURE_CHECKS, VOLUME_CHECKS, plant_checks, verdicts
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


def test_prior_takes_the_height_and_the_base_of_the_cloud_and_nothing_else(tmp_path):
    rng = np.random.default_rng(0)
    stem = np.column_stack([rng.normal(0.4, 0.01, 600), rng.normal(-0.2, 0.01, 600), rng.uniform(0, 0.3, 600)])
    crown = rng.uniform([-0.3, -0.3, 0.3], [0.3, 0.3, 0.9], (4400, 3))
    pts = np.concatenate([crown, stem])  # the stem stands at (0.4, -0.2), not at the origin
    write_points(tmp_path / "points.ply", pts)
    write_hint(tmp_path, load_hint("laurel"))
    SpeciesPrior().reconstruct(tmp_path, tmp_path / "a", seed=3)
    SpeciesPrior().reconstruct(tmp_path, tmp_path / "b", seed=3)
    SpeciesPrior().reconstruct(tmp_path, tmp_path / "c", seed=4)
    a, b, c = (read_reconstruction(tmp_path / k) for k in "abc")
    z = np.concatenate([a.skeleton.positions[:, 2], a.mesh.vertices[:, 2]])
    assert z.max() == pytest.approx(cloud_height(pts)) and np.quantile(pts[:, 2], 0.999) == cloud_height(pts)
    # the root where the cloud stands: the median x, y of its lowest tenth (all stem points here), on z = 0
    low = pts[pts[:, 2] <= np.quantile(pts[:, 2], 0.1)]
    assert len(low) < 600 and np.allclose(cloud_base(pts), [np.median(low[:, 0]), np.median(low[:, 1]), 0.0])
    np.testing.assert_allclose(a.skeleton.positions[a.skeleton.roots][0], cloud_base(pts), atol=1e-6)
    assert np.linalg.norm(cloud_base(pts)[:2] - [0.4, -0.2]) < 0.005
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


def test_prior_moves_by_round_off_when_the_height_does():
    """A 1e-6 m change of the cloud's height scales the same grown plant (the variability study's jitter run): every
    node moves by at most the relative change times its distance from the root."""
    from plantbench.methods.prior import growth_height

    a, b = grow_prior("laurel", 0, 0.6871), grow_prior("laurel", 0, 0.6871 + 1e-6)
    assert len(a.skeleton) == len(b.skeleton) and len(a.leaves) == len(b.leaves)
    np.testing.assert_allclose(b.skeleton.positions, a.skeleton.positions * (0.6871 + 1e-6) / 0.6871, atol=1e-12)
    assert growth_height(0.6871) == pytest.approx(0.6871, rel=0.005) and growth_height(3.0) == growth_height(3.001)
    assert growth_height(3.0) != growth_height(3.1)


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


def _hand_chain_count(skeleton) -> int:
    """Branches (Stava chains) counted by hand: one per edge leaving a root or a fork."""
    kids = skeleton.children_counts()
    return int(sum(k for v, k in enumerate(kids) if skeleton.parents[v] < 0 or k >= 2))


def test_twigs_are_drawn_from_the_plants_terminal_branches(laurel):
    from plantbench.skeletons import branch_chains, chain_lengths

    sk = laurel.skeleton
    n = len(branch_chains(sk))
    kids = sk.children_counts()
    term = [c for c in branch_chains(sk) if kids[c[-1]] == 0]
    lengths = chain_lengths(sk, term)
    out = add_twigs(laurel, 1.0, seeded(3, "t"))
    new = out.skeleton
    assert np.array_equal(new.positions[:len(sk)], sk.positions) and np.array_equal(new.parents[:len(sk)], sk.parents)
    first = np.flatnonzero(new.parents[len(sk):] < len(sk)) + len(sk)  # each twig's first node
    assert len(first) == n and len(np.unique(new.parents[first])) == n  # n twigs at n distinct nodes
    assert (kids[new.parents[first]] > 0).all()  # attached at nodes with children
    twig_of = np.searchsorted(first, np.arange(len(sk), len(new)), side="right") - 1
    ends = np.append(first[1:] - 1, len(new) - 1)
    for f, e in zip(first, ends):  # straight, of a terminal branch's length, tapering, no thicker than the node
        a = new.positions[new.parents[f]]
        length = np.linalg.norm(new.positions[e] - a)
        assert np.min(np.abs(lengths - length)) < 1e-9
        assert new.radii[f] <= new.radii[new.parents[f]] + 1e-15 and new.radii[e] <= new.radii[f] + 1e-15
    assert (twig_of >= 0).all() and new.is_forest() and (new.positions[:, 2] >= -1e-12).all()
    assert _hand_chain_count(new) == len(branch_chains(new)) > 2 * n - 1
    assert len(out.branch_mesh.vertices) > len(laurel.branch_mesh.vertices)  # the wood rebuilt with the twigs
    assert add_twigs(laurel, 0.0, seeded(3, "t")) is laurel


def test_twigs_cost_the_branch_f1_a_hand_computed_amount_and_not_the_wood():
    # +100 %: n true branches, n twigs; the twig rung has m branches (counted by hand), and a one-to-one matching
    # finds at most n of them, so branch F1 <= 2 n / (n + m); the volume-weighted F1 hardly moves (twigs are thin)
    from plantbench.metrics.skeleton import skeleton_prf
    from plantbench.metrics.structure import branch_prf

    plant = grow_species("peach", 2, scale=0.3)[0]
    n = _hand_chain_count(plant.skeleton)
    twigs = build_rung("twigs+100%", plant, "peach", 2)
    m = _hand_chain_count(twigs.skeleton)
    bound = 2 * n / (n + m)
    assert m >= 2 * n and bound < 0.7
    tau = 0.01 * plant.height
    exact = branch_prf(plant.skeleton, plant.skeleton, tau=tau)["branch_f1"]
    assert exact == 1.0 and branch_prf(plant.skeleton, twigs.skeleton, tau=tau)["branch_f1"] <= bound
    v = skeleton_prf(plant.skeleton, twigs.skeleton, height=plant.height, thresholds=())["vf1@1%"]
    assert v > 0.95


def test_tangle_rehangs_a_fifth_of_the_nodes_across_gaps():
    from plantbench.skeletons import branch_chains

    laurel = grow_species("laurel", 1)[0]  # full size: the small one's nodes have few neighbours within 5 % H
    sk = laurel.skeleton
    out = tangle(laurel, 0.2, seeded(1, "t"))
    new = out.skeleton
    assert np.array_equal(new.positions, sk.positions) and new.is_forest()
    moved = np.flatnonzero(new.parents != sk.parents)
    assert 0.1 * len(sk) < len(moved) <= round(0.2 * (len(sk) - len(sk.roots)))
    gap = np.linalg.norm(new.positions[moved] - new.positions[new.parents[moved]], axis=1)
    assert gap.max() <= 0.05 * laurel.height + 1e-12
    chain_of = np.full(len(sk), -1)
    for c, nodes in enumerate(branch_chains(sk)):
        chain_of[nodes[1:]] = c
    assert (chain_of[moved] != chain_of[new.parents[moved]]).all()  # onto another branch
    assert len(branch_chains(new)) != len(branch_chains(sk))


def test_rungs_deterministic_per_seed(laurel):
    for name in ("jitter-0.5%", "leaves-25%", "prior-a", "twigs+25%", "tangle-20%"):
        a, b = build_rung(name, laurel, "laurel", 7), build_rung(name, laurel, "laurel", 7)
        assert np.array_equal(a.skeleton.positions, b.skeleton.positions)
        assert np.array_equal(TriMesh.concatenate([a.branch_mesh, a.leaf_mesh]).vertices,
                              TriMesh.concatenate([b.branch_mesh, b.leaf_mesh]).vertices)
    c = build_rung("jitter-0.5%", laurel, "laurel", 8)
    assert not np.array_equal(c.skeleton.positions, build_rung("jitter-0.5%", laurel, "laurel", 7).skeleton.positions)
    assert other_species("laurel") != "laurel"
    assert set(LADDER) == set(RUNGS) | {OBSERVED_RUNG}
    with pytest.raises(InputError, match="did you mean"):
        build_rung("jiter-0.5%", laurel, "laurel", 0)


def _ladder_table(values_per_case: dict[str, dict[str, float]], metric: str) -> pd.DataFrame:
    rows = [{"case": case, "method": f"ladder:{rung}", "metric": metric, "value": v, "status": "ok"}
            for case, rungs in values_per_case.items() for rung, v in rungs.items()]
    return pd.DataFrame(rows)


def _volume(checks: dict[str, bool]) -> bool:
    return all(checks[k] for k in VOLUME_CHECKS)


def test_verdict_on_hand_made_ladders():
    good = {"gt": 1.0, "orders<=3": 0.9, "orders<=2": 0.8, "orders<=1": 0.6, "prior-a": 0.3, "prior-b": 0.35,
            "jitter-0.25%": 0.98, "jitter-0.5%": 0.9, "jitter-1%": 0.7, "jitter-2%": 0.4}
    assert _volume(plant_checks(good, True)) and not any(plant_checks(good, True)[k] for k in STRUCTURE_CHECKS)
    assert _volume(plant_checks(dict(good, **{"orders<=3": 1.0, "orders<=2": 1.0}), True))  # nothing to prune
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


def test_structure_verdict_on_hand_made_ladders():
    volume = {"gt": 1.0, "orders<=3": 0.9, "orders<=2": 0.8, "orders<=1": 0.6, "prior-a": 0.2, "prior-b": 0.24,
              "jitter-0.25%": 0.98, "jitter-0.5%": 0.9, "jitter-1%": 0.7, "jitter-2%": 0.4}
    # sees structure: the twig rungs strictly ordered, the +400 % rung at least a quarter of the way to the prior
    # (1 - 0.25 (1 - 0.24) = 0.81), the tangle below gt
    sees = dict(volume, **{"twigs+25%": 0.8, "twigs+100%": 0.5, "twigs+400%": 0.2, "tangle-20%": 0.7})
    assert all(plant_checks(sees, True).values())
    # orders the twig rungs by rounding only (a volume-weighted score): fails the material check
    rounding = dict(sees, **{"twigs+25%": 0.998, "twigs+100%": 0.99, "twigs+400%": 0.96})
    checks = plant_checks(rounding, True)
    assert checks["twigs ordered"] and not checks["twigs+400% material"]
    assert not plant_checks(dict(sees, **{"twigs+400%": 0.82}), True)["twigs+400% material"]
    assert plant_checks(dict(sees, **{"twigs+400%": 0.80}), True)["twigs+400% material"]
    assert not plant_checks(dict(sees, **{"tangle-20%": 1.0}), True)["tangle<gt"]  # blind to wrong forks
    assert not plant_checks(dict(sees, **{"twigs+100%": 0.8}), True)["twigs ordered"]  # ties fail
    lower = {k: 1 - v for k, v in sees.items()}  # a lower-is-better metric
    assert all(plant_checks(lower, False).values())
    t = pd.concat([_ladder_table({f"p{i}": (rounding if i < 2 else sees) for i in range(10)}, "skeleton.vf1@1%"),
                   _ladder_table({f"p{i}": (rounding if i < 1 else sees) for i in range(10)}, "stava.S_T")])
    v = verdicts(t).set_index("metric")
    assert v.loc["skeleton.vf1@1%", "verdict"] == "discriminates" and v.loc["skeleton.vf1@1%", "structure"] == \
        "does not discriminate" and v.loc["skeleton.vf1@1%", "structure_passed"] == 8
    assert v.loc["stava.S_T", "structure"] == "discriminates"


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
    assert "0.77" in note and "0.72" in note and "0.57" in note and "structure column" not in note
    # with the structure rungs: the note says what the structure column shows, with the ladder's numbers
    rungs = {"twigs+100%": (0.49, 0.97), "twigs+400%": (0.18, 0.93), "tangle-20%": (0.61, 0.96),
             "prior-a": (0.03, 0.40), "prior-b": (0.05, 0.42)}
    t2 = pd.concat([t] + [_ladder_table({f"p{i}": {r: v[k] for r, v in rungs.items()} for i in range(3)}, m)
                          for k, m in enumerate(("skeleton.branch_f1@1%", "skeleton.vf1@1%"))])
    write_calibration(t2.assign(species="s", family="f"), tmp_path)
    note = calibration_note(tmp_path)
    assert "skeleton.branch_f1@1%" in note and "0.49 and 0.18 on it, 0.97 and 0.93 on vF1" in note
    assert "0.61, vF1 0.96; the prior 0.04" in note


def test_cut_to_observed_keeps_the_observed_edges_and_splits_at_hidden_ones(laurel):
    """Hidden edges go, their kept ends start new stems; the cut scores observation 1 and inference about 0 against
    the truth (the calibration rung), and no hidden edge survives between two kept nodes."""
    from plantbench.metrics.skeleton import skeleton_prf

    sk = laurel.skeleton
    edges = sk.edges
    share = (seeded(3, "test", "observed").random(len(edges)) < 0.6).astype(float)
    cut = cut_to_observed(laurel, share)
    kept_pairs = {tuple(p) for p in np.round(cut.skeleton.positions[cut.skeleton.edges], 12).reshape(-1, 6).tolist()}
    want = {tuple(p) for p in np.round(sk.positions[edges[share >= 0.5]], 12).reshape(-1, 6).tolist()}
    assert kept_pairs == want  # exactly the observed edges
    assert len(cut.leaves) <= len(laurel.leaves) and len(cut.leaves) > 0
    scores = skeleton_prf(sk, cut.skeleton, height=laurel.height, gt_observed=share)
    assert scores["vf1_observed@1%"] == pytest.approx(1.0) and scores["vrecall_hidden@1%"] in (0.0, None)
    with pytest.raises(InputError, match="shares"):
        cut_to_observed(laurel, share[:-1])


def test_observation_split_reads_the_observed_rung():
    from plantbench.report.calibration import observation_split

    t = pd.concat([_ladder_table({"p0": {"observed": 0.99}, "p1": {"observed": 0.9}}, "skeleton.vf1_observed@1%"),
                   _ladder_table({"p0": {"observed": 0.01}, "p1": {"observed": 0.0}}, "skeleton.vrecall_hidden@1%")])
    split = observation_split(t).set_index("case")
    assert bool(split.loc["p0", "passed"]) and not bool(split.loc["p1", "passed"])
