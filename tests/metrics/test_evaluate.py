"""evaluate() end to end on small synthetic cases: the gt oracle scores perfectly, bad inputs give documented
values or clear errors, and every metric is registered with unit and direction."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from plantbench.errors import InputError
from plantbench.io.plantio import write_reconstruction
from plantbench.methods.gt import GroundTruth
from plantbench.metrics.evaluate import EvaluateOptions, evaluate, evaluate_detailed, format_summary
from plantbench.metrics.info import METRICS, MetricInfo
from plantbench.plant import Skeleton, TriMesh
from plantbench.registry import metrics
from plantbench.skeletons import branch_chains

from .synth import synthetic_case

FAST = EvaluateOptions(gt_samples=60_000, recon_samples=30_000)


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    root = tmp_path_factory.mktemp("case")
    plant = synthetic_case(root / "case", np.random.default_rng(3))
    GroundTruth().reconstruct(root / "case", root / "gt", seed=0)
    return root, plant


def test_gt_oracle_scores_perfectly(case):
    root, _ = case
    res, reasons = evaluate_detailed(root / "case", root / "gt", options=FAST)
    assert set(res) == set(METRICS)
    assert all(v is None or math.isfinite(v) for v in res.values())
    for v in ("stava", "stava_nosplit"):
        assert (res[f"{v}.S_T"], res[f"{v}.d_S"], res[f"{v}.d_G"], res[f"{v}.d_T"]) == (1.0, 0.0, 0.0, 0.0)
    assert res["mesh_to_surface.D_cm"] <= 1e-4  # float32 mesh.ply vertices: ~1e-7 m rounding
    assert res["mesh_to_scan.D_cm"] < 0.5  # against a sampled, noisy scan: its sampling floor, not 0
    assert res["reprojection.error"] == 0.0 and res["reprojection.iou"] == 1.0
    assert res["leaves.accuracy"] == 1.0 and res["leaves.f1"] == 1.0 and res["leaves.dic"] == 0.0
    for t in ("0.5", "1.0", "2.0"):
        assert res[f"skeleton.f1@{t}"] == 1.0
    for tau in ("0.5%", "1%", "2%"):
        assert res[f"skeleton.vf1@{tau}"] == 1.0
    assert res["leaves.strict_f1"] == 1.0
    assert res["leaves.shape_error"] < 1e-6 and res["leaves.normal_error_deg"] < 0.01  # leaves.json in float
    for part in ("all", "wood", "foliage"):
        for tau in ("0.5%", "1%", "2%"):
            assert res[f"surface.{part}.fscore@{tau}"] >= 0.999
    assert res["skeleton.branch_count_rel_error"] == 0.0 and res["skeleton.height_error_m"] == 0.0
    assert res["points.count"] is None and "points.ply" in reasons["points.count"]
    json.dumps(res, allow_nan=False)
    assert "stava.S_T" in str(format_summary(res, reasons).columns[0]._cells)


def test_deterministic(case):
    root, _ = case
    assert evaluate(root / "case", root / "gt", options=FAST) == evaluate(root / "case", root / "gt", options=FAST)


def test_degraded_reconstructions_score_worse(case):
    root, plant = case
    out = root / "bad"
    sk = plant.skeleton
    shifted = Skeleton(sk.positions + [0.02, 0, 0], sk.radii, sk.parents)
    mesh = TriMesh(plant.branch_mesh.vertices + [0.02, 0, 0], plant.branch_mesh.faces)
    write_reconstruction(out, shifted, mesh=mesh, leaves=plant.leaves[:-2],
                         points=plant.branch_mesh.vertices + [0.02, 0, 0])
    res = evaluate(root / "case", out, options=FAST)
    assert res["stava.S_T"] == pytest.approx(1.0, abs=1e-9)  # translation invariant
    assert res["mesh_to_surface.D_cm"] > 0.5
    assert 0 < res["reprojection.error"] and res["reprojection.iou"] < 1
    n = len(plant.leaves)
    assert res["leaves.accuracy"] == pytest.approx(1 - 2 / n) and res["leaves.dic"] == -2
    assert res["leaves.strict_matched"] == n - 2 and res["leaves.shape_error"] < 1e-6
    assert res["surface.foliage.recall@1%"] < 0.5 and res["points.count"] == len(plant.branch_mesh.vertices)


def test_degenerate_reconstructions(case):
    root, plant = case
    out = root / "degenerate"
    write_reconstruction(out, Skeleton(np.zeros((1, 3)), np.ones(1), np.array([-1])), mesh=TriMesh.empty())
    res, reasons = evaluate_detailed(root / "case", out, options=FAST)
    assert res["stava.S_T"] == 0.0 and res["stava.d_T"] == 1.0
    assert res["mesh_to_scan.D_cm"] is None and res["reprojection.error"] == 1.0 and res["reprojection.iou"] == 0.0
    assert res["leaves.accuracy"] is None and "leaves.json" in reasons["leaves.accuracy"]
    assert res["surface.all.fscore@1%"] == 0.0 and res["skeleton.f1@1.0"] >= 0.0
    # the calibrated headline: a one-node skeleton has no length (vF1 0, no GT-free support); no leaves.json: None
    assert res["skeleton.vf1@1%"] == 0.0 and res["skeleton.vprecision@1%"] == 0.0
    # no branch with length: branch F1 0, the count error as for one branch
    assert res["skeleton.branch_f1@1%"] == 0.0 and res["skeleton.lf1@1%"] == 0.0
    assert res["skeleton.branch_count_log2_error"] == pytest.approx(np.log2(len(branch_chains(plant.skeleton))))
    assert res["support.skeleton@1%"] is None and "no length" in reasons["support.skeleton@1%"]
    assert res["leaves.strict_f1"] is None
    write_reconstruction(root / "no_leaves", plant.skeleton, leaves=[])
    res = evaluate(root / "case", root / "no_leaves", options=FAST)
    assert res["leaves.strict_f1"] == 0.0 and res["leaves.strict_recall"] == 0.0 and res["skeleton.vf1@1%"] == 1.0
    assert res["skeleton.branch_f1@1%"] == 1.0 and res["skeleton.branch_count_log2_error"] == 0.0
    # the ground truth's own skeleton: supported by its scan where the scan saw it (a share in (0, 1])
    assert 0.0 < res["support.skeleton@1%"] <= 1.0
    assert all(v is None or math.isfinite(v) for v in res.values())


def test_real_capture_without_ground_truth(case, tmp_path):
    import shutil

    root, _ = case
    shutil.copytree(root / "case" / "views", tmp_path / "views")
    shutil.copytree(root / "case" / "scan", tmp_path / "scan")
    res, reasons = evaluate_detailed(tmp_path, root / "gt", options=FAST)
    assert res["stava.S_T"] is None and "plant/" in reasons["stava.S_T"]
    assert res["mesh_to_scan.D_cm"] is not None and res["reprojection.iou"] == 1.0
    # the reconstruction's own traits need no ground truth; the errors and P/R/F1 do
    full = evaluate(root / "case", root / "gt", options=FAST)
    for name in ("height_m", "branch_count", "total_length_m", "mean_branch_length_m", "crown_area_m2"):
        assert res[f"skeleton.{name}"] == full[f"skeleton.{name}"] and res[f"skeleton.{name}"] is not None
    assert res["skeleton.dbh_cm"] == full["skeleton.dbh_cm"]
    for name in ("height_error_m", "branch_count_rel_error", "dbh_error_cm", "crown_area_rel_error", "f1@1.0",
                 "vf1@1%", "lf1@1%", "branch_f1@1%", "branch_count_log2_error"):
        assert res[f"skeleton.{name}"] is None and "plant/" in reasons[f"skeleton.{name}"]
    assert full["skeleton.crown_area_rel_error"] == 0.0


def test_bad_input_errors(case, tmp_path):
    import shutil

    root, _ = case
    shutil.copytree(root / "case", tmp_path / "case")
    (tmp_path / "case" / "views" / "instance" / "0000.png").unlink()
    with pytest.raises(InputError, match="mismatched view counts"):
        evaluate(tmp_path / "case", root / "gt", options=FAST)
    with pytest.raises(InputError, match="not found"):
        evaluate(tmp_path / "nope", root / "gt")
    nan_out = tmp_path / "nan"
    nan_out.mkdir()
    (nan_out / "skeleton.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 2\nproperty double x\nproperty double y\nproperty double z\n"
        "property double radius\nelement edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n"
        "0 0 0 0.1\nnan 0 1 0.1\n0 1\n")
    with pytest.raises(InputError, match="NaN"):
        evaluate(root / "case", nan_out, options=FAST)


def test_every_metric_registered_with_unit_and_direction():
    assert set(METRICS) <= set(metrics.names())
    for name in ("stava.S_T", "stava.d_S", "stava_nosplit.S_T", "mesh_to_scan.D_cm", "mesh_to_scan.sigma_cm",
                 "reprojection.error", "reprojection.iou", "leaves.accuracy", "points.wood.fscore@1%",
                 "skeleton.f1@1.0", "points.all.fscore@1%", "skeleton.height_m", "skeleton.branch_count",
                 "skeleton.mean_branch_length_m", "points.count"):
        info = metrics.get(name)
        assert isinstance(info, MetricInfo) and isinstance(info.unit, str) and info.description
    assert metrics.get("stava.S_T").higher_is_better is True
    assert metrics.get("mesh_to_scan.D_cm").higher_is_better is False and metrics.get("mesh_to_scan.D_cm").unit == "cm"


def test_a_point_cloud_alone_is_scored_as_a_cloud(case, tmp_path):
    """The mvs stage's output: points.ply and no skeleton. The point metrics have values; every skeleton, trait
    (skeleton.*, qsm.*) and support metric is None with the reason."""
    from plantbench.io.ply import write_points

    root, plant = case
    out = tmp_path / "cloud"
    out.mkdir()
    write_points(out / "points.ply", plant.branch_mesh.vertices)
    res, reasons = evaluate_detailed(root / "case", out, options=FAST)
    assert res["points.count"] == len(plant.branch_mesh.vertices) and res["points.wood.precision@1%"] > 0.9
    for name in ("skeleton.vf1@1%", "skeleton.branch_f1@1%", "skeleton.trunk_volume_l", "qsm.dbh_cm",
                 "support.skeleton@spacing"):
        assert res[name] is None and "skeleton.ply" in reasons[name], name
