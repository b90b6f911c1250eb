"""A tiny suite (one small plant, 2 views at 32 px) and misbehaving external methods for runner tests."""

from __future__ import annotations

import sys
import textwrap
from pathlib import Path

import pytest

SCRIPTS = {
    "crash": "import sys; raise RuntimeError('method exploded on purpose')",
    "sleep": "import time; time.sleep(60)",
    "empty": textwrap.dedent(
        """
        import sys
        from pathlib import Path
        import numpy as np
        from plantbench.io.plantio import write_reconstruction
        from plantbench.plant import Skeleton, TriMesh
        out = Path(sys.argv[2])
        skel = Skeleton(np.array([[0.0, 0, 0], [0, 0, 1]]), np.array([0.1, 0.05]), np.array([-1, 0]))
        write_reconstruction(out, skel, mesh=TriMesh.empty())
        """
    ),
    "slow_ok": textwrap.dedent(
        """
        import sys, time
        from pathlib import Path
        import numpy as np
        from plantbench.io.plantio import write_reconstruction
        from plantbench.plant import Skeleton
        time.sleep(1.5)
        out = Path(sys.argv[2])
        skel = Skeleton(np.array([[0.0, 0, 0], [0, 0, 0.3]]), np.array([0.01, 0.005]), np.array([-1, 0]))
        write_reconstruction(out, skel)  # (methods cannot read plant/: a fixed two-node stem)
        """
    ),
}


@pytest.fixture(scope="session")
def scripts(tmp_path_factory) -> dict[str, str]:
    """name -> method spec 'cmd:python SCRIPT {capture} {out}'."""
    folder = tmp_path_factory.mktemp("methods")
    out = {}
    for name, code in SCRIPTS.items():
        path = folder / f"{name}.py"
        path.write_text(code)
        out[name] = f"cmd:{sys.executable} {path} {{capture}} {{out}}"
    return out


def suite_toml(path: Path, methods: list[str], *, seeds=(1,), timeout_s: float = 120, species: str = "laurel") -> Path:
    quoted = ", ".join(f"'{m}'" for m in methods)
    path.write_text(textwrap.dedent(f"""
        name = "{path.stem}"
        description = "runner test"
        methods = [{quoted}]
        timeout_s = {timeout_s}

        [[cases]]
        species = "{species}"
        seeds = {list(seeds)}
        scale = 0.15

        [capture]
        views = 2
        width = 32
        height = 32
        spp = 1
        scan = true
        stations = 1
        """))
    return path
