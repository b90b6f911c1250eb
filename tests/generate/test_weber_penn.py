"""The weber-penn family: the same ground-truth contract as space colonisation (rooted forest, radii, leaf
bookkeeping, byte determinism), and the Weber and Penn formulas checked on the grown geometry against values
computed here from the paper's equations (shape ratio table, taper, flare, down angle, curvature, child length and
count, splits)."""

import json
import math

import numpy as np
import pytest

from plantbench.errors import InputError
from plantbench.generate import FAMILIES, generate_case
from plantbench.generate.foliage import foliage_params, place_leaves
from plantbench.generate.params_wp import WeberPennSpecies
from plantbench.generate.weber_penn import flare_factor, grow, grow_skeleton, shape_ratio, taper_radius
from plantbench.geometry.tubes import node_frames
from plantbench.geometry.vectors import levels as tree_levels
from plantbench.io.plantio import read_plant
from plantbench.io.ply import read_mesh
from plantbench.plant import Skeleton
from plantbench.skeletons import branch_chains, children_lists
from plantbench.species import load_species, species

SCALE = 0.12
HOUSE_PLANTS = ("wp_rubber_plant", "wp_fiddle_leaf_fig")
"""Grown at full size: a few stems and tens of leaves (scaled by 0.12 the fig would keep no shoot, so no leaf)."""
FILES = ("plant.json", "skeleton.ply", "branches.ply", "leaves.ply", "leaves.json", "plant.glb")


def wp_species() -> list[str]:
    return [n for n in species.names() if load_species(n).family == "weber-penn"]


@pytest.fixture(scope="module")
def cases(tmp_path_factory):
    out = {}
    for name in wp_species():
        folder = tmp_path_factory.mktemp(name)
        out[name] = (folder, generate_case(name, 3, folder, scale=1.0 if name in HOUSE_PLANTS else SCALE))
    return out


def test_library_has_four_distinct_habits():
    names = wp_species()
    assert {"wp_conifer", "wp_weeping_willow", "wp_palm", "wp_aspen"} <= set(names)
    habits = [load_species(n).habit for n in names]
    assert len(set(habits)) == len(habits) and all(habits)
    assert FAMILIES["weber-penn"].params_model is WeberPennSpecies


def test_skeletons_are_rooted_trees_on_the_ground(cases):
    for name, (folder, meta) in cases.items():
        plant, _ = read_plant(folder)
        sk = plant.skeleton
        assert sk.is_forest(), name  # every node reaches a root: one tree per root
        roots = sk.roots
        assert len(roots) == meta.counts.roots == 1, name
        np.testing.assert_array_equal(sk.positions[roots, 2], 0.0)
        assert np.all(sk.positions[:, 2] >= 0), name
        assert np.all(sk.radii > 0), name
        child = np.flatnonzero(sk.parents >= 0)
        assert np.all(sk.radii[child] <= sk.radii[sk.parents[child]]), name
        # order = stem level: never decreases from parent to child, and grows by at most one
        step = sk.order[child] - sk.order[sk.parents[child]]
        assert np.all((step == 0) | (step == 1)), name
        # the rubber plant has no branch levels: its stem is the one chain
        unbranched = not load_species(name).branch_levels
        assert meta.family == "weber-penn" and meta.counts.branches == len(branch_chains(sk)) >= 2 - unbranched, name


def test_leaf_bookkeeping(cases):
    for name, (folder, meta) in cases.items():
        doc = json.loads((folder / "plant" / "leaves.json").read_text())
        _, fields = read_mesh(folder / "plant" / "leaves.ply")
        ids = np.unique(fields["leaf_id"])
        assert meta.counts.leaves == len(doc["leaves"]) == len(ids) > 0, name
        np.testing.assert_array_equal(ids, np.arange(meta.counts.leaves))
        plant, _ = read_plant(folder)
        nodes = np.array([leaf.node for leaf in plant.leaves])
        # leaves hang from the deepest stems only
        assert np.all(plant.skeleton.order[nodes] == plant.skeleton.order.max()), name


def test_same_seed_same_bytes_other_seed_differs(cases, tmp_path):
    for name, (folder, _) in cases.items():
        generate_case(name, 3, tmp_path / name, scale=1.0 if name in HOUSE_PLANTS else SCALE)
        for f in FILES:
            assert (folder / "plant" / f).read_bytes() == (tmp_path / name / "plant" / f).read_bytes(), (name, f)
    name = "wp_aspen"
    generate_case(name, 4, tmp_path / "other", scale=SCALE)
    for f in ("skeleton.ply", "leaves.ply"):
        assert (cases[name][0] / "plant" / f).read_bytes() != (tmp_path / "other" / "plant" / f).read_bytes()


def test_scale_shrinks_the_plant():
    spec = load_species("wp_conifer")
    small = grow_skeleton(spec, np.random.default_rng(0), scale=0.1)
    big = grow_skeleton(spec, np.random.default_rng(0), scale=0.4)
    assert small.positions[:, 2].max() < big.positions[:, 2].max()
    assert sum(small.stems) < 0.5 * sum(big.stems)
    with pytest.raises(InputError, match="scale"):
        grow_skeleton(spec, np.random.default_rng(0), scale=0.0)


# ------------------------------------------------------------------------------------------------------ formulas


@pytest.mark.parametrize(("shape", "r", "expected"), [
    ("conical", 0.0, 0.2), ("conical", 0.5, 0.6), ("conical", 1.0, 1.0),
    ("spherical", 0.0, 0.2), ("spherical", 0.5, 1.0), ("spherical", 1.0, 0.2),
    ("hemispherical", 0.0, 0.2), ("hemispherical", 1.0, 1.0), ("hemispherical", 1 / 3, 0.2 + 0.8 * 0.5),
    ("cylindrical", 0.3, 1.0),
    ("tapered_cylindrical", 0.0, 0.5), ("tapered_cylindrical", 1.0, 1.0), ("tapered_cylindrical", 0.4, 0.7),
    ("flame", 0.0, 0.0), ("flame", 0.35, 0.5), ("flame", 0.7, 1.0), ("flame", 0.85, 0.5), ("flame", 1.0, 0.0),
    ("inverse_conical", 0.0, 1.0), ("inverse_conical", 1.0, 0.2), ("inverse_conical", 0.5, 0.6),
    ("tend_flame", 0.0, 0.5), ("tend_flame", 0.7, 1.0), ("tend_flame", 0.35, 0.75), ("tend_flame", 1.0, 0.5),
    ("tend_flame", 0.85, 0.75),
])
def test_shape_ratio_table(shape, r, expected):
    """Weber and Penn's ShapeRatio table, evaluated by hand."""
    assert float(shape_ratio(shape, np.array([r]))[0]) == pytest.approx(expected, abs=1e-12)


def test_taper_and_flare():
    z = np.linspace(0, 1, 11)
    np.testing.assert_allclose(taper_radius(z, 0.2, 0.0, 5.0), 0.2)
    np.testing.assert_allclose(taper_radius(z, 0.2, 0.5, 5.0), 0.2 * (1 - 0.5 * z))
    np.testing.assert_allclose(taper_radius(z, 0.2, 1.0, 5.0), 0.2 * (1 - z), atol=1e-15)
    # taper 2: a cylinder of radius r closed by a hemisphere of radius r
    length, r = 2.0, 0.5
    d = (1 - z) * length  # distance to the tip
    want = np.where(d >= r, r, np.sqrt(np.maximum(r**2 - (r - d) ** 2, 0)))
    np.testing.assert_allclose(taper_radius(z, r, 2.0, length), want, atol=1e-12)
    assert flare_factor(np.array([0.0]), 0.6)[0] == pytest.approx(1 + 0.6 * 99 / 100)
    np.testing.assert_allclose(flare_factor(np.array([0.125, 0.5, 1.0]), 0.6), 1.0)


def _spec(**over) -> WeberPennSpecies:
    """A minimal deterministic species: no random variation unless asked."""
    data = {
        "name": "probe", "display_name": "probe",
        "tree": {"shape": "conical", "base_size": 0.2, "scale": 10.0, "ratio": 0.02, "ratio_power": 1.0},
        "trunk": {"length": 1.0, "taper": 1.0, "curve_res": 5},
        "level1": {"branches": 12, "length": 0.3, "down_angle": 60, "rotate": 140, "curve_res": 4,
                   "arrangement": "whorl", "whorl_count": 3},
        "leaves": {"arrangement": "spiral", "length": 0.05, "per_stem": 6, "start": 0.2},
    }
    for key, val in over.items():
        group, _, field = key.partition("__")
        if field:
            data[group] = {**data.get(group, {}), field: val}
        else:
            data[group] = val
    return WeberPennSpecies.model_validate(data)


def _axes(sk) -> tuple[list[np.ndarray], np.ndarray]:
    """Each axis (a stem or clone) as its node list starting at the node it hangs from."""
    skel = Skeleton(sk.positions, sk.radii, sk.parents, sk.level)
    kids = children_lists(skel)
    heads = np.flatnonzero(sk.lateral | (sk.parents < 0))
    axes = []
    for h in heads:
        chain = [int(sk.parents[h])] if sk.parents[h] >= 0 else []
        node = int(h)
        chain.append(node)
        while True:
            nxt = [c for c in kids[node] if not sk.lateral[c]]
            if not nxt:
                break
            node = int(nxt[0])
            chain.append(node)
        axes.append(np.array(chain))
    return axes, heads


def test_level1_lengths_counts_and_down_angle_follow_the_paper():
    spec = _spec()
    sk = grow_skeleton(spec, np.random.default_rng(1))
    axes, heads = _axes(sk)
    trunk = axes[0]
    trunk_len = np.linalg.norm(np.diff(sk.positions[trunk], axis=0), axis=1).sum()
    assert trunk_len == pytest.approx(10.0)
    assert sk.radii[0] == pytest.approx(10.0 * 0.02)  # r0 = L0 Ratio (no flare)
    lv1 = [a for a, h in zip(axes, heads) if sk.level[h] == 1]
    assert len(lv1) == 12  # 12 branches in whorls of 3
    assert len({int(a[0]) for a in lv1}) == 4  # four whorl nodes
    for a in lv1:
        p = sk.positions[a]
        offset = p[0, 2]  # straight vertical trunk: the offset is the attachment height
        assert offset >= 0.2 * trunk_len - 1e-9
        r = (trunk_len - offset) / (trunk_len * (1 - 0.2))
        want = trunk_len * 0.3 * (0.2 + 0.8 * r)  # L_trunk length ShapeRatio(conical, r)
        assert np.linalg.norm(np.diff(p, axis=0), axis=1).sum() == pytest.approx(want, rel=1e-9)
        # no curvature: a straight stem at the down angle from the (vertical) trunk
        first = (p[1] - p[0]) / np.linalg.norm(p[1] - p[0])
        assert math.degrees(math.acos(first[2])) == pytest.approx(60.0, abs=1e-6)
        last = (p[-1] - p[-2]) / np.linalg.norm(p[-1] - p[-2])
        np.testing.assert_allclose(last, first, atol=1e-9)
        # child radius r_trunk (L / L_trunk)^RatioPower, capped by the trunk where it attaches
        assert sk.radii[a[1]] <= sk.radii[a[0]] + 1e-15
    # whorl members spread evenly: 120 degrees apart in azimuth
    by_node: dict[int, list[float]] = {}
    for a in lv1:
        d = sk.positions[a[1]] - sk.positions[a[0]]
        by_node.setdefault(int(a[0]), []).append(math.atan2(d[1], d[0]))
    for az in by_node.values():
        gaps = np.diff(np.sort(np.mod(az, 2 * np.pi)))
        np.testing.assert_allclose(gaps, 2 * np.pi / 3, atol=1e-6)


def test_curvature_turns_the_stem_by_curve_degrees():
    spec = _spec(trunk__curve=90.0, level1__branches=0)
    sk = grow_skeleton(spec, np.random.default_rng(2))
    (trunk,) = _axes(sk)[0]
    p = sk.positions[trunk]
    seg = np.diff(p, axis=0)
    seg = seg / np.linalg.norm(seg, axis=1, keepdims=True)
    # five segments, each turned by 90/5 degrees: the last points 90 degrees from vertical
    assert math.degrees(math.acos(np.clip(seg[-1, 2], -1, 1))) == pytest.approx(90.0, abs=1e-6)
    assert math.degrees(math.acos(np.clip(seg[0, 2], -1, 1))) == pytest.approx(18.0, abs=1e-6)


def test_negative_down_angle_v_varies_along_the_parent():
    spec = _spec(level1__down_angle_v=-30.0, level1__arrangement="spiral")
    sk = grow_skeleton(spec, np.random.default_rng(3))
    axes, heads = _axes(sk)
    trunk_len = sk.positions[axes[0][-1], 2]
    wants = []
    for a in (a for a, h in zip(axes, heads) if sk.level[h] == 1):
        p = sk.positions[a]
        r = np.clip((trunk_len - p[0, 2]) / (trunk_len * 0.8), 0, 1)
        want = 60.0 - 30.0 * (1 - 2 * (0.2 + 0.8 * r))  # W&P: down + V (1 - 2 ShapeRatio(conical, r))
        first = (p[1] - p[0]) / np.linalg.norm(p[1] - p[0])
        assert math.degrees(math.acos(first[2])) == pytest.approx(want, abs=1e-6)
        wants.append(want)
    assert max(wants) - min(wants) > 20  # low branches droop, high ones rise


def test_negative_attraction_up_bends_stems_down():
    flat = grow_skeleton(_spec(), np.random.default_rng(3))
    bent = grow_skeleton(_spec(level1__attraction_up=-2.0), np.random.default_rng(3))
    for sk, lo, hi in ((flat, 59.9, 60.1), (bent, 95.0, 180.0)):
        axes, heads = _axes(sk)
        for a in (a for a, h in zip(axes, heads) if sk.level[h] == 1):
            p = sk.positions[a]
            last = (p[-1] - p[-2]) / np.linalg.norm(p[-1] - p[-2])
            assert lo < math.degrees(math.acos(np.clip(last[2], -1, 1))) < hi


def test_base_splits_fork_the_trunk():
    spec = _spec(tree__base_splits=2, trunk__split_angle=20.0, level1__branches=0)
    sk = grow_skeleton(spec, np.random.default_rng(4))
    trunk_nodes = np.flatnonzero(sk.level == 0)
    has_trunk_child = np.zeros(len(sk.parents), bool)
    c = trunk_nodes[sk.parents[trunk_nodes] >= 0]
    has_trunk_child[sk.parents[c]] = True
    assert (~has_trunk_child[trunk_nodes]).sum() == 3  # three trunk tips
    assert sk.clones == 2
    fork = np.flatnonzero(np.bincount(sk.parents[c], minlength=len(sk.parents)) == 3)
    assert len(fork) == 1
    kids = np.flatnonzero(sk.parents == fork[0])
    # clones: radius / sqrt(3) of the stem's radius there (pipe model)
    assert np.all(sk.radii[kids] <= sk.radii[fork[0]] / math.sqrt(3) + 1e-12)


def test_leaves_per_stem_and_size_profile():
    spec = _spec(leaves__per_stem=8, leaves__distribution="cylindrical", leaves__arrangement="opposite",
                 leaves__size_profile="spherical")
    sk = grow_skeleton(spec, np.random.default_rng(5))
    # 8 leaves as 4 opposite pairs on each of the 12 level-1 stems
    assert len(sk.leaf_nodes) == 12 * 4
    assert np.all(sk.level[sk.leaf_nodes] == 1)
    assert np.all((sk.leaf_index >= 0) & (sk.leaf_index < 4))
    assert np.all((sk.leaf_factor > 0.2) & (sk.leaf_factor <= 1.0))
    plant = grow(spec, np.random.default_rng(5))
    assert len(plant.leaves) == 96


def test_place_leaves_explicit_nodes_equal_the_default():
    """The generalised place_leaves with the default's own nodes and axis index gives the same leaves."""
    spec = load_species("wp_aspen")
    sk = grow_skeleton(spec, np.random.default_rng(6), scale=0.05)
    main = (sk.parents >= 0) & ~sk.lateral
    t, n, _, _ = node_frames(sk.positions, sk.parents, main)
    levels = tree_levels(sk.parents)
    fp = foliage_params(spec)
    a = place_leaves(sk.positions, sk.parents, sk.radii, main, t, n, levels, fp, np.random.default_rng(0))
    nodes = np.flatnonzero((sk.parents >= 0) & (sk.radii <= fp.max_branch_radius))
    from plantbench.geometry.tubes import axis_positions

    b = place_leaves(sk.positions, sk.parents, sk.radii, main, t, n, levels, fp, np.random.default_rng(0),
                     nodes=nodes, axis_index=axis_positions(sk.parents, main, levels)[nodes],
                     length_factor=np.ones(len(nodes)))
    assert len(a.leaves) == len(b.leaves) > 0
    np.testing.assert_array_equal(a.mesh.vertices, b.mesh.vertices)
    np.testing.assert_array_equal(a.face_ids, b.face_ids)


# ------------------------------------------------------------------------------------------------- bad input


# (bad values in a species file of either family: test_species.py)


def test_missing_level_between_levels_is_an_error():
    with pytest.raises(ValueError, match="level2 needs level1"):
        WeberPennSpecies.model_validate({
            "name": "x", "display_name": "x",
            "tree": {"shape": "conical", "base_size": 0.2, "scale": 5.0, "ratio": 0.02},
            "level2": {"branches": 3, "length": 0.3, "down_angle": 40},
            "leaves": {"arrangement": "spiral", "length": 0.05, "per_stem": 4},
        })



def test_random_phase_turns_the_phyllotaxis_per_plant_only_where_asked(tmp_path, monkeypatch):
    """wp_rubber_plant (random_phase = true): the azimuth of its lowest leaf about the stem differs between seeds by
    more than the 10-degree jitter; the same file without the flag grows the same stem with the leaves at other
    azimuths (the phase is one draw after the others: the stem, and every species without the flag, is unchanged)."""
    from plantbench.generate import grow_species
    from plantbench.paths import species_dir
    from plantbench.species import species

    def lowest_azimuth(plant) -> float:
        c = min(plant.leaves, key=lambda lf: lf.centroid[2]).centroid
        return float(np.degrees(np.arctan2(c[1], c[0])))

    az = [lowest_azimuth(grow_species("wp_rubber_plant", s)[0]) for s in (1, 2, 3)]
    assert max(abs((a - b + 180) % 360 - 180) for a in az for b in az) > 30
    on, _ = grow_species("wp_rubber_plant", 1)
    text = (species_dir() / "wp_rubber_plant.toml").read_text()
    assert "random_phase = true" in text
    folder = tmp_path / "scenes" / "species"
    folder.mkdir(parents=True)
    (folder / "wp_rubber_plant.toml").write_text(text.replace("random_phase = true\n", ""))
    monkeypatch.setenv("PLANTBENCH_SCENES", str(tmp_path / "scenes"))
    species.reset()
    try:
        off, _ = grow_species("wp_rubber_plant", 1)
    finally:
        monkeypatch.undo()
        species.reset()
    np.testing.assert_array_equal(off.skeleton.positions, on.skeleton.positions)
    assert len(off.leaves) == len(on.leaves)
    assert not np.allclose([lf.centroid for lf in off.leaves], [lf.centroid for lf in on.leaves])
