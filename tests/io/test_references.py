"""Reference QSM readers (TreeQSM, SimpleForest, aRchi) and the trait table, on a cylinder model whose traits are
computed by hand; a real-scan suite holding the model as its references."""

from __future__ import annotations

import gzip
import textwrap

import numpy as np
import pandas as pd
import pytest

from plantbench.errors import InputError
from plantbench.io.references import read_reference
from plantbench.metrics.traits import cylinder_traits, skeleton_traits
from plantbench.plant import Skeleton

# (start, end, radius, parent, order, axis): a two-cylinder stem, a lateral with its continuation, and a lateral of
# the lateral leaving where the first lateral's continuation starts
MODEL = [
    ((0, 0, 0.0), (0, 0, 1.0), 0.05, -1, 0, 0),
    ((0, 0, 1.0), (0, 0, 2.0), 0.04, 0, 0, 0),
    ((0, 0, 1.0), (1, 0, 1.2), 0.02, 0, 1, 1),
    ((1, 0, 1.2), (1.5, 0, 1.3), 0.015, 2, 1, 1),
    ((1, 0, 1.2), (1, 0.4, 1.2), 0.01, 2, 2, 2),
]
L = [1.0, 1.0, np.sqrt(1.04), np.sqrt(0.26), 0.4]
HAND = {
    "dbh_cm": 8.0,  # the stem cylinder crossing 1.3 m: radius 0.04
    "height_m": 2.0,
    "trunk_volume_l": 1000 * np.pi * (0.05**2 + 0.04**2),
    "total_volume_l": 1000 * np.pi * sum(r**2 * length for (_, _, r, *_), length in zip(MODEL, L)),
    "total_length_m": sum(L),
    "length_order0_m": 2.0,
    "length_order1_m": L[2] + L[3],
    "length_order2_m": 0.4,
    "length_order3plus_m": 0.0,
    "branch_count": 2.0,
}


def _write(tool: str, path, offset=(0.0, 0.0, 0.0), shuffle=False):
    rows = []
    off = np.asarray(offset)
    ext = {0: 1, 2: 3}  # each cylinder's continuation
    for i, (s, e, r, p, o, axis) in enumerate(MODEL):
        s, e = np.asarray(s, float) + off, np.asarray(e, float) + off
        v = e - s
        if tool == "treeqsm":  # 1-based, 0 for none
            rows.append({"radius": r, "length": np.linalg.norm(v), "start_x": s[0], "start_y": s[1], "start_z": s[2],
                         **dict(zip(("axis_x", "axis_y", "axis_z"), v / np.linalg.norm(v))), "parent": p + 1,
                         "extension": ext.get(i, -1) + 1, "added": 0, "unmod_radius": r, "branch": axis + 1,
                         "branch_order": o, "position_in_branch": 1})
        elif tool == "simpleforest":  # 0-based IDs, -1 for none, a leading space in the header as the tool writes
            rows.append({"ID": 10 + i, " parentID": 10 + p if p >= 0 else -1, " startX": s[0], " startY": s[1],
                         " startZ": s[2], " endX": e[0], " endY": e[1], " endZ": e[2], " radius": r,
                         " length": 99.0, " branchID": axis, " branchOrder": o})
        else:  # aRchi: 1-based cyl_ID, 0 for none, the stem is order 1; extension_ID not an axis continuation
            rows.append({"startX": s[0], "startY": s[1], "startZ": s[2], "endX": e[0], "endY": e[1], "endZ": e[2],
                         "cyl_ID": i + 1, "parent_ID": p + 1, "extension_ID": (i + 2) % 6, "radius_cyl": r,
                         "length": 99.0, "volume": 0.0, "axis_ID": axis + 1, "segment_ID": 0, "node_ID": 0,
                         "branching_order": o + 1})
    df = pd.DataFrame(rows)
    if shuffle:
        df = df.iloc[::-1]
    df.to_csv(path, index=False)
    return path


@pytest.mark.parametrize("tool", ["treeqsm", "simpleforest", "archi"])
def test_each_tool_reads_to_the_hand_traits(tool, tmp_path):
    table = read_reference(tool, _write(tool, tmp_path / f"{tool}.csv", shuffle=tool != "treeqsm"))
    traits = cylinder_traits(table)
    assert traits == pytest.approx(HAND)


def test_skeleton_traits_match_the_cylinders():
    # the same model as a skeleton whose radii are constant along each edge (frusta are cylinders): node per end
    pos = np.array([(0, 0, 0), (0, 0, 1), (0, 0, 2), (1, 0, 1.2), (1.5, 0, 1.3), (1, 0.4, 1.2)], float)
    par = np.array([-1, 0, 1, 1, 3, 3])
    # node radii so that every edge's two ends agree where possible: the stem tapers 0.05 -> 0.04 over its second
    # edge, so the test uses the edge-wise mean through a QSM export instead for volumes
    rad = np.array([0.05, 0.05, 0.04, 0.02, 0.015, 0.01])
    t = skeleton_traits(Skeleton(pos, rad, par))
    assert t["height_m"] == 2.0 and t["total_length_m"] == pytest.approx(HAND["total_length_m"])
    assert t["branch_count"] == 2.0 and t["length_order2_m"] == pytest.approx(0.4)
    assert t["length_order1_m"] == pytest.approx(HAND["length_order1_m"])
    # DBH at 1.3 m on the second stem edge: radius interpolated 0.05 -> 0.04, 30 % of the way
    assert t["dbh_cm"] == pytest.approx(200 * (0.05 - 0.3 * 0.01))
    # trunk: a cylinder of 0.05 and a frustum 0.05 -> 0.04
    assert t["trunk_volume_l"] == pytest.approx(1000 * np.pi * (0.05**2 + (0.05**2 + 0.05 * 0.04 + 0.04**2) / 3))


def test_bad_reference_tables_name_the_file(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b\n1,2\n")
    with pytest.raises(InputError, match="bad.csv.*not a simpleforest table: missing column"):
        read_reference("simpleforest", bad)
    with pytest.raises(InputError, match="unknown reference tool"):
        read_reference("qsmx", bad)
    df = pd.read_csv(_write("archi", tmp_path / "a.csv"))
    df.loc[2, "parent_ID"] = 42
    df.to_csv(tmp_path / "a.csv", index=False)
    with pytest.raises(InputError, match="ID 42 names no cylinder"):
        read_reference("archi", tmp_path / "a.csv")


def _surface_scan(rng, offset, per_metre=3000):
    """Points on the model's cylinder surfaces (a dense, noise-free 'scan'), shifted by ``offset``."""
    pts = []
    for (s, e, r, *_), length in zip(MODEL, L):
        s, e = np.asarray(s, float), np.asarray(e, float)
        d = (e - s) / length
        a = np.cross(d, [1.0, 0, 0] if abs(d[0]) < 0.9 else [0, 1.0, 0])
        a /= np.linalg.norm(a)
        b = np.cross(d, a)
        n = int(per_metre * length)
        t, phi = rng.uniform(0, length, n), rng.uniform(0, 2 * np.pi, n)
        pts.append(s + t[:, None] * d + r * (np.cos(phi)[:, None] * a + np.sin(phi)[:, None] * b))
    ground = np.column_stack([rng.uniform(-1, 2, 400), rng.uniform(-1, 1, 400), np.zeros(400)])
    return np.concatenate(pts + [ground]) + offset


def test_a_scan_suite_with_references_reports_their_traits(tmp_path, monkeypatch):
    """A georeferenced scan of the model as a suite's scan case (a data: path, gzip text) with the model as its
    three references: the import, the references moved into the case frame, and the report's trait table."""
    from plantbench.report.real import reference_traits, trait_comparison
    from plantbench.report.report import write_report
    from plantbench.runner import run_suite
    from plantbench.suites import load_suite

    offset = np.array([500_000.0, 4_000_000.0, 250.0])
    data = tmp_path / "data"
    (data / "tree").mkdir(parents=True)
    pts = _surface_scan(np.random.default_rng(0), offset)
    with gzip.open(data / "tree" / "model.xyz.gz", "wt") as fh:
        np.savetxt(fh, pts, fmt="%.4f")
    for tool in ("treeqsm", "simpleforest", "archi"):
        _write(tool, data / "tree" / f"{tool}.csv", offset=offset)
    monkeypatch.setenv("PLANTBENCH_DATA", str(data))
    suite_file = tmp_path / "realmodel.toml"
    suite_file.write_text(textwrap.dedent("""
        name = "realmodel"
        description = "a cylinder model scanned"
        methods = ["livny"]
        source = "scan"
        timeout_s = 300

        [[cases]]
        scan = "data:tree/model.xyz.gz"

        [cases.references]
        treeqsm = "data:tree/treeqsm.csv"
        simpleforest = "data:tree/simpleforest.csv"
        archi = "data:tree/archi.csv"
        """))
    res = run_suite(load_suite(str(suite_file)), tmp_path / "runs", workers=1)
    assert set(res.table["status"]) == {"ok"} and set(res.table["case"]) == {"model"}
    refs = reference_traits(res.run_dir)
    assert set(refs["source"]) == {"TreeQSM", "SimpleForest", "aRchi"}
    for source, grp in refs.groupby("source"):  # the case frame: the ground at z = 0 shifts nothing but z
        got = dict(zip(grp["trait"], grp["value"]))
        assert got == pytest.approx(HAND, rel=1e-6), source
    comp = trait_comparison(res.run_dir, res.table).set_index("trait")
    assert comp.loc["dbh_cm", "references"] == "8.000 - 8.000" and comp.loc["dbh_cm", "livny"] != "-"
    livny = res.table[(res.table["method"] == "livny") & (res.table["metric"] == "qsm.dbh_cm")]["value"].iloc[0]
    assert float(comp.loc["dbh_cm", "livny"].split()[0]) == pytest.approx(livny, rel=1e-3)
    files = write_report(res.run_dir, ("md",), tmp_path / "report")
    md = next(f for f in files if f.suffix == ".md").read_text()
    assert "Traits against the reference QSMs" in md and "skeletons_model.png" in md and "traits.png" in md
