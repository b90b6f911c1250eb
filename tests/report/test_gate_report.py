"""Gate and report over synthetic results tables (real metric names, so directions come from the registry)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from plantbench.report.gate import Baseline, compare, make_baseline, write_baseline
from plantbench.report.report import write_report
from plantbench.report.tables import aggregate, bootstrap_ci


def _table(rng, s_t_shift=0.0, d_shift=0.0, fail_case=None):
    rows = []
    for family, species in (("space-colonisation", "maple"), ("space-colonisation", "laurel"), ("weber-penn", "aspen")):
        for seed in (1, 2):
            case = f"{species}-{seed}"
            for method, s_t, d in (("gt", 1.0, 0.0), ("livny", 0.8, 0.5)):
                status = "failed" if (case, method) == fail_case else "ok"
                values = {"stava.S_T": s_t - (s_t_shift if method == "livny" else 0) + rng.normal(0, 0.005),
                          "mesh_to_scan.D_cm": d + (d_shift if method == "livny" else 0) + abs(rng.normal(0, 0.01)),
                          "leaves.count_gt": 100.0, "runtime_s": rng.uniform(1, 5)}
                for metric, value in values.items():
                    rows.append({"case": case, "species": species, "family": family, "seed": seed, "method": method,
                                 "sweep": None, "metric": metric, "value": None if status != "ok" else value,
                                 "status": status})
    return pd.DataFrame(rows)


def test_bootstrap_ci_brackets_the_mean(rng):
    v = rng.normal(3.0, 1.0, 40)
    lo, hi = bootstrap_ci(v)
    assert lo < v.mean() < hi
    # the percentile interval of the mean is close to the normal-theory interval for n = 40
    half = 1.96 * v.std(ddof=1) / np.sqrt(v.size)
    assert hi - lo == pytest.approx(2 * half, rel=0.25)
    assert bootstrap_ci(np.array([2.0])) == (2.0, 2.0)
    assert all(np.isnan(bootstrap_ci(np.array([]))))


def test_aggregate_counts_failures(rng):
    agg = aggregate(_table(rng, fail_case=("maple-1", "livny")), ("method",))
    row = agg[(agg["method"] == "livny") & (agg["metric"] == "stava.S_T")].iloc[0]
    assert row["n"] == 5 and row["failed"] == 1


def test_baseline_skips_descriptive_and_runtime(rng):
    b = make_baseline(_table(rng), "t")
    names = {(e.method, e.metric) for e in b.entries}
    assert ("livny", "stava.S_T") in names and ("livny", "mesh_to_scan.D_cm") in names
    assert not any(m in ("leaves.count_gt", "runtime_s") for _, m in names)
    s_t = next(e for e in b.entries if e.metric == "stava.S_T")
    d = next(e for e in b.entries if e.metric == "mesh_to_scan.D_cm")
    assert s_t.higher_is_better is True and d.higher_is_better is False


def test_gate_is_direction_aware(rng):
    base = make_baseline(_table(np.random.default_rng(1)), "t")
    same = compare(_table(np.random.default_rng(1)), base)
    assert not same["regressed"].any()
    worse = compare(_table(np.random.default_rng(1), s_t_shift=0.2), base)
    assert set(worse.loc[worse["regressed"], "metric"]) == {"stava.S_T"}
    better = compare(_table(np.random.default_rng(1), s_t_shift=-0.1, d_shift=-0.3), base)
    assert not better["regressed"].any()
    worse_d = compare(_table(np.random.default_rng(1), d_shift=+0.3), base)
    assert set(worse_d.loc[worse_d["regressed"], "metric"]) == {"mesh_to_scan.D_cm"}


def test_gate_flags_a_method_that_newly_fails():
    rows = _table(np.random.default_rng(1))
    base = make_baseline(rows, "t")
    rows.loc[rows["method"] == "livny", ["value", "status"]] = [None, "failed"]
    res = compare(rows, base)
    assert res.loc[res["method"] == "livny", "regressed"].all()


def _good_and_bad_runs(tmp_path):
    """Two run folders of the same cells, the second with livny's D 1 cm worse everywhere, and a baseline made from
    the first; returns (good, bad, the baseline's table)."""
    good, bad = tmp_path / "good", tmp_path / "bad"
    good.mkdir()
    bad.mkdir()
    _table(np.random.default_rng(1)).to_csv(good / "results.csv", index=False)
    _table(np.random.default_rng(1), d_shift=1.0).to_csv(bad / "results.csv", index=False)
    base = pd.read_csv(good / "results.csv")
    write_baseline(tmp_path / "baseline.json", make_baseline(base, "t"))
    return good, bad, base


def test_gate_cli_names_the_regressed_metric(tmp_path):
    good, bad, _ = _good_and_bad_runs(tmp_path)
    cli = [sys.executable, "-m", "plantbench.cli", "gate"]
    ok = subprocess.run([*cli, str(good), "--baseline", str(tmp_path / "baseline.json")], capture_output=True,
                        text=True)
    assert ok.returncode == 0, ok.stdout + ok.stderr
    fail = subprocess.run([*cli, str(bad), "--baseline", str(tmp_path / "baseline.json")], capture_output=True,
                          text=True, env={"COLUMNS": "200", "PATH": "/usr/bin:/bin"})
    assert fail.returncode == 1
    assert "mesh_to_scan.D_cm" in fail.stdout and "stava.S_T" not in fail.stdout
    # every livny cell regressed (the shift is the same in each) and livny's mean over them, none of gt's
    assert "7 of 28 headline metrics regressed" in fail.stdout and "maple-2" in fail.stdout
    assert "mean" in fail.stdout


def test_gate_in_a_pipe_prints_one_whole_line_per_regression(tmp_path):
    """A CI log: plain lines, full metric names, no box drawing, nothing cut even on a narrow COLUMNS."""
    _, bad, base = _good_and_bad_runs(tmp_path)
    fail = subprocess.run([sys.executable, "-m", "plantbench.cli", "gate", str(bad), "--baseline",
                           str(tmp_path / "baseline.json")], capture_output=True, text=True,
                          env={"COLUMNS": "40", "PATH": "/usr/bin:/bin"})
    assert fail.returncode == 1, fail.stderr
    lines = fail.stdout.splitlines()
    assert not set("".join(lines)) & set("│┃━─┏┓┗┛┡┩└┘╇…")
    rows = [line for line in lines if line.startswith("regressed: ")]
    assert len(rows) == 7 and lines[-1].startswith("gate failed: 7 of 28 headline metrics regressed")
    expected = base[(base["method"] == "livny") & (base["metric"] == "mesh_to_scan.D_cm")].set_index("case")["value"]
    for case, value in expected.items():
        row = next(r for r in rows if f" case={case} " in r)
        fields = dict(f.split("=", 1) for f in row.removeprefix("regressed: ").split(" ") if "=" in f)
        assert fields["method"] == "livny" and fields["metric"] == "mesh_to_scan.D_cm" and fields["better"] == "lower"
        assert float(fields["baseline"]) == pytest.approx(value, rel=1e-3)
        assert float(fields["now"]) - float(fields["baseline"]) == pytest.approx(1.0, abs=0.05)
        assert float(fields["change"]) == pytest.approx(1.0, abs=0.05) and float(fields["tolerance"]) > 0


def test_baseline_file_is_validated(tmp_path):
    from plantbench.errors import InputError
    from plantbench.report.gate import load_baseline

    (tmp_path / "b.json").write_text('{"suite": "x", "entries": [{"method": "gt"}]}')
    with pytest.raises(InputError, match="b.json: entries.0.case: Field required"):
        load_baseline(tmp_path / "b.json")
    assert Baseline(suite="x", entries=[]).entries == []


def test_report_writes_every_format_with_family_rows(tmp_path, rng):
    run = tmp_path / "run"
    run.mkdir()
    _table(rng, fail_case=("aspen-2", "livny")).to_parquet(run / "results.parquet")
    files = write_report(run)
    names = {f.name for f in files}
    assert {"report.md", "report.tex", "report.html", "overall.csv", "family.csv", "metrics.png"} <= names
    md = (run / "report" / "report.md").read_text()
    assert "weber-penn" in md and "space-colonisation" in md and "(1 failed)" in md
    tex = (run / "report" / "report.tex").read_text()
    assert r"\begin{tabular}" in tex and "stava.S\\_T" in tex
    fam = pd.read_csv(run / "report" / "family.csv")
    assert set(fam["family"]) == {"space-colonisation", "weber-penn"} and set(fam["method"]) == {"gt (oracle)", "livny"}  # the oracle is marked


def test_family_study_ranks_methods_per_family(tmp_path, rng):
    from plantbench.report.report import family_ranking, family_study

    t = _table(rng)
    # make livny the best on weber-penn only (it beats a third method there, loses to it elsewhere)
    third = t[t["method"] == "livny"].copy()
    third["method"] = "xu"
    wp = third["family"] == "weber-penn"
    third.loc[(third["metric"] == "stava.S_T") & ~wp, "value"] += 0.1
    third.loc[(third["metric"] == "stava.S_T") & wp, "value"] -= 0.1
    t = pd.concat([t, third], ignore_index=True)
    ranking = family_ranking(t)
    s_t = ranking[ranking["metric"] == "stava.S_T"]
    assert list(s_t[s_t["family"] == "space-colonisation"].sort_values("rank")["method"]) == ["xu", "livny"]
    assert list(s_t[s_t["family"] == "weber-penn"].sort_values("rank")["method"]) == ["livny", "xu"]
    assert "gt" not in set(ranking["method"])
    text = family_study(t)
    assert "| stava.S_T |" in text and "-1.00" in text


def test_run_summary_is_plain_and_fits_80_columns(rng):
    """The quick suite's ten method columns as rows and the headline across: no box-drawing character, no value cut
    to an ellipsis, every line within 80 columns; means and half-widths as aggregate computes them."""
    from plantbench.metrics.info import HEADLINE, short_label
    from plantbench.report.tables import summary_lines

    methods = ["gt", "prior", "mvs", "livny", "xu", "guo", "livny@oracle", "xu@oracle", "guo@oracle"]
    rows = [{"case": f"c{c}", "species": "s", "family": "f", "seed": 1, "method": m, "sweep": None, "metric": metric,
             "value": float(rng.uniform(0, 1)), "status": "failed" if (m, c) == ("xu", 2) else "ok"}
            for m in methods for c in range(3) for metric in HEADLINE]
    table = pd.DataFrame(rows)
    table.loc[table["status"] != "ok", "value"] = np.nan
    lines = summary_lines(table, oracles=("gt", "prior", "livny@oracle", "xu@oracle", "guo@oracle"))
    text = "\n".join(lines)
    assert all(len(line) <= 80 for line in lines)
    assert "…" not in text and not any(0x2500 <= ord(ch) <= 0x257F for ch in text)
    assert "failed cells: xu 1" in text and "* oracle" in text
    agg = aggregate(table).set_index(["metric", "method"])
    guo = next(line for line in lines if line.startswith("guo "))
    mean, lo, hi = agg.loc[(HEADLINE[0], "guo"), ["mean", "lo", "hi"]]
    assert guo.split()[1] == f"{mean:.3f}±{(hi - lo) / 2:.2g}"
    assert lines[1].split()[0] == "method"
    # the headline's columns (the short labels, each once) in blocks of the method rows, a blank line between
    blocks = [i for i, line in enumerate(lines) if line.startswith("method ")]
    headers = [label for i in blocks for label in lines[i].split("  ")[1:] if label.strip()]
    assert [h.strip() for h in headers] == [short_label(m) for m in HEADLINE]
    assert len(lines) == 1 + len(blocks) * (1 + len(methods)) + (len(blocks) - 1) + 3
