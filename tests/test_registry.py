import pytest

from plantbench.errors import InputError, UnknownNameError
from plantbench.registry import Registry, methods


def test_register_get_and_names():
    reg = Registry("thing")
    reg.register("alpha", 1)

    @reg.register("beta")
    def beta():
        return 2

    assert reg.get("alpha") == 1 and reg.get("beta") is beta
    assert reg.names() == ["alpha", "beta"]
    assert "alpha" in reg and "gamma" not in reg


def test_duplicate_refused():
    reg = Registry("thing")
    reg.register("alpha", 1)
    with pytest.raises(InputError, match="already registered"):
        reg.register("alpha", 2)
    assert reg.get("alpha") == 1


def test_unknown_name_did_you_mean():
    reg = Registry("suite")
    for n in ("quick", "multiview", "scan"):
        reg.register(n, n)
    with pytest.raises(UnknownNameError) as err:
        reg.get("quik")
    msg = str(err.value)
    assert "did you mean 'quick'" in msg
    assert "Available: multiview, quick, scan" in msg


def test_unknown_name_without_close_match_lists_available():
    reg = Registry("method")
    reg.register("guo", 1)
    with pytest.raises(UnknownNameError) as err:
        reg.get("zzzzzz")
    assert "did you mean" not in str(err.value) and "Available: guo" in str(err.value)


def test_lazy_loader_runs_once():
    calls = []

    def loader(r):
        calls.append(1)
        r.register("x", 1)

    reg = Registry("thing", loader)
    assert calls == []
    reg.names()
    reg.get("x")
    assert calls == [1]


def test_methods_entry_point_loads_gt():
    gt = methods.get("gt")
    assert gt.name == "gt" and gt.inputs == "views"
