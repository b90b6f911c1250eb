"""Suites over case folders (real captures, no plant/): planning, validation, a run scored with the metrics that
need no ground truth, and its report."""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import numpy as np
import pytest

from plantbench.errors import InputError
from plantbench.suites import load_suite


def _scanned_case(folder: Path, seed: int) -> Path:
    """A small plant scanned from two stations, written as a georeferenced .xyz and imported as a real case."""
    from plantbench.capture.importers import import_scan
    from plantbench.capture.scan import scan_plant
    from plantbench.capture.settings import CaptureOptions
    from tests.capture.plants import make_plant

    plant = make_plant(height=2.0, branches=5, leaves_per_branch=3, seed=seed)
    opts = CaptureOptions(stations=2, angular_step_deg=0.25, range_noise=0.001, dropout=0.0)
    pts = scan_plant(plant, opts, np.random.default_rng(seed)).points
    xyz = folder / f"tree{seed}.xyz"
    np.savetxt(xyz, pts + [500_000.0, 4_000_000.0, 120.0], fmt="%.4f")
    return import_scan(xyz, folder / f"tree{seed}").case


def _suite(path: Path, cases: str, methods=("livny", "xu")) -> Path:
    quoted = ", ".join(f"'{m}'" for m in methods)
    path.write_text(textwrap.dedent(f"""
        name = "{path.stem}"
        description = "real cases"
        methods = [{quoted}]
        source = "scan"
        timeout_s = 120
        """) + textwrap.dedent(cases))
    return path


@pytest.fixture(scope="module")
def real_run(tmp_path_factory):
    from plantbench.runner import run_suite

    root = tmp_path_factory.mktemp("real")
    (root / "data").mkdir()
    a, b = _scanned_case(root / "data", 1), _scanned_case(root / "data", 2)
    (root / "suites").mkdir()
    suite_file = _suite(root / "suites" / "realtest.toml", f"""
        [[cases]]
        path = "../data/{a.name}"
        species = "laurel"

        [[cases]]
        path = "{b}"
        """)
    suite = load_suite(str(suite_file))
    return suite, run_suite(suite, root / "runs", workers=1), root


def test_case_folders_resolve_and_plan(real_run):
    from plantbench.runner.plan import make_plan

    suite, _, root = real_run
    assert [c.path for c in suite.cases] == [str((root / "data" / n).resolve()) for n in ("tree1", "tree2")]
    plan = make_plan(suite)
    cells = {(c.case, c.method): c for c in plan.cells}
    assert set(cells) == {(t, m) for t in ("tree1", "tree2") for m in ("livny", "xu")}
    assert {(c.species, c.family, c.seed) for c in plan.cells if c.case == "tree1"} == {("laurel", "real", 0)}
    assert {c.species for c in plan.cells if c.case == "tree2"} == {"unknown"}
    captures = [j for j in plan.jobs.values() if j.kind == "capture"]
    assert len(captures) == 2 and all("folder" in j.params for j in captures)
    # the hint reaches the methods of the hinted case only
    assert {j.params["species"] for j in plan.jobs.values() if j.kind == "method"} == {"laurel", None}
    # editing a file of a case folder changes its capture key (everything downstream re-runs)
    before = cells[("tree2", "xu")].case_key
    (root / "data" / "tree2" / "case.json").write_text((root / "data" / "tree2" / "case.json").read_text() + " ")
    after = {(c.case, c.method): c for c in make_plan(suite).cells}
    assert after[("tree2", "xu")].case_key != before
    assert after[("tree1", "xu")].case_key == cells[("tree1", "xu")].case_key


def test_real_cases_scored_without_ground_truth(real_run):
    _, res, _ = real_run
    t = res.table
    assert set(t["status"]) == {"ok"}
    assert set(t["family"]) == {"real"} and set(t["seed"]) == {0}
    for (case, method), cell in t.groupby(["case", "method"]):
        v = cell.set_index("metric")["value"]
        for name in ("support.skeleton@1%", "skeleton.height_m", "skeleton.branch_count", "skeleton.crown_area_m2",
                     "skeleton.total_length_m", "mesh_to_scan.D_cm"):
            assert math.isfinite(v[name]), (case, method, name)
        assert 1.0 < v["skeleton.height_m"] < 3.0 and v["skeleton.crown_area_m2"] > 0.01
        for name in ("stava.S_T", "skeleton.vf1@1%", "skeleton.height_error_m", "skeleton.f1@1.0",
                     "skeleton.crown_area_rel_error", "mesh_to_surface.D_cm", "surface.wood.fscore@0.5%"):
            assert math.isnan(v[name]), (case, method, name)


def test_report_of_a_run_without_ground_truth(real_run, tmp_path):
    from plantbench.report.report import write_report

    _, res, _ = real_run
    written = write_report(res.run_dir, out=tmp_path / "report")
    md = (tmp_path / "report" / "report.md").read_text()
    # the headline table and the paired comparisons hold the metrics with values, not the all-empty GT ones
    assert "| support.skeleton@1% ↑ |" in md and "| mesh_to_scan.D_cm (cm) ↓ |" in md
    assert "| skeleton.vf1@1% ↑ |" not in md and "| stava.S_T ↑ |" not in md
    assert "| support.skeleton@1% ↑ | livny - xu | 2 |" in md
    assert "| unknown | xu |" in md and "| real | livny |" in md  # per species (the hint or 'unknown'), per family
    assert {p.name for p in written} >= {"report.md", "report.html", "report.tex", "overall.csv", "metrics.png"}


@pytest.mark.parametrize("cases, message", [
    ('species = "laurel"\nseeds = [1]\npath = "data/tree"', "not seeds and path"),
    ('path = "data/missing"', "data/missing not found"),
    ('path = "data/empty"', "neither scan/scan.ply nor views/cameras.json"),
    ('path = "data/tree"\nspecies = "no_such_species"', "species hint"),
    ('path = "data/tree"\nscale = 0.5', "does not apply to a case folder"),
])
def test_bad_case_folders_name_the_suite_file(tmp_path, cases, message):
    (tmp_path / "data" / "empty").mkdir(parents=True)
    (tmp_path / "data" / "tree" / "scan").mkdir(parents=True)
    (tmp_path / "data" / "tree" / "scan" / "scan.ply").write_text("not read at load")
    suite_file = _suite(tmp_path / "bad.toml", "[[cases]]\n" + cases)
    with pytest.raises(InputError, match=message) as info:
        load_suite(str(suite_file))
    assert str(suite_file) in str(info.value)


def test_two_case_folders_with_one_name_are_refused(tmp_path):
    from plantbench.runner.plan import make_plan

    for parent in ("x", "y"):
        (tmp_path / parent / "tree" / "views").mkdir(parents=True)
        (tmp_path / parent / "tree" / "views" / "cameras.json").write_text("{}")
    suite = load_suite(str(_suite(tmp_path / "dup.toml", '[[cases]]\npath = "x/tree"\n[[cases]]\npath = "y/tree"')))
    with pytest.raises(InputError, match="two cases named 'tree'"):
        make_plan(suite)
