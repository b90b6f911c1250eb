"""Paired comparisons and the report's table formatting: fixed notation, best value marked, headline first."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from plantbench.metrics.info import HEADLINE
from plantbench.report.report import _BEST_MARK, comparison_table, headline_table, render_table, wide_table
from plantbench.report.tables import compare_runs, format_value, paired_differences


def _table(values: dict[str, dict[str, list[float]]]) -> pd.DataFrame:
    rows = [{"case": f"c{i}", "species": f"s{i % 2}", "family": "f", "method": method, "metric": metric,
             "value": v, "status": "ok"}
            for method, per in values.items() for metric, vs in per.items() for i, v in enumerate(vs)]
    return pd.DataFrame(rows)


def test_paired_difference_against_a_hand_bootstrap():
    rng = np.random.default_rng(0)
    base = rng.uniform(0.2, 0.8, 10)
    a = base + 0.1 + rng.normal(0, 0.01, 10)  # consistently above: beats, though the spread across cases is wide
    t = _table({"a": {"skeleton.vf1@1%": list(a), "mesh_to_surface.D_cm": list(5 + base)},
                "prior": {"skeleton.vf1@1%": list(base), "mesh_to_surface.D_cm": list(5 + base - 0.001 * (-1) ** np.arange(10))}})
    d = paired_differences(t, ("skeleton.vf1@1%", "mesh_to_surface.D_cm"), [("a", "prior")], n_boot=4000, seed=3)
    row = d.set_index("metric").loc["skeleton.vf1@1%"]
    diff = a - base
    g = np.random.Generator(np.random.PCG64(3))
    means = diff[g.integers(0, 10, (4000, 10))].mean(1)
    assert row["diff"] == pytest.approx(diff.mean())
    assert (row["lo"], row["hi"]) == pytest.approx(tuple(np.quantile(means, [0.025, 0.975])))
    assert row["verdict"] == "a beats prior" and row["n"] == 10
    # two species of five seeds each: the verdict's interval resamples seeds within species (a hand loop), the
    # across-plant one stays beside it; the minimum detectable difference is the verdict interval's half-width
    g = np.random.Generator(np.random.PCG64(3))
    sp = np.arange(10) % 2
    sums = np.zeros(4000)
    for k in (0, 1):
        grp = diff[sp == k]
        sums += grp[g.integers(0, 5, (4000, 5))].sum(1)
    assert (row["lo_species"], row["hi_species"]) == pytest.approx(tuple(np.quantile(sums / 10, [0.025, 0.975])))
    assert row["mdd"] == pytest.approx((row["hi_species"] - row["lo_species"]) / 2)
    # unpaired, the intervals of the two means overlap: the pairing is what makes it a win
    assert np.quantile(base, 0.9) > np.quantile(a, 0.1)
    assert d.set_index("metric").loc["mesh_to_surface.D_cm", "verdict"] == "within noise"
    worse = paired_differences(t, ("skeleton.vf1@1%",), [("prior", "a")])
    assert worse["verdict"].iloc[0] == "prior below a"


def test_one_seed_a_species_keeps_the_across_plant_interval_and_failures_count_zero():
    rows = [{"case": f"c{i}", "species": f"s{i}", "family": "f", "method": m, "metric": "skeleton.vf1@1%",
             "value": v, "status": "ok"} for m, vs in (("a", [0.5, 0.6, 0.7, 0.8]), ("b", [0.4, 0.5, 0.6, 0.7]))
            for i, v in enumerate(vs)]
    t = pd.DataFrame(rows)
    d = paired_differences(t, ("skeleton.vf1@1%",), [("a", "b")]).iloc[0]
    assert np.isnan(d["lo_species"]) and d["mdd"] == pytest.approx((d["hi"] - d["lo"]) / 2)
    t.loc[(t["method"] == "a") & (t["case"] == "c3"), ["value", "status"]] = [np.nan, "failed"]
    assert paired_differences(t, ("skeleton.vf1@1%",), [("a", "b")]).iloc[0]["n"] == 3  # the failure leaves
    zero = paired_differences(t, ("skeleton.vf1@1%",), [("a", "b")], failed_as_zero=True).iloc[0]
    assert zero["n"] == 4 and zero["diff"] == pytest.approx((0.1 * 3 - 0.7) / 4)


def test_lower_is_better_and_missing_cases():
    t = _table({"a": {"mesh_to_surface.D_cm": [1.0, 2.0, 3.0, np.nan]},
                "b": {"mesh_to_surface.D_cm": [2.0, 3.1, 4.2, 9.0]}})
    d = paired_differences(t, ("mesh_to_surface.D_cm",), [("a", "b")])
    assert d["n"].iloc[0] == 3 and d["diff"].iloc[0] == pytest.approx(-1.1)
    assert d["verdict"].iloc[0] == "a beats b"  # lower distance is better
    # a method that does not score the metric at all (a skeleton-only method's surface) is no pair, not 'within noise'
    t = pd.concat([t, _table({"c": {"mesh_to_surface.D_cm": [np.nan] * 4}})])
    d = paired_differences(t, ("mesh_to_surface.D_cm",), [("a", "b"), ("a", "c"), ("c", "b")])
    assert list(zip(d["a"], d["b"])) == [("a", "b")]


def test_fixed_notation():
    assert format_value(2840.0) == "2840" and format_value(12.345) == "12.3" and format_value(0.41234) == "0.412"
    assert format_value(3.14159, "cm") == "3.14" and format_value(float("nan")) == "-" and format_value(None) == "-"
    assert "e+" not in format_value(1.23e6)


def test_tables_mark_best_and_lead_with_headline():
    t = _table({"gt (oracle)": {"skeleton.vf1@1%": [1.0, 1.0], "stava.S_T": [1.0, 1.0]},
                "a": {"skeleton.vf1@1%": [0.5, 0.7], "stava.S_T": [0.4, 0.5]},
                "b": {"skeleton.vf1@1%": [0.4, 0.6], "stava.S_T": [0.6, 0.5]}})
    h = headline_table(t, ("skeleton.vf1@1%", "stava.S_T"))
    assert list(h["metric"])[0].startswith(HEADLINE[0])
    row = h.iloc[0]
    assert row["a"].startswith(_BEST_MARK) and not row["b"].startswith(_BEST_MARK)
    assert not row["gt (oracle)"].startswith(_BEST_MARK)  # an oracle is never "best"
    md = render_table(h, "md", "x")
    assert "**0.600" in md and _BEST_MARK not in md
    assert "<b>0.600" in render_table(h, "html", "x") and _BEST_MARK not in render_table(h, "csv", "x")
    w = wide_table(t, ("species", "method"), ("stava.S_T",))
    marked = w[w["stava.S_T"].str.startswith(_BEST_MARK)]
    assert set(marked["species"]) == {"s0", "s1"}  # best within each species
    comp, raw = comparison_table(t, ("skeleton.vf1@1%",))
    assert list(raw[["a", "b"]].itertuples(index=False, name=None)) == [("a", "b")]  # no prior: pairs only


def test_compare_runs_pairs_each_method_across_two_runs():
    # run b: guo's skeleton F1 up by 0.1 on every case (better), D up by 1 cm (worse: lower is better); xu only in
    # run a (left out); the means are those of the cases both runs scored (c4 failed in b)
    rng = np.random.default_rng(1)
    base = rng.uniform(0.2, 0.6, 6)
    a = _table({"guo": {"skeleton.vf1@1%": list(base), "mesh_to_surface.D_cm": list(4 + base)},
                "xu": {"skeleton.vf1@1%": list(base)}})
    b = _table({"guo": {"skeleton.vf1@1%": list(base + 0.1), "mesh_to_surface.D_cm": list(5 + base)}})
    b.loc[(b["case"] == "c4"), "status"] = "failed"
    t = compare_runs(a, b, label_a="mvs", label_b="oracle", metrics=("skeleton.vf1@1%", "mesh_to_surface.D_cm"))
    assert set(t["method"]) == {"guo"}
    row = t.set_index("metric").loc["skeleton.vf1@1%"]
    keep = np.arange(6) != 4
    assert row["n"] == 5 and row["diff"] == pytest.approx(0.1)
    assert row["mean_a"] == pytest.approx(base[keep].mean()) and row["mean_b"] == pytest.approx(base[keep].mean() + 0.1)
    assert row["verdict"] == "oracle better"
    assert t.set_index("metric").loc["mesh_to_surface.D_cm", "verdict"] == "oracle worse"


def test_per_family_comparisons_with_their_minimum_detectable_difference():
    """by='family': the paired differences within each family, over its own cases; the MDD shrinks with n (a paired
    bootstrap half-width falls about as 1 / sqrt(n))."""
    rng = np.random.default_rng(2)
    rows = []
    for n, family in ((6, "sc"), (24, "wp")):
        for i in range(n):
            base = rng.uniform(0.2, 0.8)
            for method, v in (("prior", base), ("a", base + 0.05 + rng.normal(0, 0.1))):
                rows.append({"case": f"{family}{i}", "species": "s", "family": family, "method": method,
                             "metric": "skeleton.vf1@1%", "value": v, "status": "ok"})
    t = pd.DataFrame(rows)
    fam, raw = comparison_table(t, ("skeleton.vf1@1%",), by="family")
    r = raw.set_index("family")
    assert list(fam.columns) == ["family", "metric", "comparison", "cases", "difference [95 % CI]", "MDD", "verdict"]
    assert (r.loc["sc", "n"], r.loc["wp", "n"]) == (6, 24) and r.loc["wp", "mdd"] < r.loc["sc", "mdd"]
    for family, sub in t.groupby("family"):
        alone = paired_differences(sub, ("skeleton.vf1@1%",), [("a", "prior")])
        assert alone["mdd"].iloc[0] == pytest.approx(r.loc[family, "mdd"])
