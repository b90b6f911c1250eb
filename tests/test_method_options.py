"""What a method can be told, from the command line: `plantbench methods NAME` lists the options of the model that
validates them, `plantbench reconstruct --option NAME=VALUE` passes them, checked before the method runs."""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import numpy as np
import pytest

from plantbench.errors import InputError
from plantbench.methods.api import method_from_spec
from plantbench.methods.options import describe_options, field_docstrings, parse_option, parse_options


def plantbench(*args):
    return subprocess.run([sys.executable, "-m", "plantbench.cli", *args], capture_output=True, text=True)


def test_parse_option_reads_toml_values_else_text():
    assert parse_option("k=3") == ("k", 3) and parse_option("noise = 0.5") == ("noise", 0.5)
    assert parse_option("ground__enabled=false") == ("ground__enabled", False)
    assert parse_option("elevation=[5, 45]") == ("elevation", [5, 45])
    assert parse_option("depth=oracle") == ("depth", "oracle") and parse_option('depth="oracle"')[1] == "oracle"
    for bad in ("k", "=3", "1k=3", "a b=1"):
        with pytest.raises(InputError, match="NAME=VALUE"):
            parse_option(bad)
    with pytest.raises(InputError, match="twice"):
        parse_options(["k=1", "k=2"])


@pytest.mark.parametrize("name", ["livny", "xu", "guo", "mvs", "leaves"])
def test_every_option_of_the_model_is_listed_with_its_default(name):
    method = method_from_spec(name)
    rows = {r.name: r for r in describe_options(method)}
    model = method.options_model
    models = model if isinstance(model, dict) else {"": model}
    for prefix, cls in models.items():
        docs = field_docstrings(cls)
        for f in dataclasses.fields(cls):
            default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
            if dataclasses.is_dataclass(default):
                assert any(k.startswith(f"{prefix}{f.name}__") for k in rows), f.name
                continue
            row = rows[prefix + f.name]
            assert row.default == default
            assert row.meaning and docs[f.name].replace("\n", " ").startswith(row.meaning[:-1]), f.name
    # each listed option is accepted by the method's own check, at its default
    for r in rows.values():
        method.check_options({r.name: r.default})


def test_units_come_from_the_name_or_the_first_sentence():
    rows = {r.name: r for r in describe_options(method_from_spec("xu"))}
    assert rows["cone_angle_deg"].unit == "deg" and rows["neighbourhood"].unit == "m"
    assert rows["synthesis_iterations"].unit == "-"


def test_methods_name_prints_the_options_in_a_pipe():
    out = plantbench("methods", "xu")
    assert out.returncode == 0, out.stderr
    lines = [line.split("\t") for line in out.stdout.splitlines()]
    assert lines[0] == ["option", "default", "unit", "meaning"]
    row = next(r for r in lines if r[0] == "stem_gap_share")
    assert row[1] == "0.5" and "root subgraph" in row[3]
    assert plantbench("methods", "prior").stdout.strip() == "prior: takes no options"
    assert plantbench("methods", "xuu").returncode == 2


@pytest.fixture(scope="module")
def cloud(tmp_path_factory):
    from plantbench.io.ply import write_points
    from tests.baselines.synthetic import random_tree, sample_surface

    rng = np.random.default_rng(3)
    pts = sample_surface(rng, random_tree(rng, height=1.0, levels=2, segment=0.04), 6000, ground=500)
    d = tmp_path_factory.mktemp("cloud")
    write_points(d / "points.ply", pts)
    return d


def test_reconstruct_passes_options_checked_before_the_method_runs(cloud, tmp_path):
    def run(out, *options):
        return plantbench("reconstruct", str(cloud), "--method", "livny", "--out", str(tmp_path / out), "--points",
                          str(cloud), *[a for o in options for a in ("--option", o)])

    bad = run("bad", "voxel_fractoin=0.02")
    assert bad.returncode == 2 and "did you mean 'voxel_fraction'" in bad.stderr
    assert not (tmp_path / "bad").exists()
    for out, options in (("default", ()), ("same", ("voxel_fraction=0.005",)), ("coarse", ("voxel_fraction=0.03",))):
        res = run(out, *options)
        assert res.returncode == 0, res.stderr
    skeleton = {k: (tmp_path / k / "skeleton.ply").read_bytes() for k in ("default", "same", "coarse")}
    assert skeleton["same"] == skeleton["default"] != skeleton["coarse"]
