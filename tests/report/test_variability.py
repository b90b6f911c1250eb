"""The variability study's tolerances, and the gate with them: it passes every run of the committed study and
fails a run whose headline metric is degraded beyond its tolerance."""

from __future__ import annotations

import math
import shutil
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from plantbench.paths import project_root
from plantbench.report.gate import (
    FLOORS,
    GATED,
    compare,
    load_baseline,
    load_tolerances,
    make_baseline,
    tolerances_path,
)
from plantbench.report.variability import (
    PERTURBATIONS,
    another_cpu,
    available_perturbations,
    extend_study,
    study_perturbations,
    tolerances_from_study,
)

REPORTS = project_root() / "reports"


def _study(cells: dict[tuple[str, str, str], list[float]]) -> pd.DataFrame:
    """Long study table; each cell's first value is the reference run's."""
    names = ["reference", "a", "b", "c", "d", "e", "f"]
    return pd.DataFrame([{"perturbation": names[i], "method": m, "case": c, "metric": k, "value": v}
                         for (m, c, k), values in cells.items() for i, v in enumerate(values)])


def test_tolerance_is_the_largest_of_three_terms():
    study = _study({
        ("guo", "maple-1", "stava.S_T"): [0.50, 0.52, 0.48],                 # sd 0.02: 3 sd = 0.06
        ("guo", "maple-1", "leaves.accuracy"): [0.60, 0.50, 0.50, 0.50],     # the reference is the outlier
        ("gt", "maple-1", "stava.S_T"): [1.0, 1.0, 1.0],                     # no spread: the floor
        ("xu", "maple-1", "stava.S_T"): [float("nan"), 0.3, 0.3],            # no reference value: not gated
        ("xu", "laurel-1", "reprojection.iou"): [0.4, float("nan"), 0.41, 0.39],  # a failed run is left out
    })
    tol = {(e.method, e.case, e.metric): e for e in tolerances_from_study(study, "t").entries}
    assert set(tol) == {("guo", "maple-1", "stava.S_T"), ("guo", "maple-1", "leaves.accuracy"),
                        ("gt", "maple-1", "stava.S_T"), ("xu", "laurel-1", "reprojection.iou")}
    e = tol[("guo", "maple-1", "stava.S_T")]
    assert e.sd == pytest.approx(0.02) and e.tolerance == pytest.approx(0.06) and e.bound == "spread"
    assert e.max_change == pytest.approx(0.02) and e.runs == 3
    e = tol[("guo", "maple-1", "leaves.accuracy")]
    # values 0.6, 0.5, 0.5, 0.5: mean 0.525, sample sd = sqrt(3 * 0.025^2 + 0.075^2) / sqrt(3) = 0.05
    assert e.sd == pytest.approx(0.05) and e.max_change == pytest.approx(0.1)
    assert e.tolerance == pytest.approx(0.15) and e.bound == "spread"
    e = tol[("gt", "maple-1", "stava.S_T")]
    assert e.sd == 0 and e.tolerance == FLOORS["stava.S_T"] and e.bound == "floor"
    e = tol[("xu", "laurel-1", "reprojection.iou")]
    assert e.runs == 3 and e.sd == pytest.approx(0.01)


def test_max_change_binds_when_it_exceeds_three_sd():
    # a cell with many identical runs and one far one: sd = 0.1 * sqrt(1/12) ~ 0.029 (n = 12), 3 sd ~ 0.087 < 0.1
    values = [0.5] * 11 + [0.6]
    study = pd.DataFrame([{"perturbation": "reference" if i == 0 else f"p{i}", "method": "m", "case": "c",
                           "metric": "stava.S_T", "value": v} for i, v in enumerate(values)])
    (e,) = tolerances_from_study(study, "t").entries
    assert e.sd == pytest.approx(np.std(values, ddof=1))
    assert 3 * e.sd < 0.1 and e.bound == "max_change" and e.tolerance == pytest.approx(0.1)


def test_perturbations_start_with_the_reference():
    assert PERTURBATIONS[0].name == "reference" and not PERTURBATIONS[0].env and not PERTURBATIONS[0].capture
    chosen = available_perturbations(["threads2"])
    assert [p.name for p in chosen] == ["reference", "threads2"]
    from plantbench.errors import InputError

    with pytest.raises(InputError, match="unknown perturbation"):
        available_perturbations(["warp-speed"])


def test_another_cpus_run_grows_the_study_and_its_tolerances():
    # a study made on one machine; the same configuration on another CPU moves S_T by 0.2: the tolerance covers it,
    # the reference (and so the baseline) stays the first machine's, and a second run of that CPU replaces the first
    first = _study({("guo", "maple-1", "stava.S_T"): [0.50, 0.51, 0.49]})
    other = another_cpu("AMD EPYC 9B45 (Zen 5)")
    assert other.name == "cpu-amd-epyc-9b45-zen-5" and "AMD EPYC 9B45" in other.description
    moved = pd.DataFrame([{"method": "guo", "case": "maple-1", "metric": "stava.S_T", "value": 0.70, "status": "ok"}])
    grown = extend_study(first, {other.name: moved})
    grown = grown[grown["case"] == "maple-1"]  # (the added run also has the suite's mean, cell_values' "mean" case)
    assert len(grown) == 4 and set(grown["perturbation"]) == {"reference", "a", "b", other.name}
    (e,) = tolerances_from_study(grown, "t").entries
    assert e.tolerance >= 0.2 and e.max_change == pytest.approx(0.2)
    again = extend_study(grown, {other.name: moved.assign(value=0.55)})
    again = again[again["case"] == "maple-1"]
    assert len(again) == 4 and again.loc[again["perturbation"] == other.name, "value"].tolist() == [0.55]
    assert study_perturbations(again)[0].name == "reference" and study_perturbations(again)[-1].name == other.name


# ------------------------------------------------------------------------------ the committed study and baseline

@pytest.fixture(scope="module")
def committed():
    study = pd.read_csv(REPORTS / "variability" / "study.csv")
    baseline = load_baseline(REPORTS / "baseline.json")
    tolerances = load_tolerances(tolerances_path(REPORTS / "baseline.json"))
    return study, baseline, tolerances


def _as_results(study: pd.DataFrame, run: str) -> pd.DataFrame:
    t = study[study["perturbation"] == run].drop(columns="perturbation").copy()
    t["status"] = np.where(t["value"].notna(), "ok", "failed")
    return t


def test_committed_baseline_is_the_studys_reference_run(committed):
    study, baseline, tolerances = committed
    ref = _as_results(study, "reference")
    values = {(r.method, r.case, r.metric): r.value for r in ref.itertuples()}
    assert baseline.entries and {e.metric for e in baseline.entries} <= set(GATED)
    for e in baseline.entries:
        assert values[(e.method, e.case, e.metric)] == pytest.approx(e.value, rel=1e-12, abs=1e-12)
    covered = {(t.method, t.case, t.metric) for t in tolerances.entries}
    assert {(e.method, e.case, e.metric) for e in baseline.entries} <= covered
    assert tolerances.perturbations[0] == "reference" and len(tolerances.perturbations) >= 5


def test_gate_passes_every_run_of_the_study(committed):
    study, baseline, tolerances = committed
    for run in sorted(set(study["perturbation"])):
        result = compare(_as_results(study, run), baseline, tolerances)
        assert not result["regressed"].any(), (run, result[result["regressed"]])
        assert (result["source"] == "study").all()


def _moves_the_mean(ref, tolerances, method: str, metric: str, change: float) -> bool:
    """Whether changing one case of ``method`` by ``change`` moves its mean over its cases (by change / their
    number) beyond the mean's own tolerance (the mean varies less than one case, so its tolerance is tighter)."""
    cases = ref.loc[(ref["method"] == method) & (ref["metric"] == metric) & (ref["case"] != "mean"), "case"].nunique()
    mean_tol = {(t.method, t.case, t.metric): t.tolerance for t in tolerances.entries}.get((method, "mean", metric))
    return mean_tol is not None and abs(change) / cases > mean_tol * (1 + 1e-6)


@pytest.mark.parametrize("metric", ["stava.S_T", "mesh_to_scan.D_cm", "points.all.fscore@1%"])
def test_gate_fails_a_headline_metric_degraded_beyond_its_tolerance(committed, metric):
    study, baseline, tolerances = committed
    entry = next(e for e in baseline.entries if e.metric == metric and e.method != "gt")
    tol = next(t.tolerance for t in tolerances.entries if (t.method, t.case, t.metric) ==
               (entry.method, entry.case, entry.metric))
    ref = _as_results(study, "reference")
    where = (ref["method"] == entry.method) & (ref["case"] == entry.case) & (ref["metric"] == metric)
    bad_sign = -1.0 if entry.higher_is_better else 1.0
    for factor, fails in ((1.05, True), (0.95, False), (-5.0, False)):  # beyond, within, an improvement
        run = ref.copy()
        run.loc[where, "value"] = entry.value + bad_sign * factor * tol
        result = compare(run, baseline, tolerances)
        flagged = result.loc[result["regressed"], ["method", "case", "metric"]].to_records(index=False).tolist()
        expected = [(entry.method, entry.case, metric)] if fails else []
        if entry.case != "mean" and factor > 0 and _moves_the_mean(ref, tolerances, entry.method, metric, factor * tol):
            expected.append((entry.method, "mean", metric))
        assert sorted(flagged) == sorted(expected), factor


def test_gate_cli_on_a_degraded_copy_of_a_run(committed, tmp_path):
    """A copy of the reference run with one cell's S_T lowered beyond its tolerance: exit 1, and the output names
    the method, case, metric and the tolerance; the copy as it is passes."""
    study, baseline, tolerances = committed
    ref = _as_results(study, "reference")
    ok_run, bad_run = tmp_path / "ok", tmp_path / "bad"
    for d in (ok_run, bad_run):
        d.mkdir()
    ref.to_csv(ok_run / "results.csv", index=False)
    entry = next(e for e in baseline.entries if e.metric == "stava.S_T" and e.method == "guo")
    tol = next(t for t in tolerances.entries if (t.method, t.case, t.metric) == (entry.method, entry.case, entry.metric))
    bad = ref.copy()
    where = (bad["method"] == "guo") & (bad["case"] == entry.case) & (bad["metric"] == "stava.S_T")
    bad.loc[where, "value"] = entry.value - 2 * tol.tolerance
    bad.to_csv(bad_run / "results.csv", index=False)
    shutil.copy(REPORTS / "baseline.json", tmp_path / "baseline.json")
    shutil.copy(REPORTS / "tolerances.json", tmp_path / "tolerances.json")
    cli = [sys.executable, "-m", "plantbench.cli", "gate", "--baseline", str(tmp_path / "baseline.json")]
    env = {"COLUMNS": "200", "PATH": "/usr/bin:/bin"}
    ok = subprocess.run([*cli, str(ok_run)], capture_output=True, text=True, env=env)
    assert ok.returncode == 0 and "gate passed" in ok.stdout, ok.stdout + ok.stderr
    fail = subprocess.run([*cli, str(bad_run)], capture_output=True, text=True, env=env)
    assert fail.returncode == 1, fail.stdout + fail.stderr
    flagged = 1 + int(_moves_the_mean(ref, tolerances, "guo", "stava.S_T", 2 * tol.tolerance))  # and guo's mean?
    assert f"gate failed: {flagged} of" in fail.stdout
    line = next(ln for ln in fail.stdout.splitlines() if "stava.S_T" in ln)
    assert "guo" in line and entry.case in line and f"{tol.tolerance:.3g}" in line
    assert f"{-2 * tol.tolerance:+.3g}" in line


def test_baseline_from_a_table_keys_cells(rng):
    t = pd.DataFrame([{"case": c, "method": "guo", "metric": m, "value": rng.random(), "status": "ok"}
                      for c in ("a-1", "b-1") for m in ("stava.S_T", "runtime_s", "leaves.count_gt")])
    b = make_baseline(t, "t")
    assert sorted((e.case, e.metric) for e in b.entries) == [("a-1", "stava.S_T"), ("b-1", "stava.S_T"),
                                                             ("mean", "stava.S_T")]
    values = {e.case: e.value for e in b.entries}
    assert values["mean"] == pytest.approx((values["a-1"] + values["b-1"]) / 2)
    # a failed case leaves the mean without a value: not a baseline entry
    t.loc[(t["case"] == "b-1") & (t["metric"] == "stava.S_T"), ["value", "status"]] = [None, "failed"]
    assert [(e.case, e.metric) for e in make_baseline(t, "t").entries] == [("a-1", "stava.S_T")]
    assert all(math.isfinite(e.value) for e in b.entries)


def test_variability_cli_end_to_end(tmp_path):
    """`plantbench variability` on a tiny suite (gt only, two runs): writes the study, tolerances and baseline, and
    the gate passes the study's own runs with them."""
    from tests.runner.conftest import suite_toml

    toml = suite_toml(tmp_path / "tiny.toml", ["gt"])
    reports = tmp_path / "reports"
    proc = subprocess.run([sys.executable, "-m", "plantbench.cli", "variability", "--suite", str(toml), "--only",
                           "threads2", "--out", str(tmp_path / "runs"), "--reports", str(reports)],
                          capture_output=True, text=True, env={"COLUMNS": "200", "PATH": "/usr/bin:/bin"})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    study = pd.read_csv(reports / "variability" / "study.csv")
    assert set(study["perturbation"]) == {"reference", "threads2"}
    tol = load_tolerances(reports / "tolerances.json")
    assert tol.perturbations == ["reference", "threads2"] and tol.entries
    assert all(e.bound == "floor" for e in tol.entries if e.method == "gt")  # exact rows: no spread
    assert "# Variability study: suite tiny" in (reports / "variability" / "README.md").read_text()
    for run in ("reference", "threads2"):
        gate = subprocess.run([sys.executable, "-m", "plantbench.cli", "gate", str(tmp_path / "runs" / run / "tiny"),
                               "--baseline", str(reports / "baseline.json")], capture_output=True, text=True)
        assert gate.returncode == 0 and "gate passed" in gate.stdout, gate.stdout + gate.stderr


def test_two_cpus_with_one_model_name_make_two_runs():
    """Cloud AMD EPYCs report 'AMD EPYC' whatever their generation: the family and model numbers keep a Zen 4's and a
    Zen 5's --another-cpu runs apart (read from /proc/cpuinfo texts; the first processor counts)."""
    from plantbench.backend import cpu_name

    def info(family, model):
        one = f"processor\t: 0\nvendor_id\t: AuthenticAMD\ncpu family\t: {family}\nmodel\t\t: {model}\n" \
              "model name\t: AMD EPYC\nflags\t\t: fpu avx2\n"
        return one + "\n" + one.replace("processor\t: 0", "processor\t: 1").replace(f": {model}\n", ": 99\n", 1)

    zen4, zen5 = cpu_name(info(25, 17)), cpu_name(info(26, 2))
    assert zen4 == "AMD EPYC (family 25, model 17)" and zen5 == "AMD EPYC (family 26, model 2)"
    assert another_cpu(zen4).name != another_cpu(zen5).name
    assert cpu_name("processor\t: 0\nmodel name\t: Some CPU\n") == "Some CPU" and cpu_name("flags : x\n") is None


def test_input_runs_are_held_to_the_grey_level_noise():
    """Per method and metric: the largest change under the order and jitter runs against the largest under the grey
    level runs, over every cell, as a naive loop computes it."""
    from plantbench.report.variability import input_noise_against_grey

    rng = np.random.default_rng(4)
    rows = []
    for run in ("reference", "noise1-a", "noise1-b", "order", "jitter"):
        for method in ("livny", "xu"):
            for case in ("a-1", "b-1", "mean"):
                for metric in ("skeleton.vf1@1%", "stava.S_T"):
                    rows.append({"perturbation": run, "method": method, "case": case, "metric": metric,
                                 "value": rng.uniform(0, 1)})
    study = pd.DataFrame(rows)
    table = input_noise_against_grey(study, metrics=("skeleton.vf1@1%", "stava.S_T")).set_index(["method", "metric"])
    for (method, metric), got in table.iterrows():
        def largest(runs, method=method, metric=metric):
            best = 0.0
            for r in rows:
                if r["perturbation"] in runs and r["method"] == method and r["metric"] == metric:
                    ref = next(x["value"] for x in rows if x["perturbation"] == "reference" and x["method"] == method
                               and x["case"] == r["case"] and x["metric"] == metric)
                    best = max(best, abs(r["value"] - ref))
            return best

        assert got["grey"] == pytest.approx(largest({"noise1-a", "noise1-b"}))
        assert got["jitter"] == pytest.approx(largest({"jitter"}))
        assert got["within"] == (max(largest({"order"}), largest({"jitter"})) <= largest({"noise1-a", "noise1-b"}))
    assert input_noise_against_grey(study[study["perturbation"] != "order"]).columns.tolist()[-1] == "within"
    assert input_noise_against_grey(study[~study["perturbation"].isin(["order", "jitter"])]).empty


def test_a_cell_the_study_saw_fail_may_fail_but_not_degrade():
    """A cell that failed under a meaningless perturbation: failing now is not a regression, a worse value still is;
    a cell that never failed in the study regresses when it fails."""
    from plantbench.report.variability import study_table

    def results(xu, livny):
        return pd.DataFrame([{"case": "a-1", "method": m, "metric": "skeleton.vf1@1%", "value": v,
                              "status": "ok" if v == v else "failed"} for m, v in (("xu", xu), ("livny", livny))])

    study = study_table({"reference": results(0.5, 0.6), "noise1-a": results(float("nan"), 0.61),
                         "noise1-b": results(0.52, 0.59)})
    tol = tolerances_from_study(study, "t")
    flags = {(e.method, e.case): e.may_fail for e in tol.entries}
    assert flags[("xu", "a-1")] and flags[("xu", "mean")] and not flags[("livny", "a-1")]
    baseline = make_baseline(_as_results(study, "reference"), "t")

    now = results
    regressed = lambda t: {(r.method, r.case) for r in compare(t, baseline, tol).itertuples() if r.regressed}  # noqa: E731
    assert regressed(now(float("nan"), 0.6)) == set()
    assert regressed(now(0.5, float("nan"))) == {("livny", "a-1"), ("livny", "mean")}
    assert ("xu", "a-1") in regressed(now(0.3, 0.6))
