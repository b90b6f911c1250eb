"""The table of metrics: every name :func:`plantbench.metrics.evaluate.evaluate` writes, with its unit and direction,
and the lists every table, the gate and the calibration take from it (the one place they are defined):
:data:`HEADLINE` (the report's headline, ``plantbench metrics --headline``, run.json's ``headline``) and
:data:`KEY_METRICS` (the headline, then the reference paper's and the older columns: the report's first table and
the gated metrics). A metric's short label and its gate floor are fields of its :class:`MetricInfo`.

``higher_is_better`` is None for descriptive values (a count, a height) that have no better direction; the gate
should not gate those.
"""

from __future__ import annotations

from dataclasses import dataclass

from plantbench.metrics.points import TAU_FRACTIONS, tau_label
from plantbench.metrics.skeleton import HEIGHT_FRACTIONS, STRUCTURE_FRACTION, THRESHOLDS

__all__ = ["MetricInfo", "METRICS", "HEADLINE", "HEADLINE_FIDELITY", "HEADLINE_STRUCTURE", "HEADLINE_GT_FREE",
           "KEY_METRICS", "short_label"]


@dataclass(frozen=True)
class MetricInfo:
    """One registered metric."""

    name: str
    """name in the results JSON, e.g. 'stava.S_T'"""
    unit: str
    """unit of the value ('' for a ratio or a count)"""
    higher_is_better: bool | None
    """direction of improvement; None for a descriptive value"""
    description: str
    """one line: what it measures and the reference that defines it"""
    short: str | None = None
    """a label of at most 11 characters for narrow tables (the run summary), tolerance and unit in it"""
    floor: float | None = None
    """the gate's smallest tolerance, in the metric's unit: a change below it is never a regression, even in a cell
    the variability study saw perfectly stable (a key metric has one)"""


METRICS: dict[str, MetricInfo] = {}


def _add(name: str, unit: str, higher: bool | None, description: str) -> None:
    assert name not in METRICS, name
    METRICS[name] = MetricInfo(name, unit, higher, description)


def short_label(name: str) -> str:
    """The metric's short label (:attr:`MetricInfo.short`), or its name."""
    info = METRICS.get(name)
    return info.short if info is not None and info.short else name


def _add_group(prefix: str, unit: str, higher: bool | None, descriptions: dict[str, str]) -> None:
    """Register ``prefix.key`` for every key of ``descriptions`` (in its order), all with one unit and direction."""
    for key, description in descriptions.items():
        _add(f"{prefix}.{key}", unit, higher, description)


for _v, _what in (("stava", "with split/merge of chains"), ("stava_nosplit", "plain Zhang, no split/merge")):
    _add(f"{_v}.S_T", "", True, f"Stava et al. 2014 similarity 1 - (d_S + d_G + d_T)/3, {_what}")
    _add(f"{_v}.d_S", "", False, f"Stava shape distance (13 crown descriptors), {_what}")
    _add(f"{_v}.d_G", "", False, f"Stava geometric distance (20 branch-statistics descriptors), {_what}")
    _add(f"{_v}.d_T", "", False, f"Stava structural distance (normalised constrained tree edit distance), {_what}")

_add_group("mesh_to_scan", "cm", False, {
    "D_cm": "mean distance, reconstructed mesh vertex -> nearest scan point (Guo et al. 2018, D)",
    "sigma_cm": "std of vertex -> nearest scan point distance (Guo et al. 2018, sigma)",
    "reverse_D_cm": "mean distance, scan point -> reconstructed surface",
    "reverse_sigma_cm": "std of scan point -> reconstructed surface distance",
    "area_D_cm": "mean distance, area-uniform sample of the reconstruction -> scan point",
    "symmetric_cm": "(area_D + reverse_D) / 2",
})
_add_group("mesh_to_surface", "cm", False, {
    "D_cm": "D of Guo et al. 2018 against a perfect scan: mean exact distance, reconstructed vertex -> GT surface",
    "sigma_cm": "std of exact vertex -> ground-truth surface distance",
})

_add("reprojection.error", "", False, "Guenard Eq. 3: |render XOR reference mask| / |reference mask|, mean over views")
_add("reprojection.error_max", "", False, "worst view's reprojection error")
_add("reprojection.iou", "", True, "silhouette IoU with the ground-truth plant mask, mean over views")
_add("reprojection.iou_min", "", True, "worst view's silhouette IoU")

_add("leaves.count_gt", "", None, "ground-truth leaf count")
_add("leaves.count_pred", "", None, "reconstructed leaf count")
_add("leaves.dic", "", None, "difference in count N_pred - N_gt (CVPPP DiC)")
_add("leaves.abs_dic", "", False, "|DiC|")
_add("leaves.rel_error", "", False, "|DiC| / N_gt")
_add("leaves.accuracy", "", True, "leaf-count accuracy max(0, 1 - |DiC| / N_gt)")
_add("leaves.precision", "", True, "leaf detection precision (Hungarian centroid matching, half median leaf length)")
_add("leaves.recall", "", True, "leaf detection recall")
_add("leaves.f1", "", True, "leaf detection F1")
for _k in ("precision", "recall", "f1"):
    _add(f"leaves.strict_{_k}", "", True, f"strict leaf detection {_k} (centroids within half the median GT leaf "
                                           "spacing)")
_add("leaves.strict_matched", "", None, "leaves matched by the strict detection")
_add("leaves.shape_error", "", False, "strictly matched leaves: median of the symmetric mean surface distance between "
                                      "fitted and true blade / true blade length")
_add("leaves.normal_error_deg", "deg", False, "strictly matched leaves: median angle between fitted and true blade "
                                              "normals (unsigned, 0-90)")

_add("points.count", "", None, "number of points in the method's points.ply (Guo et al. 2018, |P|)")
for _src, _what in (("points", "the method's points.ply"), ("surface", "an area-uniform sample of mesh.ply")):
    for _part in ("all", "wood", "foliage"):
        _pre = f"{_src}.{_part}"
        _add(f"{_pre}.accuracy_cm", "cm", False, f"DTU accuracy of {_what} ({_part})")
        _add(f"{_pre}.completeness_cm", "cm", False, f"DTU completeness of {_what} ({_part})")
        _add(f"{_pre}.chamfer_cm", "cm", False, f"(accuracy + completeness)/2 of {_what} ({_part})")
        for _t in TAU_FRACTIONS:
            _lab = tau_label(_t)
            for _k, _name in (("precision", "precision"), ("recall", "recall"), ("fscore", "F-score")):
                _add(f"{_pre}.{_k}@{_lab}", "", True,
                     f"Tanks and Temples {_name} at tau = {_lab} of plant height, {_what} ({_part})")

for _t in THRESHOLDS:
    for _k in ("precision", "recall", "f1"):
        _add(f"skeleton.{_k}@{_t:.1f}", "", True,
             f"skeleton sample {_k} within {_t:g} x local ground-truth radius (Smart-Tree protocol)")
for _w, _weighting in (("v", "volume-weighted skeleton {} within {} of plant height (wood pi r^2 x length)"),
                      ("l", "length-weighted skeleton {} within {} of plant height (every metre of branch alike)")):
    for _f in HEIGHT_FRACTIONS:
        for _k in ("precision", "recall", "f1"):
            _add(f"skeleton.{_w}{_k}@{tau_label(_f)}", "", True, _weighting.format(_k, tau_label(_f)))
for _f in HEIGHT_FRACTIONS:
    _add(f"skeleton.vf1_observed@{tau_label(_f)}", "", True,
         f"observation: vF1 within {tau_label(_f)} of plant height, precision against the whole truth, recall over the "
         "edges the capture observed (at least half their bark; plantbench.capture.observed)")
    _add(f"skeleton.vrecall_hidden@{tau_label(_f)}", "", True,
         f"inference: volume-weighted recall within {tau_label(_f)} of plant height over the hidden edges' wood "
         f"farther than {tau_label(_f)} of plant height from the observed")
_add("capture.observed_wood_share", "", None,
     "volume-weighted share of the ground-truth wood the method's capture observed (views: a wood pixel of agreeing "
     "exact depth in >= 2 views; scans: a wood return within 2 x the median spacing); the same for every method")
_add("capture.breast_height_observed", "", None,
     "1 when the method's capture observed at least half the bark of the ground-truth stem at breast height (1.3 m "
     "above its base), else 0: a DBH is checked against the truth only where the capture showed the stem")
for _k, _what in (("precision", "matched / reconstructed branches"), ("recall", "matched / true branches"),
                  ("f1", "2 matched / (true + reconstructed branches)")):
    _add(f"skeleton.branch_{_k}@{tau_label(STRUCTURE_FRACTION)}", "", True,
         f"branch-level {_k}, {_what}: branches (Stava chains) matched one to one where more than half of each lies "
         f"within {tau_label(STRUCTURE_FRACTION)} of plant height of the other")
_add("skeleton.branch_count_log2_error", "", False, "|log2(branch count / GT branch count)|: doublings between the counts")
for _f in HEIGHT_FRACTIONS:
    _add(f"support.skeleton@{tau_label(_f)}", "", True,
         f"GT-free: share of skeleton length within {tau_label(_f)} of the observed height of an observed point")
_add("support.skeleton@spacing", "", True,
     "GT-free: share of skeleton length within max(1% of the observed height, 2 x the median spacing of the observed "
     "points) of an observed point: meaningful on scans sparser than 1% of the height")
_add("support.coverage@spacing", "", True,
     "GT-free completeness: share of the observed points within max(1% of the observed height, 2 x their median "
     "spacing) of the skeleton's surface (distance to the axis minus the radius; TreeQSM's coverage)")
_add("support.spacing_cm", "cm", None, "median distance from an observed point to its nearest other point")
_add("skeleton.branch_count", "", None, "reconstructed branch count (unbranched chains; Guo et al. 2018, |B|)")
_add("skeleton.branch_count_rel_error", "", False, "|branch count - GT| / GT")
_add("skeleton.total_length_m", "m", None, "reconstructed total branch length")
_add("skeleton.total_length_rel_error", "", False, "|total branch length - GT| / GT")
_add("skeleton.mean_branch_length_m", "m", None, "reconstructed mean branch length (Guo et al. 2018, l_B)")
_add("skeleton.height_m", "m", None, "reconstructed skeleton height (Guo et al. 2018, H)")
_add("skeleton.height_error_m", "m", False, "|height - GT height|")
_add("skeleton.dbh_cm", "cm", None, "reconstructed diameter at breast height (1.3 m)")
_add("skeleton.dbh_error_cm", "cm", False, "|DBH - GT DBH|")
_add("skeleton.crown_area_m2", "m2", None,
     "reconstructed crown projection area: 2D convex hull of the skeleton nodes' (x, y); needs no ground truth")
_add("skeleton.crown_area_rel_error", "", False, "|crown projection area - GT| / GT")
_TRAITS = {
    "dbh_cm": ("cm", "diameter at breast height, 1.3 m above the lowest point, of the thickest stem crossing it"),
    "height_m": ("m", "height, max z - min z"),
    "trunk_volume_l": ("L", "volume of the stem axes (order 0)"),
    "total_volume_l": ("L", "volume of every axis"),
    "total_length_m": ("m", "length of every axis"),
    "length_order0_m": ("m", "length of the stem axes (order 0)"),
    "length_order1_m": ("m", "length of the first-order laterals"),
    "length_order2_m": ("m", "length of the second-order laterals"),
    "length_order3plus_m": ("m", "length of the laterals of order 3 and more"),
    "branch_count": ("", "lateral axes (order >= 1; an axis follows the thickest child, as TreeQSM's branches)"),
}
for _k, (_unit, _what) in _TRAITS.items():
    if _k not in ("dbh_cm", "height_m", "total_length_m", "branch_count"):  # (skeleton.* has these already)
        _add(f"skeleton.{_k}", _unit, None, f"GT-free trait of the skeleton: {_what} (truncated cones between the "
                                            "node radii; plantbench.metrics.traits)")
for _k, (_unit, _what) in _TRAITS.items():
    _add(f"qsm.{_k}", _unit, None, f"GT-free trait of the skeleton's QSM cylinder export (plantbench qsm export): "
                                   f"{_what}")

HEADLINE = ("skeleton.vf1@1%", "skeleton.vf1_observed@1%", "skeleton.branch_f1@1%", "surface.wood.fscore@0.5%",
            "leaves.strict_f1", "support.skeleton@1%")
"""The report's headline, first in every table: the skeleton's volume (vF1), its volume on the wood the capture
observed (vf1_observed: recall over the observed wood only, issue 63) and its structure (branch F1), one surface and
one leaf metric, each of which ``plantbench calibrate`` found to tell a faithful reconstruction from a plausible one
(reports/calibration/), and the GT-free skeleton support."""
HEADLINE_STRUCTURE = ("skeleton.branch_f1@1%",)
"""The headline's structure metric: it also passes the calibration's structure checks (invented branches, wrong
forks)."""
HEADLINE_GT_FREE = ("support.skeleton@1%",)
"""The headline metric that needs no ground truth (real captures); not a fidelity metric (it cannot see missing
branches)."""
HEADLINE_FIDELITY = tuple(m for m in HEADLINE if m not in HEADLINE_GT_FREE)
"""The headline's fidelity metrics: those the calibration must find discriminating."""
KEY_METRICS = (*HEADLINE, "stava.S_T", "mesh_to_surface.D_cm", "mesh_to_surface.sigma_cm", "mesh_to_scan.D_cm",
               "reprojection.error", "reprojection.iou", "leaves.accuracy", "skeleton.f1@1.0", "points.all.fscore@1%")
"""The headline, then the reference paper's and the older columns kept for reproduction: the report's first table
(with the running time) and the metrics the gate compares with the baseline."""

_LABELS_AND_FLOORS = {
    "skeleton.vf1@1%": ("vF1 1%H", 0.005),
    "skeleton.vf1_observed@1%": ("vF1obs 1%H", 0.005),
    "skeleton.branch_f1@1%": ("branch F1", 0.005),
    "surface.wood.fscore@0.5%": ("woodF 0.5%H", 0.005),
    "leaves.strict_f1": ("leaf F1", 0.005),
    "support.skeleton@1%": ("support 1%H", 0.005),
    "stava.S_T": ("S_T", 0.005),
    "mesh_to_surface.D_cm": ("D cm", 0.05),
    "mesh_to_surface.sigma_cm": ("sigma cm", 0.05),
    "mesh_to_scan.D_cm": ("D scan cm", 0.05),
    "reprojection.error": ("reproj err", 0.005),
    "reprojection.iou": ("reproj IoU", 0.005),
    "leaves.accuracy": ("leaf acc", 0.01),
    "skeleton.f1@1.0": ("skel F1 1r", 0.005),
    "points.all.fscore@1%": ("points F1%H", 0.005),
}
METRICS["support.skeleton@spacing"] = MetricInfo(**{**vars(METRICS["support.skeleton@spacing"]), "short": "support 2s"})
for _name, (_short, _floor) in _LABELS_AND_FLOORS.items():
    METRICS[_name] = MetricInfo(**{**vars(METRICS[_name]), "short": _short, "floor": _floor})
assert set(_LABELS_AND_FLOORS) == set(KEY_METRICS) and all(len(m.short or "") <= 11 for m in METRICS.values())
