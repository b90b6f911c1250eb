"""Stage code hashes follow imports: editing a helper a stage imports (even inside a function, even through a
relative import) changes the stage's hash; editing a module it never imports does not."""

from __future__ import annotations

import textwrap

import pytest

from plantbench.runner.plan import code_hash


@pytest.fixture()
def package(tmp_path, monkeypatch):
    root = tmp_path / "src"
    files = {
        "pkgx/__init__.py": "",
        "pkgx/method/__init__.py": "from .core import run\n",
        "pkgx/method/core.py": textwrap.dedent(
            """
            def run():
                from pkgx.helpers.util import f  # imported where used
                return f()
            """
        ),
        "pkgx/helpers/__init__.py": "",
        "pkgx/helpers/util.py": "def f():\n    return 1\n",
        "pkgx/helpers/unused.py": "def g():\n    return 2\n",
    }
    for rel, text in files.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)
    monkeypatch.syspath_prepend(str(root))
    code_hash.cache_clear()
    yield root
    code_hash.cache_clear()


def _edit(path, text):
    path.write_text(path.read_text() + text)
    code_hash.cache_clear()


def test_hash_follows_function_level_and_relative_imports(package):
    method = str(package / "pkgx" / "method")
    before = code_hash(method)
    _edit(package / "pkgx" / "helpers" / "unused.py", "# not imported by the method\n")
    assert code_hash(method) == before
    _edit(package / "pkgx" / "helpers" / "util.py", "# a helper the method imports inside a function\n")
    after = code_hash(method)
    assert after != before
    _edit(package / "pkgx" / "method" / "core.py", "# the method itself\n")
    assert code_hash(method) != after


def test_shipped_method_hash_covers_common_helpers():
    """livny imports reference_impl.common and plantbench.plant: both are in its hash's closure."""
    from plantbench.paths import project_root
    from plantbench.runner.plan import _import_closure, _module_name

    start = tuple(sorted((project_root() / "reference_impl" / "livny").rglob("*.py")))
    names = {_module_name(f) for f in _import_closure(start, frozenset({"plantbench", "reference_impl"}))}
    assert {"reference_impl.common.graph", "reference_impl.common.radii", "plantbench.plant"} <= names
    assert "reference_impl.guo.growth" not in names
    # the metric registry's lazy loader (a framework hook) does not tie the method to the metrics code
    assert not any(n.startswith("plantbench.metrics") for n in names)


def test_runner_and_plant_stage_hashes_leave_other_stages_out():
    from plantbench.paths import project_root
    from plantbench.runner.plan import _import_closure, _module_name

    def closure(path):
        p = project_root() / path
        start = tuple(sorted(p.rglob("*.py"))) if p.is_dir() else (p,)
        return {_module_name(f) for f in _import_closure(start, frozenset({"plantbench"}))}

    worker = closure("plantbench/runner/worker.py")  # imports every stage lazily: module level only
    assert not any(n.startswith(("plantbench.generate", "plantbench.capture", "plantbench.metrics")) for n in worker)
    plant = closure("plantbench/generate")
    assert "plantbench.io.ply" in plant and not any(n.startswith("plantbench.metrics") for n in plant)


def test_methods_using_a_metric_helper_do_not_depend_on_the_metric_table():
    """mvs imports plantbench.metrics.surface and guo plantbench.metrics.reprojection: adding a metric to the table
    (plantbench.metrics.info) or a skeleton metric must not re-run them."""
    from plantbench.paths import project_root
    from plantbench.runner.plan import _import_closure, _module_name

    for method in ("mvs", "guo"):
        start = tuple(sorted((project_root() / "reference_impl" / method).rglob("*.py")))
        names = {_module_name(f) for f in _import_closure(start, frozenset({"plantbench", "reference_impl"}))}
        assert "plantbench.metrics.surface" in names
        assert not names & {"plantbench.metrics.info", "plantbench.metrics.skeleton", "plantbench.metrics.structure",
                            "plantbench.metrics.evaluate"}
