import json

import pytest
from pydantic import ValidationError

from plantbench.errors import InputError
from plantbench.schemas import CamerasJson, load_json
from plantbench.suites import Suite, load_suite, suites


def test_every_shipped_suite_validates():
    assert {"quick", "multiview", "scan", "views-sweep", "noise-sweep"} <= set(suites.names())
    from plantbench.paths import data_dir

    for name in suites.names():
        if name == "real" and not (data_dir() / "real").is_dir():
            # read in place from the data folder; where it is absent, loading says so and names the setting
            with pytest.raises(InputError, match="not found .*PLANTBENCH_DATA"):
                load_suite(name)
            continue
        s = load_suite(name)
        assert s.name == name


def test_unknown_field_named(tmp_path):
    p = tmp_path / "cams.json"
    p.write_text(json.dumps({"cameras": [], "colour": 1}))
    with pytest.raises(InputError, match=r"cams.json: colour: unknown field"):
        load_json(p, CamerasJson)


def test_malformed_json_named(tmp_path):
    p = tmp_path / "cams.json"
    p.write_text("{not json")
    with pytest.raises(InputError, match=r"cams.json: malformed JSON"):
        load_json(p, CamerasJson)


def test_suite_invalid_value_names_field(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text('name = "bad"\ndescription = "x"\nmethods = ["gt"]\n[[cases]]\nspecies = "maple"\nseeds = [1]\n'
                 "[capture]\nviews = 0\n")
    with pytest.raises(InputError, match=r"bad.toml: capture.views: Input should be greater than or equal to 1"):
        load_suite(str(p))


def test_suite_malformed_toml(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text("name = \n")
    with pytest.raises(InputError, match="malformed TOML"):
        load_suite(str(p))


def test_suite_model_forbids_extra():
    with pytest.raises(ValidationError, match="extra"):
        Suite(name="x", description="y", cases=[{"species": "a", "seeds": [1]}], methods=["gt"], extra=1)


def test_sweep_with_linked_settings():
    """A sweep level sets the swept value and each linked setting's value at the same position."""
    from plantbench.runner.plan import make_plan
    from plantbench.suites import apply_override

    suite = load_suite("scan")
    levels = suite.sweep.levels()
    assert [v for v, _ in levels] == [0.005, 0.01, 0.02, 0.05]
    s = apply_override(suite, levels[3][1])
    assert (s.capture.scan_spacing, s.capture.registration_error, s.capture.range_noise_per_m) == (0.05, 0.02, 0.002)
    plan = make_plan(suite, ["gt"])
    captures = [j for j in plan.jobs.values() if j.kind == "capture"]
    assert len(captures) == 4 * sum(c.count for c in suite.cases)
    assert {(j.params["settings"]["scan_spacing"], j.params["settings"]["registration_error"]) for j in captures} \
        == {(0.005, 0.002), (0.01, 0.005), (0.02, 0.01), (0.05, 0.02)}
    data = suite.model_dump(mode="python")
    data["sweep"]["linked"]["capture.registration_error"] = [0.1]
    with pytest.raises(ValidationError, match="1 values for 4 sweep values"):
        Suite.model_validate(data)
    data["sweep"]["linked"] = {"capture.stations": [1, 2, 3, 99]}
    with pytest.raises(InputError, match="stations"):
        make_plan(Suite.model_validate(data), ["gt"])


def test_sweep_labels_name_levels_that_share_a_value():
    """Two levels with the same swept value (512 px, with and without denoising) are told apart by their labels;
    labels must be distinct and one per value."""
    from plantbench.runner.plan import make_plan

    base = {"name": "s", "description": "d", "methods": ["gt"], "cases": [{"species": "laurel", "seeds": [1]}]}
    sweep = {"parameter": "capture.width", "values": [512, 512, 1024], "labels": ["512", "512-dn", "1024"],
             "linked": {"capture.denoise": [False, True, False]}}
    suite = Suite.model_validate({**base, "sweep": sweep})
    assert [name for name, _ in suite.sweep.levels()] == ["512", "512-dn", "1024"]
    plan = make_plan(suite, ["gt"])
    captures = {j.params["settings"]["width"] * 10 + j.params["settings"]["denoise"]
                for j in plan.jobs.values() if j.kind == "capture"}
    assert captures == {5120, 5121, 10240}
    assert {c.case for c in plan.cells} == {"laurel-1@512", "laurel-1@512-dn", "laurel-1@1024"}
    with pytest.raises(ValidationError, match="distinct names"):
        Suite.model_validate({**base, "sweep": {**sweep, "labels": None}})
    with pytest.raises(ValidationError, match="2 labels for 3"):
        Suite.model_validate({**base, "sweep": {**sweep, "labels": ["a", "b"]}})


def test_sweep_linked_default_leaves_the_setting_alone():
    """A linked "default" sets nothing at its level: that level's settings, and so its method jobs' cache keys, are
    those of the sweep without the linked setting; the other levels get the value."""
    from plantbench.runner.plan import make_plan

    base = {"name": "s", "description": "d", "methods": ["mvs"], "cases": [{"species": "laurel", "seeds": [1]}],
            "method_options": {"mvs": {"depth_params__background_span": 0.5}}}
    two = {"parameter": "capture.width", "values": [512, 1024], "labels": ["512", "1024"]}
    three = {"parameter": "capture.width", "values": [512, 1024, 1024], "labels": ["512", "1024", "1024-at-512"],
             "linked": {"method_options.mvs.max_size": ["default", "default", 512]}}

    def mvs_jobs(sweep):
        plan = make_plan(Suite.model_validate({**base, "sweep": sweep}), ["mvs"])
        jobs = {key: j for key, j in plan.jobs.items() if j.kind != "capture" and j.params.get("method") == "mvs"}
        return plan, jobs

    plan, jobs3 = mvs_jobs(three)
    options = sorted((sorted(j.params["options"].items()) for j in jobs3.values()), key=len)
    assert options == [[("depth_params__background_span", 0.5)]] * 2 + [[("depth_params__background_span", 0.5),
                                                                          ("max_size", 512)]]
    assert {c.case for c in plan.cells} == {"laurel-1@512", "laurel-1@1024", "laurel-1@1024-at-512"}
    keys2, keys3 = set(mvs_jobs(two)[1]), set(jobs3)
    assert len(keys2) == 2 and len(keys3) == 3
    assert keys2 < keys3  # the two old levels' mvs jobs are the same jobs, the new level adds one
