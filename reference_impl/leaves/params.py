"""Parameters of leaf segmentation and Bezier fitting (Chaurasia and Beardsley 2017), one frozen dataclass.

Lengths given as fractions scale with ``delta_plane`` (the paper's plane-fitting threshold), which itself scales with
the leaf size: the paper's 2 cm is for its leaves, taken here to be ``reference_leaf_length`` long. [S] marks our
choices (not the paper's); what the defaults were measured on: ``docs/tuning/mvs.md``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from plantbench.errors import InputError
from plantbench.schemas import unknown_options

__all__ = ["LeafParams"]


@dataclass(frozen=True)
class LeafParams:
    """Every parameter of :func:`reference_impl.leaves.segment_and_fit` that changes its output."""

    # ---- scale
    delta_plane: float = 0.02
    """Plane-fitting threshold delta_plane (Chaurasia and Beardsley 2017, section 4.1: "typically 2 cm"), metres, for
    leaves of ``reference_leaf_length``; used as RANSAC inlier distance, the unit of Eq. 7's 3D distance and the ICP
    correspondence distance (section 4.2)."""
    reference_leaf_length: float = 0.10
    """Leaf length the paper's delta_plane is meant for (single-lobed beech/holly/cherry leaves; an assumption, the
    paper does not state it). delta_plane is scaled by leaf_length / reference_leaf_length."""
    # ---- depth input
    speckle_fraction: float = 0.01
    """Depth speckle removal before segmentation [S]: an 8-connected piece of a view's depth map smaller than this
    fraction of (leaf length in pixels at the view's median depth)^2 loses its depth (exact depth has none; mvs
    depth's speckles become false leaves). 0: off. Evidence: docs/tuning/mvs.md."""
    # ---- section 4.1: per view
    superpixels_per_leaf: float = 40.0
    """SLIC target: expected projected leaf area / superpixel area (the paper over-segments leaves, Fig. 2(b)) [S].
    The leaves suites use 10, fewer superpixels per leaf on mvs depth: docs/tuning/mvs.md."""
    min_superpixel_px: int = 12
    """Smallest target superpixel area in pixels (bounds the SLIC segment count on far-away, tiny leaves)."""
    slic_compactness: float = 10.0
    """SLIC compactness (scikit-image's default balance of colour and space)."""
    depth_weight: float = 10.0
    """SLIC feature scale of depth: a depth change of delta_plane weighs as much as this many Lab units."""
    ransac_iterations: int = 32
    """RANSAC plane hypotheses per superpixel (3-point samples)."""
    min_points: int = 6
    """A superpixel with fewer back-projected points is dropped ("very few 3D points")."""
    min_inlier_fraction: float = 0.6
    """A superpixel whose best plane explains fewer of its points is dropped ("no valid plane fit")."""
    outlier_factor: float = 3.0
    """After the plane fit, points farther from the inliers' mean than this times their median distance to it are
    removed ("remove 3D points far away from the mean")."""
    sigma: float = 0.2
    """Eq. 8: width of the Gaussian affinity kernel."""
    affinity_threshold: float = 0.85
    """Edges with affinity above this join superpixels into candidate leaves."""
    min_candidate_points: int = 20
    """Candidate leaves (and extracted leaves, section 4.2) with fewer points are skipped as ``few_points``."""
    # ---- section 4.2: across views
    template_leaves: int = 50
    """Most confident candidates whose median length-to-width ratio defines the ellipse template."""
    confidence_bins: int = 25
    """Confidence bins processed in decreasing order (leaves within a bin by decreasing size)."""
    icp_iterations: int = 300
    """Rigid ICP iterations (template to candidate), correspondence distance delta_plane."""
    capture_distance: float = 0.5
    """Scene points within this many delta_plane of the ICP-placed template join the leaf (the paper: 1)."""
    min_width_fraction: float = 0.5
    """A fitted blade whose width is less than this fraction of the template's width-to-length ratio times its
    length is a twig or a sliver: skipped as ``not_leaf_shaped``. [S]"""
    max_length_factor: float = 2.0
    """A fitted blade longer than this many leaf lengths (the species hint, or the length estimated from the data)
    is conjoined leaves or background, skipped as ``not_leaf_shaped`` (the generator's leaves vary log-normally
    with sd 0.12-0.15: twice the mean is over 4 sd out). [S]"""
    min_views: int = 1
    """A leaf whose points come from fewer views is skipped as ``few_views`` [S] (1: off; the leaves suites use 3:
    false leaves on mvs depth come from one or two views, true leaves from most; docs/tuning/mvs.md)."""
    duplicate_fraction: float = 0.5
    """A candidate whose points were already claimed by earlier leaves in this proportion is a duplicate."""
    overlap_fraction: float = 0.8
    """After the fit, a blade whose points lie within ``capture_distance`` x delta_plane of a larger fitted blade in
    at least this proportion is a fragment of it, dropped as ``duplicate`` [S] (lower values also drop real leaves
    beside conjoined blades; docs/tuning/mvs.md)."""
    fragment_fraction: float = 0.0
    """After the fit, a blade whose points lie within delta_plane / 2 of a larger blade's plane in at least this
    proportion, less than a leaf length from it and touching it, is a piece of the same leaf, dropped as
    ``duplicate`` [S] (0: off; the leaves suites use 0.95; docs/tuning/mvs.md)."""
    min_point_fraction: float = 0.0
    """After the fit, a blade with fewer points than this fraction of the typical blade's (the point-weighted
    median of the blades' point counts, so that many small false blades do not set it) is skipped as
    ``few_points_after_icp`` [S] (0: off; the leaves suites use 0.1 with 10 superpixels per leaf, 0.02 with 40;
    docs/tuning/mvs.md)."""
    # ---- section 5: fitting
    scanlines: int = 24
    """UV mapping: scanlines perpendicular to the axis, evenly spaced in v in [0, 1]."""
    max_fit_points: int = 300
    """Points per leaf used by the fit (a seeded subsample of larger clouds)."""
    fit_iterations: int = 15
    """Most alternations of UV mapping and Levenberg-Marquardt (the paper converges in 4-15)."""
    lm_evaluations: int = 3
    """Levenberg-Marquardt steps between two UV mappings (scipy backend: most residual evaluations). [S]"""
    lm_backend: str = "batched"
    """'batched' (:func:`reference_impl.leaves.fit.lm_batch`: every leaf of a plant in one vectorised LM) or
    'scipy' (``scipy.optimize.least_squares(method="lm")``, MINPACK, one leaf at a time; the same energy)."""
    max_width_factor: float = 2.0
    """A fitted blade whose half-width exceeds this many times the semi-minor axis of its points' enclosing ellipse
    has diverged; it keeps the ellipse-shaped start (counted as ``fits_reset``). [S]"""
    fit_tolerance: float = 1e-3
    """Alternation stops when the weighted RMS residual (leaf lengths) changes by less than this."""
    occlusion_weights: bool = True
    """Eq. 10-11 scanline weights from the enclosing ellipse (False: unweighted Eq. 9)."""
    ground: bool = True
    """Remove the ground (RANSAC plane among near-horizontal planes) before segmentation."""

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool | str):
                continue
            if f.name in ("speckle_fraction", "fragment_fraction", "min_point_fraction") and value == 0:
                continue
            if not isinstance(value, int | float) or value <= 0:
                raise InputError(f"leaf parameter {f.name} must be a positive number, got {value!r}", field=f.name)
        if not 0 < self.affinity_threshold < 1 or not 0 < self.min_inlier_fraction <= 1:
            raise InputError("affinity_threshold and min_inlier_fraction must lie in (0, 1)")
        if self.lm_backend not in ("batched", "scipy"):
            raise InputError(f"lm_backend must be 'batched' or 'scipy', got {self.lm_backend!r}", field="lm_backend")
        if not 0 < self.overlap_fraction <= 1:
            raise InputError("overlap_fraction must lie in (0, 1]", field="overlap_fraction")
        if not 0 < self.duplicate_fraction <= 1:
            raise InputError("duplicate_fraction must lie in (0, 1]", field="duplicate_fraction")
        if not 0 <= self.fragment_fraction <= 1:
            raise InputError("fragment_fraction must lie in [0, 1]", field="fragment_fraction")
        if not isinstance(self.min_views, int):
            raise InputError(f"min_views must be an integer, got {self.min_views!r}", field="min_views")

    def scaled_delta(self, leaf_length: float) -> float:
        """delta_plane for leaves ``leaf_length`` metres long."""
        return self.delta_plane * float(leaf_length) / self.reference_leaf_length

    @classmethod
    def from_options(cls, options: dict) -> LeafParams:
        """From a method's option dict (unknown names raise InputError)."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(options) - names)
        if unknown:
            raise InputError("leaves: " + unknown_options(unknown, sorted(names)))
        return cls(**options)
