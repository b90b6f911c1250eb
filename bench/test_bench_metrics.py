"""Metric speed beside the raw library doing the same work:

* one cell: ``evaluate_detailed`` on a synthetic cell of the full metric sizes (1M ground-truth surface samples, 200k
  reconstructed ones, 1 mm skeleton samples, a scan, 20 views), one thread, beside the raw libraries' part of the
  same work on the same arrays: scipy cKDTree builds and nearest-neighbour queries (surface, mesh-to-scan, skeleton
  P/R and support) and Open3D point-to-mesh distances and ray casting (mesh-to-scan reverse, mesh-to-surface,
  reprojection). The ratio is asserted (bound :data:`MAX_CELL_RATIO`); the rest of a cell is reading, sampling and
  Stava, which has no library to compare with (below). Issue 27's target: <= 20 s per multiview cell on one core.
* mesh-to-scan D for 1M reconstructed vertices against 1M scan points, beside a bare
  ``cKDTree(scan).query(vertices, workers=-1)`` on the same arrays (target: <= 1.5x);
* Stava S_T of two ~2k-branch trees, with split/merge (target: <= 10 s) and without;
* leaf detection of 3000 predicted against 3000 ground-truth leaf centroids (a dense crown), beside scipy's
  dense Hungarian assignment (``linear_sum_assignment``) that gives the same match count.

Run ``pytest bench/test_bench_metrics.py --benchmark-only -s`` to see the printed ratios.
"""

import time

import numpy as np
import pytest
from scipy.spatial import cKDTree

from plantbench.metrics.leaves import leaf_detection
from plantbench.metrics.stava import stava_similarity
from plantbench.metrics.surface import mesh_to_scan
from plantbench.plant import Skeleton, TriMesh
from tests.metrics.synth import random_tree, synthetic_case, tube_mesh

MAX_CELL_RATIO = 1.6
"""evaluate_detailed / the raw libraries' part of a cell's work, one thread. Measured 0.81-0.86 on the shared 2-core
machine when the other core is idle (about 1.0 before issue 27's bounded searches and shared samples: the plain
searches of the raw side visit far points that the metrics need not), 0.96-1.02 when it is busy; about 2x the quiet
measurement, so that only a real regression (a search or a sample done twice, an unbounded search over far points)
fails."""


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    """A synthetic case (a tree with 400 laterals and a leaf per tip, a scan, 20 views of 256 px) and a
    reconstruction that misses it by centimetres, with a second copy 15 cm aside (much of a method's skeleton lies
    far from the ground truth): the skeletons jittered, a tube mesh around them, the leaves."""
    from plantbench.io.plantio import write_reconstruction

    rng = np.random.default_rng(7)
    root = tmp_path_factory.mktemp("bench_cell")
    plant = synthetic_case(root / "case", rng, n_laterals=400, n_views=20, size=256)
    gt = plant.skeleton
    pos = np.concatenate([gt.positions, gt.positions + [0.15, 0.0, 0.0]])  # and a copy beside it: far samples
    skel = Skeleton(pos + rng.normal(0, 0.02, pos.shape), np.tile(gt.radii, 2),
                    np.concatenate([gt.parents, np.where(gt.parents >= 0, gt.parents + len(gt), -1)]))
    write_reconstruction(root / "recon", skel, mesh=tube_mesh(skel, sides=12), leaves=plant.leaves)
    return root / "case", root / "recon"


def _raw_cell_inputs(case, recon) -> dict:
    """The arrays a cell's metrics search, at the same sizes: surface samples (1M of the ground truth, 200k of the
    reconstruction), the scan, the mesh vertices, the 1 mm skeleton samples, every pixel's ray, the two meshes."""
    from plantbench.cameras import read_cameras
    from plantbench.io.plantio import read_plant, read_reconstruction
    from plantbench.io.ply import read_points
    from plantbench.metrics.skeleton import sample_skeleton
    from plantbench.metrics.surface import sample_surface

    plant, out = read_plant(case)[0], read_reconstruction(recon)
    rng = np.random.default_rng(0)
    gt_mesh = TriMesh.concatenate([plant.branch_mesh, plant.leaf_mesh])
    cams, _ = read_cameras(case / "views" / "cameras.json")
    rays = np.concatenate([np.concatenate([np.broadcast_to(o, d.shape), d], 1) for o, d in
                           (c.pixel_rays() for c in cams)]).astype(np.float32)
    return {"gt": sample_surface(gt_mesh, 1_000_000, rng)[0], "rec": sample_surface(out.mesh, 200_000, rng)[0],
            "scan": read_points(case / "scan" / "scan.ply")[0], "verts": out.mesh.vertices,
            "g": sample_skeleton(plant.skeleton)[0], "p": sample_skeleton(out.skeleton)[0], "rays": rays,
            "gt_mesh": gt_mesh, "mesh": out.mesh}


def _raw_cell_seconds(x: dict) -> float:
    """Seconds the raw libraries take for the searches a cell's metrics make (:func:`_raw_cell_inputs`), one thread:
    cKDTree builds and nearest-neighbour queries, Open3D point-to-mesh distances and ray casting."""
    import open3d as o3d

    def scene(mesh):
        s = o3d.t.geometry.RaycastingScene(nthreads=1)
        s.add_triangles(o3d.core.Tensor(mesh.vertices.astype(np.float32)), o3d.core.Tensor(mesh.faces.astype(np.uint32)))
        return s

    t0 = time.perf_counter()
    t_gt, t_rec, t_scan, t_g, t_p = (cKDTree(x[k], balanced_tree=False, compact_nodes=False)  # (the fast build)
                                     for k in ("gt", "rec", "scan", "g", "p"))
    for tree, q in ((t_gt, "rec"), (t_rec, "gt"), (t_scan, "verts"), (t_scan, "rec"), (t_g, "p"), (t_p, "g"),
                    (t_scan, "p")):
        tree.query(x[q], workers=1)
    rec_scene = scene(x["mesh"])
    rec_scene.compute_distance(o3d.core.Tensor(x["scan"].astype(np.float32)), nthreads=1)
    rec_scene.test_occlusions(o3d.core.Tensor(x["rays"]), nthreads=1)
    scene(x["gt_mesh"]).compute_distance(o3d.core.Tensor(x["verts"].astype(np.float32)), nthreads=1)
    return time.perf_counter() - t0


@pytest.mark.benchmark(group="one-cell")
def test_cell_metrics_beside_raw_libraries(benchmark, cell, monkeypatch):
    from plantbench.metrics.evaluate import evaluate_detailed

    monkeypatch.setenv("PLANTBENCH_THREADS", "1")
    case, recon = cell
    inputs = _raw_cell_inputs(case, recon)
    bare_s = min(_raw_cell_seconds(inputs) for _ in range(2))
    values, _ = benchmark.pedantic(evaluate_detailed, args=(case, recon), rounds=2, iterations=1)
    ours = benchmark.stats.stats.min
    benchmark.extra_info.update(bare_s=bare_s, ratio=ours / bare_s)
    print(f"\none cell: evaluate_detailed / raw cKDTree + Open3D work = {ours / bare_s:.2f} ({ours:.1f} s vs "
          f"{bare_s:.1f} s; bound {MAX_CELL_RATIO}; issue 27 target <= 20 s per multiview cell on one core)")
    assert values["skeleton.f1@2.0"] is not None and values["surface.all.chamfer_cm"] is not None
    assert ours / bare_s <= MAX_CELL_RATIO


@pytest.fixture(scope="module")
def clouds():
    rng = np.random.Generator(np.random.PCG64(0))
    n = 1_000_000
    scan = rng.random((n, 3))
    verts = rng.random((n, 3))
    return scan, TriMesh(verts, np.zeros((0, 3), np.int64))


@pytest.mark.benchmark(group="mesh-to-scan-1M")
def test_bare_ckdtree_query(benchmark, clouds):
    scan, mesh = clouds

    def bare():
        d, _ = cKDTree(scan).query(mesh.vertices, workers=-1)
        return d.mean(), d.std()

    benchmark.pedantic(bare, rounds=3, iterations=1)


@pytest.mark.benchmark(group="mesh-to-scan-1M")
def test_plantbench_mesh_to_scan(benchmark, clouds):
    scan, mesh = clouds
    rng = np.random.Generator(np.random.PCG64(1))
    res = benchmark.pedantic(mesh_to_scan, args=(scan, mesh), kwargs={"rng": rng, "reverse": False},
                             rounds=3, iterations=1)
    assert res.D_cm > 0


@pytest.fixture(scope="module")
def trees():
    rng = np.random.Generator(np.random.PCG64(1))
    return random_tree(rng, 1000, trunk_segments=60), random_tree(rng, 1000, trunk_segments=60)


@pytest.mark.benchmark(group="stava-2k-branches")
def test_stava_split_merge(benchmark, trees):
    r = benchmark.pedantic(stava_similarity, args=trees, rounds=1, iterations=1)
    assert 0 < r.S_T < 1


@pytest.mark.benchmark(group="stava-2k-branches")
def test_stava_nosplit(benchmark, trees):
    r = benchmark.pedantic(stava_similarity, args=trees, kwargs={"split_merge": False}, rounds=1, iterations=1)
    assert 0 < r.S_T < 1


@pytest.fixture(scope="module")
def leaf_centroids():
    rng = np.random.Generator(np.random.PCG64(2))
    gt = rng.random((3000, 3)) * [1.0, 1.0, 1.5]
    pred = np.concatenate([gt[:2400] + rng.normal(0, 0.02, (2400, 3)), rng.random((600, 3)) * [1.0, 1.0, 1.5]])
    return gt, pred, 0.04


@pytest.mark.benchmark(group="leaf-detection-3k")
def test_bare_dense_hungarian(benchmark, leaf_centroids):
    from scipy.optimize import linear_sum_assignment
    from scipy.spatial.distance import cdist

    gt, pred, radius = leaf_centroids

    def bare():
        d = cdist(gt, pred)
        r, c = linear_sum_assignment(np.where(d <= radius, d, 1e6 + d))
        return int(np.count_nonzero(d[r, c] <= radius))

    leaf_centroids_matched["dense"] = benchmark.pedantic(bare, rounds=1, iterations=1)


@pytest.mark.benchmark(group="leaf-detection-3k")
def test_plantbench_leaf_detection(benchmark, leaf_centroids):
    gt, pred, radius = leaf_centroids
    res = benchmark.pedantic(leaf_detection, args=(gt, pred), kwargs={"radius": radius}, rounds=3, iterations=1)
    if "dense" in leaf_centroids_matched:
        assert res["matched"] == leaf_centroids_matched["dense"]


leaf_centroids_matched: dict[str, int] = {}
