"""The sweep figure's x values from a sweep column (plantbench.report.report.sweep_values)."""

import pandas as pd

from plantbench.report.report import sweep_ticks, sweep_values


def test_numbers_stay_numbers():
    assert sweep_values(pd.Series(["0.5", "2", "0.5"])).tolist() == [0.5, 2.0, 0.5]


def test_labels_with_a_number_give_the_number():
    # a suite's [sweep] labels, as the views-realism suite writes them
    assert sweep_values(pd.Series(["512px", "2048px", "1024px", "512px"])).tolist() == [512.0, 2048.0, 1024.0, 512.0]
    assert sweep_values(pd.Series(["sigma 1e-3", "sigma 2.5e-2"])).tolist() == [0.001, 0.025]


def test_labels_the_numbers_cannot_tell_apart_give_their_order():
    # two levels share the number 1 (the label is what names them): order of first appearance
    assert sweep_values(pd.Series(["1 station", "1 station dense", "3 stations", "1 station"])).tolist() == \
        [0.0, 1.0, 2.0, 0.0]
    assert sweep_values(pd.Series(["low", "high", "low"])).tolist() == [0.0, 1.0, 0.0]


def test_ticks_name_the_levels():
    # numbers: the numbers; labels with distinct numbers: those numbers; labels placed by their order: the labels
    numbers = pd.Series(["2", "0.5", "2"])
    assert sweep_ticks(numbers, sweep_values(numbers)) == ["0.5", "2"]
    px = pd.Series(["512px", "1024px", "2048px", "2048px-at-1024", "512px"])
    assert sweep_values(px).tolist() == [0.0, 1.0, 2.0, 3.0, 0.0]  # 2048 twice: by order
    assert sweep_ticks(px, sweep_values(px)) == ["512px", "1024px", "2048px", "2048px-at-1024"]
    distinct = pd.Series(["1024px", "512px"])
    assert sweep_ticks(distinct, sweep_values(distinct)) == ["512px", "1024px"]
