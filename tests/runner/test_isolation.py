"""A method sees only what a real capture gives: its input folder holds nothing of plant/, the exact maps, the scan's
labels or the cache, through the local runner, the Dask executor and ``plantbench reconstruct``."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from plantbench.io.ply import read_points, write_points
from plantbench.methods.inputs import is_oracle, prepare_inputs
from plantbench.runner import run_suite
from plantbench.suites import load_suite
from tests.runner.conftest import suite_toml

PROBE = textwrap.dedent(
    """
    import json, os, sys
    from pathlib import Path
    import numpy as np
    from plantbench.io.plantio import write_reconstruction
    from plantbench.plant import Skeleton
    capture, out = Path(sys.argv[1]), Path(sys.argv[2])
    tried = {}
    for rel in ("../plant/plant.json", "../../cache", "../../../cache", "plant", "plant/plant.json", "views/depth",
                "views/instance", "views/foliage", "scan/scan.ply", "../capture", "../../capture"):
        tried[rel] = os.path.exists(capture / rel)
    listing = sorted(str(p.relative_to(capture)) for p in capture.rglob("*"))
    links = [str(p) for p in capture.rglob("*") if p.is_symlink()]
    (out / "probe.json").write_text(json.dumps({"tried": tried, "listing": listing, "links": links,
                                                "hint": json.loads((capture / "hint.json").read_text())}))
    skel = Skeleton(np.array([[0.0, 0, 0], [0, 0, 1]]), np.array([0.1, 0.05]), np.array([-1, 0]))
    write_reconstruction(out, skel)
    """
)


@pytest.fixture(scope="module")
def probe(tmp_path_factory) -> str:
    path = tmp_path_factory.mktemp("probe") / "probe.py"
    path.write_text(PROBE)
    return f"cmd:{sys.executable} {path} {{capture}} {{out}}"


def _probe_result(run) -> dict:
    cells = json.loads((run.run_dir / "cells.json").read_text())
    (cell,) = [c for c in cells if c["method"].startswith("cmd:")]
    assert cell["status"] == "ok", cell
    return json.loads((run.run_dir / cell["recon"] / "probe.json").read_text())


def _assert_isolated(found: dict) -> None:
    assert not any(found["tried"].values()), found["tried"]
    assert not found["links"]
    listing = set(found["listing"])
    assert {"views/images", "views/cameras.json", "views/capture.json", "hint.json"} <= listing
    assert not any(p.startswith(("plant", "views/depth", "views/instance", "views/foliage", "views/normal", "scan"))
                   for p in listing), listing
    assert found["hint"]["species"] == "laurel" and found["hint"]["leaf_length"] > 0


def test_an_external_method_finds_no_ground_truth(tmp_path, probe):
    suite = load_suite(str(suite_toml(tmp_path / "iso.toml", [probe, "gt"])))
    run = run_suite(suite, tmp_path / "runs", workers=2)
    _assert_isolated(_probe_result(run))
    assert (run.table["status"] == "ok").all()  # the oracle gt still reads plant/ and scores 1


def test_the_same_through_the_dask_executor(tmp_path, probe):
    distributed = pytest.importorskip("dask.distributed")
    suite = load_suite(str(suite_toml(tmp_path / "iso.toml", [probe])))
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        with distributed.Client(cluster) as client:
            run = run_suite(suite, tmp_path / "dask", executor="dask", client=client)
    _assert_isolated(_probe_result(run))


def test_the_cli_prepares_the_same_folder(tmp_path, probe):
    suite = load_suite(str(suite_toml(tmp_path / "iso.toml", ["gt"])))
    run = run_suite(suite, tmp_path / "runs")
    case = run.run_dir / json.loads((run.run_dir / "cells.json").read_text())[0]["capture"]
    out = tmp_path / "cli-out"
    proc = subprocess.run([sys.executable, "-m", "plantbench.cli", "reconstruct", str(case), "--method", probe,
                           "--out", str(out), "--species", "laurel"], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    _assert_isolated(json.loads((out / "probe.json").read_text()))


def _fake_capture(root):
    """A capture folder with every kind of file, ground truth included."""
    (root / "plant").mkdir(parents=True)
    (root / "plant" / "plant.json").write_text("{}")
    v = root / "views"
    for sub in ("images", "depth", "instance", "foliage", "colmap"):
        (v / sub).mkdir(parents=True)
    (v / "images" / "0000.png").write_bytes(b"png")
    (v / "depth" / "0000.npy").write_bytes(b"npy")
    from plantbench.cameras import look_at, write_cameras
    from plantbench.capture.formats import Tracks, write_colmap_text

    cam = look_at((3.0, 0.0, 1.0), (0.0, 0.0, 1.0), fov_x_deg=40.0, width=64, height=48)
    write_cameras(v / "cameras.json", [cam], ["0000.png"])
    write_colmap_text(v / "colmap", [cam], ["0000.png"], Tracks(np.array([[0.0, 0.0, 1.0]]), np.zeros((1, 3), np.uint8),
                                                               np.zeros(1, np.int64), np.zeros(1, np.int64),
                                                               np.array([[32.0, 24.0]])))
    (v / "transforms.json").write_text("{}")
    (v / "capture.json").write_text(json.dumps({"plant": {"height": 3.2, "species": "maple"}, "seed": 1,
                                                "scan": {"points": 10}, "settings": {"views": 1},
                                                "leaf_pixels": {"leaves": 3, "median_px": 250.0}}))
    (root / "scan").mkdir()
    rng = np.random.default_rng(0)
    write_points(root / "scan" / "scan.ply", rng.random((20, 3)),
                 {"label": rng.integers(0, 2, 20), "leaf_id": rng.integers(-1, 5, 20), "station": np.zeros(20, int)})
    (root / "scan" / "stations.json").write_text("{}")
    return root


def test_prepare_inputs_per_kind(tmp_path):
    cap = _fake_capture(tmp_path / "cap")
    views = prepare_inputs(tmp_path / "v", cap, "views")
    got = sorted(str(p.relative_to(views)) for p in views.rglob("*"))
    assert got == ["views", "views/cameras.json", "views/capture.json", "views/colmap", "views/colmap/cameras.txt",
                   "views/colmap/images.txt", "views/colmap/points3D.txt", "views/images", "views/images/0000.png",
                   "views/transforms.json"]
    # the COLMAP model keeps its cameras and images (pycolmap reads it), not the ground-truth points
    import PIL.Image  # noqa: F401  (before pycolmap: zlib clash)
    import pycolmap

    full = pycolmap.Reconstruction(str(cap / "views" / "colmap"))
    mine = pycolmap.Reconstruction(str(views / "views" / "colmap"))
    assert full.num_points3D() == 1 and mine.num_points3D() == 0
    assert mine.num_images() == 1 and (views / "views" / "colmap" / "cameras.txt").read_text() == \
        (cap / "views" / "colmap" / "cameras.txt").read_text()
    assert json.loads((views / "views" / "capture.json").read_text()) == {"seed": 1, "settings": {"views": 1}}
    scan = prepare_inputs(tmp_path / "s", cap, "scan")
    pts, fields = read_points(scan / "scan" / "scan.ply")
    assert set(fields) == {"station"} and pts.shape == (20, 3)
    np.testing.assert_allclose(pts, read_points(cap / "scan" / "scan.ply")[0])
    pdir = tmp_path / "pts"
    (pdir / "depth").mkdir(parents=True)
    (pdir / "depth" / "0000.npz").write_bytes(b"z")
    write_points(pdir / "points.ply", np.ones((12, 3)), {"label": np.ones(12, int)})
    pin = prepare_inputs(tmp_path / "p", cap, "points", points_dir=pdir)
    assert set(read_points(pin / "points.ply")[1]) == set()  # coordinates only
    assert (pin / "depth" / "0000.npz").exists() and (pin / "views" / "images" / "0000.png").exists()
    assert not (pin / "views" / "depth").exists() and not (pin / "plant").exists()
    oracle = prepare_inputs(tmp_path / "o", cap, "views", oracle=True)
    assert (oracle / "plant" / "plant.json").exists() and (oracle / "views" / "depth" / "0000.npy").exists()


def test_oracle_declarations():
    from plantbench.registry import methods

    assert is_oracle(methods.get("gt"))
    assert not is_oracle(methods.get("mvs")) and is_oracle(methods.get("mvs"), {"depth": "oracle"})
    assert not is_oracle(methods.get("guo")) and is_oracle(methods.get("guo"), {"leaf_depth": "oracle"})
    assert not is_oracle(methods.get("livny")) and not is_oracle(methods.get("xu"))


def test_reference_methods_import_nothing_of_the_generator():
    """No module of reference_impl imports plantbench.generate or plantbench.species (the generator's internals and
    species files): they get the hint, and share only plantbench.geometry."""
    import ast

    from plantbench.paths import project_root

    bad = []
    for f in sorted((project_root() / "reference_impl").rglob("*.py")):
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = [node.module or ""]
            else:
                continue
            bad += [f"{f.name}: {n}" for n in names if n.startswith(("plantbench.generate", "plantbench.species"))]
    assert not bad


def test_methods_on_an_oracle_cloud_are_marked_oracles():
    # the multiview_oracle suite's mvs stage reads the exact depth: guo, livny and xu reconstruct from ground truth
    # and every table must say so; on the estimated cloud only gt and the prior are oracles; a scan has no mvs stage
    from plantbench.runner.run import oracle_methods
    from plantbench.suites import load_suite

    for name, expected in (("multiview", {"gt", "prior"}), ("multiview_oracle", {"prior", "guo", "livny", "xu"}),
                           ("scan", {"gt", "prior"})):
        s = load_suite(name)
        assert set(oracle_methods(s, list(s.methods))) == expected, name


def test_oracle_cloud_cells_read_the_mvs_stage_oracle_cloud():
    # 'livny@oracle' in a views suite: livny on the points job of mvs with depth = "oracle" (the suite's other mvs
    # options kept), marked an oracle; the same method job as plain 'livny' in a suite whose mvs stage is the oracle
    # (multiview_oracle's cache serves the quick-style cells); plain 'livny' keeps the estimated cloud
    from plantbench.errors import InputError
    from plantbench.methods.api import split_cloud
    from plantbench.runner.plan import make_plan
    from plantbench.runner.run import oracle_methods
    from plantbench.suites import Suite

    base = {"name": "t", "description": "t", "cases": [{"species": "laurel", "seeds": [1], "scale": 0.3}],
            "capture": {"views": 4, "width": 64, "height": 64}, "method_options": {"mvs": {"noise": 0.001}}}
    s = Suite.model_validate({**base, "methods": ["mvs", "livny", "livny@oracle", "prior"]})
    plan = make_plan(s)
    cells = {c.method: c for c in plan.cells}
    assert set(cells) == {"mvs", "livny", "livny@oracle", "prior"}

    def cloud_options(cell):
        recon = plan.jobs[cell.recon_key]
        points = plan.jobs[recon.params["points"]]
        return plan.jobs[points.params["recon"]].params["options"]

    assert cloud_options(cells["livny@oracle"]) == {"noise": 0.001, "depth": "oracle"}
    assert cloud_options(cells["livny"]) == {"noise": 0.001}
    assert plan.jobs[cells["livny@oracle"].recon_key].params["method"] == "livny"
    assert set(oracle_methods(s, list(s.methods))) == {"livny@oracle", "prior"}

    oracle_suite = Suite.model_validate({**base, "methods": ["livny"],
                                         "method_options": {"mvs": {"noise": 0.001, "depth": "oracle"}}})
    assert make_plan(oracle_suite).cells[0].recon_key == cells["livny@oracle"].recon_key

    assert split_cloud("cmd:tool {capture} {out} --x@oracle") == ("cmd:tool {capture} {out} --x@oracle", False)
    for methods, source, why in ((["mvs@oracle"], "views", "reads views"), (["gt@oracle"], "views", "reads"),
                                 (["livny@oracle"], "scan", "reconstructs from the scan")):
        bad = Suite.model_validate({**base, "methods": methods, "source": source})
        with pytest.raises(InputError, match=why):
            make_plan(bad)


def test_each_case_has_its_own_capture_stream_shared_across_suites():
    """Two plants of one suite with the same seed are captured with different streams (textures, render and scan
    noise); the same plant in another suite with the same capture settings has the same capture job (one cache
    entry), and another root seed gives another stream."""
    from plantbench.runner.plan import make_plan
    from plantbench.suites import Suite

    def captures(name, species, root_seed=0):
        s = Suite(name=name, description="t", root_seed=root_seed, methods=["gt"],
                  cases=[{"species": sp, "seeds": [1]} for sp in species])
        return {j.params["plant"]: j for j in make_plan(s).jobs.values() if j.kind == "capture"}

    both = captures("a", ["laurel", "maple"])
    seeds = [j.params["seed"] for j in both.values()]
    assert len(set(seeds)) == 2 and all(isinstance(x, int) and x >= 0 for x in seeds)
    alone = captures("b", ["maple"])
    (plant, job), = alone.items()
    assert both[plant].key == job.key and both[plant].params["seed"] == job.params["seed"]
    other_root = captures("b", ["maple"], root_seed=3)
    assert next(iter(other_root.values())).params["seed"] != job.params["seed"]
