"""The report's observation tables against hand-made results."""

import numpy as np
import pandas as pd
import pytest

from plantbench.report.observation import (
    BREAST,
    INFERENCE,
    OBSERVATION,
    OBSERVED,
    observation_tables,
    observed_per_plant,
    oracle_ratio,
)
from plantbench.report.report import wide_table


def _rows(case, method, values, status="ok"):
    return [{"case": case, "species": case.split("-")[0], "family": "f", "method": method, "metric": m, "value": v,
             "status": status} for m, v in values.items()]


def _table():
    rows = []
    for case, share in (("a-1", 0.9), ("b-1", 0.7), ("c-1", 0.3)):
        for method, obs in (("livny", {"a-1": 0.6, "b-1": 0.5, "c-1": 0.2}),
                            ("livny@oracle (oracle)", {"a-1": 0.8, "b-1": 0.9, "c-1": 0.5})):
            rows += _rows(case, method, {OBSERVED: share, BREAST: 1.0, OBSERVATION: obs[case], INFERENCE: 0.1})
    return pd.DataFrame(rows)


def test_observed_share_per_plant_lowest_first():
    plants = observed_per_plant(_table())
    assert list(plants["case"]) == ["c-1", "b-1", "a-1"] and plants[OBSERVED].tolist() == [0.3, 0.7, 0.9]


def test_oracle_ratio_of_means_split_at_the_observed_share_with_failures_at_zero():
    t = _table()
    r = oracle_ratio(t).set_index("group")
    assert r.loc[">= 0.6", "plants"] == 2 and r.loc[">= 0.6", "ratio"] == pytest.approx((0.6 + 0.5) / (0.8 + 0.9))
    assert r.loc["< 0.6", "ratio"] == pytest.approx(0.2 / 0.5)
    failed = (t["method"] == "livny") & (t["case"] == "a-1") & (t["metric"] == OBSERVATION)
    t.loc[failed, ["value", "status"]] = [np.nan, "failed"]
    assert oracle_ratio(t).set_index("group").loc[">= 0.6", "ratio"] == pytest.approx(0.5 / 1.7)
    # a separate oracle run (its methods named as the run's own)
    oracle = t[t["method"] == "livny@oracle (oracle)"].assign(method="livny")
    mine = t[t["method"] == "livny"]
    assert oracle_ratio(mine, oracle).set_index("group").loc["< 0.6", "ratio"] == pytest.approx(0.4)


def test_observation_tables_only_with_the_metrics():
    slugs = [s for s, _, _ in observation_tables(_table(), wide_table)]
    assert slugs == ["observed", "inference", "oracle_ratio"]
    none = _table()[~_table()["metric"].isin([OBSERVED, BREAST])]
    assert observation_tables(none, wide_table) == []


def test_dbh_checked_only_where_the_stem_was_observed():
    from plantbench.report.observation import dbh_check

    rows = []
    for case, seen, gt, est in (("a-1", 1.0, 10.0, 10.5), ("b-1", 1.0, 20.0, 30.0), ("c-1", 0.0, 5.0, 20.0),
                                ("d-1", np.nan, np.nan, np.nan)):
        rows += _rows(case, "gt (oracle)", {OBSERVED: 0.5, BREAST: seen, "skeleton.dbh_cm": gt})
        rows += _rows(case, "xu", {OBSERVED: 0.5, BREAST: seen, "skeleton.dbh_cm": est})
    d = dbh_check(pd.DataFrame(rows)).set_index("method").loc["xu"]
    assert (d["checked"], d["within"], d["within_2x"], d["hidden"], d["short"]) == (2, 1, 2, 1, 1)
    assert d["median_rel_error"] == pytest.approx(np.median([0.05, 0.5]))


def test_dbh_checked_per_level_of_a_sweep():
    """A scan suite captures each plant at several beam spacings: the DBH check counts each level's plants against
    that level's truth, not a mix of the levels (here the 5 cm level's estimate is off, the 1 cm level's is not)."""
    from plantbench.report.observation import dbh_check

    rows = []
    for level, est in ((0.01, 10.5), (0.05, 14.0)):
        for method, value in (("gt (oracle)", 10.0), ("livny", est)):
            rows += [{**r, "sweep": level} for r in _rows("a-1", method, {OBSERVED: 0.9, BREAST: 1.0,
                                                                         "skeleton.dbh_cm": value})]
    d = dbh_check(pd.DataFrame(rows))
    assert list(d.columns[:2]) == ["sweep", "method"]
    by_level = d.set_index("sweep")
    assert by_level.loc[0.01, "within"] == 1 and by_level.loc[0.05, "within"] == 0
    assert by_level.loc[0.05, "median_rel_error"] == pytest.approx(0.4)
    plants = observed_per_plant(pd.DataFrame(rows))
    assert len(plants) == 2 and list(plants["sweep"]) == [0.01, 0.05]
