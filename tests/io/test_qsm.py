"""QSM cylinder tables (plantbench.io.qsm): skeleton -> cylinders -> skeleton round trips, TreeQSM's 1-based tables,
branches off their parent's end, bad tables naming the file, and the CLI."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
from scipy.spatial import cKDTree

from plantbench.errors import InputError
from plantbench.io.plantio import write_reconstruction
from plantbench.io.ply import read_skeleton
from plantbench.io.qsm import COLUMNS, cylinders_to_skeleton, read_qsm_csv, skeleton_to_cylinders, write_qsm_csv
from plantbench.plant import Skeleton
from plantbench.skeletons import children_lists, topological_order
from tests.metrics.synth import random_tree


def with_axis_orders(skel: Skeleton) -> Skeleton:
    """The skeleton with ``order`` by the thickest-child rule (naive: a child continues its parent's order when it
    is the parent's thickest child, else adds one)."""
    order = np.zeros(len(skel), np.int64)
    kids = children_lists(skel)
    for node in topological_order(skel):
        if len(kids[node]):
            thickest = kids[node][np.argmax(skel.radii[kids[node]])]
            for k in kids[node]:
                order[k] = order[node] + (k != thickest)
    return Skeleton(skel.positions, skel.radii, skel.parents, order)


def matched(a: Skeleton, b: Skeleton, tol: float = 1e-9) -> np.ndarray:
    """Index in ``b`` of each node of ``a`` (same positions up to ``tol``)."""
    d, idx = cKDTree(b.positions).query(a.positions)
    assert d.max() < tol and len(np.unique(idx)) == len(a) == len(b)
    return idx


def test_round_trip_keeps_positions_structure_orders(rng):
    skel = with_axis_orders(random_tree(rng, 25))
    df = skeleton_to_cylinders(skel)
    assert list(df.columns) == list(COLUMNS) and len(df) == len(skel) - 1
    back = cylinders_to_skeleton(df)
    m = matched(skel, back)
    par = skel.parents
    assert np.array_equal(np.where(par >= 0, m[np.maximum(par, 0)], -1), back.parents[m])
    assert np.array_equal(back.order[m], skel.order)
    # radii: a node gets the radius of the cylinder ending at it, the mean of the edge's two node radii
    child = par >= 0
    assert np.allclose(back.radii[m][child], 0.5 * (skel.radii[child] + skel.radii[par[child]]))
    root, first = 0, children_lists(skel)[0][0]
    assert np.isclose(back.radii[m][root], 0.5 * (skel.radii[root] + skel.radii[first]))


def test_cylinder_table_is_treeqsm_like(rng):
    skel = with_axis_orders(random_tree(rng, 15))
    df = skeleton_to_cylinders(skel)
    par, ext, branch = df["parent"].to_numpy(), df["extension"].to_numpy(), df["branch"].to_numpy()
    idx = np.arange(len(df))
    assert par[0] == -1 and np.all(par[1:] < idx[1:]) and np.all(par[1:] >= 0)  # parents first, one stem
    assert np.allclose(np.linalg.norm(df[["axis_x", "axis_y", "axis_z"]].to_numpy(), axis=1), 1.0)
    starts = df[["start_x", "start_y", "start_z"]].to_numpy()
    ends = starts + df["length"].to_numpy()[:, None] * df[["axis_x", "axis_y", "axis_z"]].to_numpy()
    assert np.allclose(starts[1:], ends[par[1:]])
    for i in idx:  # the extension is the thickest child; a branch follows extensions
        kids = idx[par == i]
        if len(kids):
            assert ext[i] == kids[np.argmax(df["radius"].to_numpy()[kids])]
            assert branch[ext[i]] == branch[i] and all(branch[k] != branch[i] for k in kids if k != ext[i])
        else:
            assert ext[i] == -1
    assert len(np.unique(branch)) == int((~np.isin(idx, ext)).sum())  # one branch per first cylinder
    topo = topological_order(skel)
    assert np.array_equal(df["branch_order"].to_numpy(), skel.order[topo[skel.parents[topo] >= 0]])
    first_of_branch = ~np.isin(idx, ext)
    orders = df["branch_order"].to_numpy()
    assert np.all(orders[~first_of_branch] == orders[par[~first_of_branch]])  # an axis keeps its order
    assert np.all(orders[first_of_branch & (par >= 0)] == orders[par[first_of_branch & (par >= 0)]] + 1)


def test_csv_round_trip_is_exact(tmp_path, rng):
    skel = with_axis_orders(random_tree(rng, 10))
    df = write_qsm_csv(tmp_path / "q.csv", skel)
    back = read_qsm_csv(tmp_path / "q.csv")
    direct = cylinders_to_skeleton(df)
    assert np.array_equal(back.positions, direct.positions) and np.array_equal(back.radii, direct.radii)
    assert np.array_equal(back.parents, direct.parents) and np.array_equal(back.order, direct.order)


def test_treeqsm_one_based_table_and_extra_columns(rng):
    skel = random_tree(rng, 8)
    df = skeleton_to_cylinders(skel)
    one = df.copy()
    one["parent"] += 1  # TreeQSM / rTwig: cylinders from 1, 0 for none
    one["extension"] += 1
    one["PositionInBranch"] = 1
    a, b = cylinders_to_skeleton(df), cylinders_to_skeleton(one)
    assert np.array_equal(a.positions, b.positions) and np.array_equal(a.parents, b.parents)


def test_branch_starting_off_its_parents_end():
    df = pd.DataFrame({
        "start_x": [0, 0, 0.02], "start_y": [0, 0, 0], "start_z": [0, 1, 0.6],  # cylinder 2 starts mid-stem
        "axis_x": [0, 0, 1], "axis_y": [0, 0, 0], "axis_z": [1, 1, 0], "length": [1, 1, 0.5],
        "radius": [0.05, 0.04, 0.02], "parent": [-1, 0, 0], "extension": [1, -1, -1], "branch": [0, 0, 1],
        "branch_order": [0, 0, 1]})
    s = cylinders_to_skeleton(df)
    assert len(s) == 5  # root, stem joint, stem top, the branch's own start and end
    start = int(np.flatnonzero(np.all(np.isclose(s.positions, [0.02, 0, 0.6]), axis=1))[0])
    assert np.allclose(s.positions[s.parents[start]], [0, 0, 1])  # hangs from the nearer end of its parent
    assert s.order[start] == 1 and np.isclose(s.radii[start], 0.02)


def test_bad_tables_name_the_file(tmp_path, rng):
    df = skeleton_to_cylinders(random_tree(rng, 5))
    cases = {
        "missing.csv": (df.drop(columns=["radius", "branch"]), "missing column(s) radius, branch"),
        "nan.csv": (df.assign(length=np.where(df.index == 3, np.nan, df["length"])), "column length: 1 NaN"),
        "range.csv": (df.assign(parent=np.where(df.index == 2, 999, df["parent"])), "index out of range"),
        "cycle.csv": (df.assign(parent=np.where(df.index == 0, 1, df["parent"])), None),
        "radius.csv": (df.assign(radius=-df["radius"]), "radii > 0"),
        "words.csv": (df.assign(branch="trunk"), "column branch: not numeric"),
    }
    for name, (table, message) in cases.items():
        table.to_csv(tmp_path / name, index=False)
        with pytest.raises(InputError) as err:
            read_qsm_csv(tmp_path / name)
        assert str(tmp_path / name) in str(err.value) and (message is None or message in str(err.value)), str(err.value)
    (tmp_path / "empty.csv").write_text("")
    (tmp_path / "header.csv").write_text(",".join(COLUMNS) + "\n")
    for name, message in (("empty.csv", "not a readable CSV"), ("header.csv", "no cylinders"),
                          ("absent.csv", "file not found")):
        with pytest.raises(InputError, match=message) as err:
            read_qsm_csv(tmp_path / name)
        assert str(tmp_path / name) in str(err.value)
    with pytest.raises(InputError, match="no edge"):
        skeleton_to_cylinders(Skeleton(np.zeros((1, 3)), np.ones(1), np.array([-1])))


def test_cli_export_import_and_evaluate(tmp_path, rng):
    skel = with_axis_orders(random_tree(rng, 12))
    write_reconstruction(tmp_path / "recon", skel)
    cli = [sys.executable, "-m", "plantbench.cli", "qsm"]
    out = subprocess.run([*cli, "export", str(tmp_path / "recon"), "--out", str(tmp_path / "t.csv")],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert f"{len(skel) - 1} cylinders" in out.stdout
    out = subprocess.run([*cli, "import", str(tmp_path / "t.csv"), "--out", str(tmp_path / "back")],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    back = read_skeleton(tmp_path / "back" / "skeleton.ply")
    matched(skel, back)
    (tmp_path / "bad.csv").write_text("start_x,start_y\n1,2\n")
    out = subprocess.run([*cli, "import", str(tmp_path / "bad.csv"), "--out", str(tmp_path / "x")],
                         capture_output=True, text=True)
    assert out.returncode == 2 and str(tmp_path / "bad.csv") in out.stderr and "missing column" in out.stderr


def test_qsm_in_the_source_frame_of_an_imported_scan(tmp_path, rng):
    """A QSM made by TreeQSM on the georeferenced cm file imports into the case frame (--case), and goes back."""
    from plantbench.capture.importers import import_scan, read_case_json, skeleton_to_frame, to_source
    from plantbench.metrics.evaluate import evaluate_detailed

    skel = with_axis_orders(random_tree(rng, 10))
    e = skel.edges
    t = rng.random((2000, 1))
    k = rng.integers(0, len(e), 2000)
    cloud = skel.positions[e[k, 0]] + t * (skel.positions[e[k, 1]] - skel.positions[e[k, 0]])
    utm = np.array([500_000.0, 5_400_000.0, 250.0])
    np.savetxt(tmp_path / "plot.xyz", (cloud + utm) * 100, fmt="%.4f")  # cm, Z up
    import_scan(tmp_path / "plot.xyz", tmp_path / "case", units="cm")
    frame = read_case_json(tmp_path / "case").frame
    # what TreeQSM gives on plot.xyz: the skeleton in the file's frame (cm, georeferenced)
    source = Skeleton((skel.positions + utm) * 100, skel.radii * 100, skel.parents, skel.order)
    local = skeleton_to_frame(source, frame, to="local")
    assert np.allclose(local.positions, skel.positions + utm - frame.offset, atol=1e-6)
    assert np.allclose(local.radii, skel.radii)
    back = skeleton_to_frame(local, frame, to="source")
    assert np.allclose(back.positions, source.positions, atol=1e-6) and np.allclose(back.radii, source.radii)
    assert np.allclose(to_source(local.positions, frame), source.positions, atol=1e-6)
    write_qsm_csv(tmp_path / "treeqsm.csv", source)
    out = subprocess.run([sys.executable, "-m", "plantbench.cli", "qsm", "import", str(tmp_path / "treeqsm.csv"),
                          "--out", str(tmp_path / "recon"), "--case", str(tmp_path / "case")],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    values, reasons = evaluate_detailed(tmp_path / "case", tmp_path / "recon")  # no plant/: the GT-free metrics
    support = {key: v for key, v in values.items() if key.startswith("support.skeleton")}  # the shares
    assert support and all(v is not None and v > 0.9 for v in support.values()), (support, reasons)
    out = subprocess.run([sys.executable, "-m", "plantbench.cli", "qsm", "export", str(tmp_path / "recon"),
                          "--out", str(tmp_path / "again.csv"), "--case", str(tmp_path / "case")],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    again = read_qsm_csv(tmp_path / "again.csv")  # back in the file's frame, cm
    matched(Skeleton(source.positions / 100, source.radii, source.parents),
            Skeleton(again.positions / 100, again.radii, again.parents), tol=1e-6)
