"""The code's layout as docs/design.md describes it: no import circle inside plantbench (lazy imports included), and
no function longer than 80 lines anywhere in the project's Python."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from plantbench.paths import project_root

ROOT = project_root()


def _modules(package: str, root: Path) -> dict[str, Path]:
    out = {}
    for p in sorted((root / package).rglob("*.py")):
        parts = list(p.relative_to(root).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = p
    return out


def import_cycles(package: str = "plantbench", root: Path = ROOT) -> list[list[str]]:
    """Groups of modules of ``package`` that import each other in a circle, counting imports inside functions."""
    mods = _modules(package, root)
    names = list(mods)
    index = {m: i for i, m in enumerate(names)}
    edges = set()
    for m, p in mods.items():
        for node in ast.walk(ast.parse(p.read_text())):
            targets = []
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                targets = [node.module, *(f"{node.module}.{a.name}" for a in node.names)]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            edges |= {(index[m], index[t]) for t in targets if t in index and t != m}
    i, j = (np.array(x, int) for x in zip(*edges, strict=True)) if edges else (np.zeros(0, int), np.zeros(0, int))
    graph = coo_matrix((np.ones(len(i)), (i, j)), shape=(len(names), len(names)))
    _, labels = connected_components(graph, directed=True, connection="strong")
    groups = {}
    for name, label in zip(names, labels, strict=True):
        groups.setdefault(label, []).append(name)
    return [g for g in groups.values() if len(g) > 1]


def test_no_import_circle():
    assert import_cycles() == []


def test_the_cycle_finder_finds_one(tmp_path):
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from pkg import b\n")
    (pkg / "b.py").write_text("def f():\n    import pkg.a\n")
    (pkg / "c.py").write_text("import pkg.a\n")
    assert [sorted(g) for g in import_cycles("pkg", tmp_path)] == [["pkg.a", "pkg.b"]]


def test_no_function_over_80_lines():
    long = []
    for folder in ("plantbench", "reference_impl", "tests", "bench", "scripts", "plugins"):
        for p in sorted((ROOT / folder).rglob("*.py")):
            if "build" in p.parts:
                continue
            for node in ast.walk(ast.parse(p.read_text())):
                if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and node.end_lineno - node.lineno >= 80:
                    long.append(f"{p.relative_to(ROOT)}:{node.lineno} {node.name} ({node.end_lineno - node.lineno + 1})")
    assert long == []
