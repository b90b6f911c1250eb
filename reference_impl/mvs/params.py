"""Parameters of the multi-view point-cloud stage, one frozen dataclass per step.

Every field that changes the output is here, with its default; :class:`MVSParams` collects them and
:meth:`MVSParams.from_options` maps a suite's ``[method_options.mvs]`` keywords onto them (unknown keywords are an
:class:`~plantbench.errors.InputError`). What the defaults were measured on: ``docs/tuning/mvs.md``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

from plantbench.errors import InputError
from plantbench.schemas import unknown_options

__all__ = ["REFERENCE_VIEW_PX", "AUTO_BACKGROUND_SPAN", "REFERENCE_FOCAL_PX", "NeighbourParams", "DepthParams", "FilterParams", "FusionParams", "GroundParams", "SfMParams", "MVSParams"]


@dataclass(frozen=True)
class NeighbourParams:
    """Choice of source views for each reference view."""

    count: int = 4
    """Number of source (neighbour) views per reference view."""
    min_angle_deg: float = 5.0
    """Smallest triangulation angle (between the rays to the scene centre) of a usable neighbour; below it depth is
    ill-conditioned."""
    max_angle_deg: float = 50.0
    """Largest triangulation angle of a usable neighbour; above it the appearance changes too much to match."""
    best_angle_deg: float = 15.0
    """Preferred triangulation angle: candidates are ranked by |angle - best| weighted by their frustum overlap."""
    min_overlap: float = 0.2
    """Smallest fraction of the reference frustum (sampled over its depth range) that a neighbour must see."""


REFERENCE_VIEW_PX = 512
"""The shorter side, pixels, of the views the depth and filter defaults were measured on (the multiview suites):
:attr:`DepthParams.window_scale` and :attr:`FilterParams.depth_px` carry them to other image sizes."""
AUTO_BACKGROUND_SPAN = 0.5
""":attr:`DepthParams.background_span` where the views are matched at 768 px or more (the windows scaled at least
twice): the value of the 1024 and 2048 px levels of the views-realism sweep."""
REFERENCE_FOCAL_PX = 0.5 * REFERENCE_VIEW_PX / math.tan(math.radians(40.0) / 2)
"""Their focal length, pixels (the capture's default 40 deg horizontal field of view): 703.3."""


@dataclass(frozen=True)
class DepthParams:
    """Per-view depth and normal estimation: fronto-parallel plane sweep, then slanted-plane PatchMatch."""

    hypotheses: int = 128
    """Number of depth planes of the sweep, uniform in inverse depth over the view's depth range."""
    sweep_window: int = 5
    """Side of the square ZNCC window of the sweep, pixels (odd)."""
    coarse_scale: int = 2
    """Coarse to fine: the sweep and the first ``coarse_iterations`` PatchMatch iterations run on the images
    downsampled by this factor, then ``pm_iterations`` at full resolution, with the checkerboard window
    (``coarse_checker``) at both levels, a random depth as the fine level's fresh candidate (``fine_random_depth``)
    and ``coarse_max_cost``; 1 runs everything at full resolution with the dense window. Used only when the coarse
    image keeps ``coarse_min_size`` pixels on its shorter side."""
    coarse_min_size: int = 256
    """Coarse to fine only when the downsampled image's shorter side has at least this many pixels."""
    coarse_iterations: int = 2
    """PatchMatch iterations at the coarse scale, before the ``pm_iterations`` at full resolution (coarse to fine
    only)."""
    coarse_checker: bool = True
    """Coarse to fine evaluates only the PatchMatch window samples with an even offset sum (a checkerboard: 13 of 25
    for r = 2), the sparse sampling of Gipuma (Galliani et al. 2015)."""
    fine_random_depth: bool = True
    """At the fine level of coarse to fine, each pixel's fresh random candidate is a depth (uniform in inverse depth,
    with its current normal) instead of a normal."""
    coarse_max_cost: float = 0.57
    """``max_cost`` of coarse to fine, whose final costs come from the 13-sample checkerboard window."""
    top_k: int = 2
    """Matching cost = mean of the ``top_k`` best source costs (robust to occlusion in the other sources)."""
    pm_iterations: int = 2
    """PatchMatch iterations (each a red and a black half-sweep over the image)."""
    pm_radius: int = 2
    """PatchMatch window half-size in samples; the window spans (2 r + 1)^2 samples ``pm_step`` pixels apart."""
    pm_step: int = 1
    """Pixel spacing of the PatchMatch window samples (2 with r = 1: a sparse 3 x 3 sampling of a 5 x 5 footprint)."""
    propagation: str = "four"
    """PatchMatch propagation: 'four' (each pixel tries the planes of its 4 adjacent pixels, so a plane travels
    about one pixel per half-sweep) or 'adaptive' (the adaptive checkerboard sampling of ACMH, Xu and Tao 2019:
    from each of 4 V-shaped near regions of 7 samples and 4 long strips of 11 samples reaching 23 pixels, the
    sample of lowest current cost, 8 candidates that carry a plane across a weakly textured surface in one
    iteration)."""
    geometric_iterations: int = 0
    """Geometric-consistency pass (ACMM, Xu and Tao 2019, section 3.3): once every view has its photometric depth,
    this many more full-resolution PatchMatch iterations per view in which each source's cost gains
    ``geometric_weight`` x min(forward-backward reprojection error through the source's depth map,
    ``geometric_max_px``). The term only guides the choice of planes; a pixel is kept on its photometric cost as
    before. 0: off."""
    geometric_weight: float = 0.2
    """ACMM's weight of the reprojection error (pixels) against the photometric cost (1 - ZNCC)."""
    geometric_max_px: float = 3.0
    """ACMM's truncation of the reprojection error, pixels."""
    pm_checker: bool = False
    """Use the checkerboard window (see ``coarse_checker``) at full resolution too."""
    pm_textured_only: bool = False
    """Refine only the pixels textured enough to keep a depth, the others keeping their sweep plane."""
    fine_textured_only: bool = True
    """Coarse to fine: the full-resolution iterations refine only the pixels textured enough to keep a depth (the
    coarse level refines every pixel, so planes still travel across untextured ones there); 1024 px views: the same
    cloud (accuracy 2.38 cm, wood recall 0.461 against 0.463) for 11 % less depth time [S: docs/tuning/mvs.md]."""
    bilateral_sigma_color: float = 0.1
    """Colour sigma of the bilateral support weights (grey levels in [0, 1])."""
    bilateral_sigma_space: float = 3.0
    """Spatial sigma of the bilateral support weights, pixels."""
    window_scale: int = 0
    """The windows above (``sweep_window``, ``pm_step``, ``bilateral_sigma_space``) are sizes at 512 px, where they
    were measured; a view whose shorter side is S pixels runs them ``window_scale`` times larger: the sweep window
    2 (w // 2) s + 1, the PatchMatch samples s ``pm_step`` pixels apart (the same (2 ``pm_radius`` + 1)^2 samples,
    the same cost), the spatial sigma s times. 0 (auto): s = round(S / 512), at least 1, so a window covers the same
    share of the view at every size above 512 px (1024 px: a 9 px sweep window, samples 2 px apart, sigma 6 px) and
    smaller views keep the 512 px windows. 1: the sizes as given, at any image size [S: docs/tuning/mvs.md]."""
    max_cost: float = 0.6
    """A pixel keeps its depth when its final cost (1 - weighted ZNCC, mean of the ``top_k`` best sources) is
    below this value."""
    min_texture: float = 0.01
    """Pixels whose reference window has a grey-level standard deviation below this are not matched."""
    depth_margin: float = 1.25
    """Scene radius used for the depth range = margin x (distance to the scene centre) x tan(half field of view)."""
    background_span: float | None = None
    """Depths beyond the scene are searched too, over this fraction of the scene's inverse-depth span beyond its
    far end (with ``hypotheses`` raised in proportion, so the scene keeps its plane spacing), and a pixel whose best
    depth lies there is background, not kept: without them a pixel that sees the ground far behind the plant takes
    the cheapest depth inside the scene, and such wrong depths agree across neighbouring views [S]. 0: off. None
    (auto): :data:`AUTO_BACKGROUND_SPAN` where the windows run at least twice their 512 px size (``window_scale``,
    auto from 768 px), 0 below, where the floater filter removes those depths and the search would cost thin branches
    [S: docs/tuning/mvs.md]."""

    def __post_init__(self) -> None:
        if not (isinstance(self.window_scale, int) and self.window_scale >= 0):
            raise InputError(f"mvs: depth_params__window_scale must be an integer >= 0 (0: auto), got "
                             f"{self.window_scale!r}")
        if self.background_span is not None and not self.background_span >= 0:
            raise InputError(f"mvs: depth_params__background_span must be >= 0 or absent (auto), got "
                             f"{self.background_span!r}")

    def for_view(self, width: int, height: int) -> DepthParams:
        """These parameters for a view of ``width`` x ``height`` pixels: the windows scaled by ``window_scale``
        and the automatic ``background_span`` resolved (see there), everything else as it is."""
        s = self.window_scale or max(1, int(min(width, height) / REFERENCE_VIEW_PX + 0.5))
        span = self.background_span
        if span is None:
            span = AUTO_BACKGROUND_SPAN if s >= 2 else 0.0
        if s == 1:
            return self if span == self.background_span else dataclasses.replace(self, background_span=span)
        return dataclasses.replace(self, sweep_window=2 * (self.sweep_window // 2) * s + 1, pm_step=self.pm_step * s,
                                   bilateral_sigma_space=self.bilateral_sigma_space * s, window_scale=1,
                                   background_span=span)


@dataclass(frozen=True)
class FilterParams:
    """Geometric coherence across views (Guo et al. 2018, Eq. 3-4, in spirit) and the edge-aware guided filter."""

    min_consistent: int = 1
    """A depth is kept when at least this many other views agree with it (1: the point is confirmed by two views,
    the reference and one other)."""
    reproj_px: float = 2.0
    """Agreement: the forward-backward reprojection error is below this many pixels ..."""
    depth_px: float = 0.005 * REFERENCE_FOCAL_PX
    """... and the depths differ by less than this many pixel footprints (a pixel at depth z spans z / f, f the
    reference view's focal length in pixels): the relative tolerance is ``depth_px / f``, the same share of a pixel at
    every image size. 3.52 footprints: 0.5 % of the depth at 512 px and a 40 deg field of view (f = 703.3 px), where
    it was measured (with the plant filling the frame and the cameras about 1.5 plant heights away, about 0.75 % of
    its height); 1 % at 256 px, 0.25 % at 1024 px (docs/tuning/mvs.md)."""
    search_radius: int = 1
    """The other view agrees when any of its pixels within this radius (Chebyshev, pixels) of the projection
    passes the test (0: nearest pixel only)."""
    consistency_views: int = 8
    """Number of views (nearest by viewing direction) against which each reference is checked."""
    guided_radius: int = 2
    """Guided-filter window radius, pixels (He et al. 2010)."""
    guided_eps: float = 1e-4
    """Guided-filter regulariser eps (on grey levels in [0, 1])."""
    guided: bool = True
    """Apply the guided filter to the kept depths."""

    def __post_init__(self) -> None:
        if not self.depth_px > 0:
            raise InputError(f"mvs: filter__depth_px must be > 0 (pixel footprints), got {self.depth_px!r}")

    def rel_depth(self, focal_px: float) -> float:
        """The relative depth tolerance of a view with focal length ``focal_px`` (pixels): ``depth_px / focal_px``."""
        return float(self.depth_px) / float(focal_px)


@dataclass(frozen=True)
class FusionParams:
    """Fusion of the per-view depth maps into one cloud."""

    points: int = 200_000
    """Target number of points after voxel downsampling (the result has at most this many)."""
    max_violations: int = 1
    """A point is dropped when more than this many views see through it (free-space violations)."""
    pre_ground_factor: int = 4
    """Before ground removal the cloud is downsampled to this many times ``points`` only; the final downsampling
    to ``points`` comes after it."""


@dataclass(frozen=True)
class GroundParams:
    """Separation of the plant from the ground."""

    enabled: bool = True
    """Remove the ground; when False the whole fused cloud is written."""
    ransac_iterations: int = 500
    """RANSAC iterations of the plane fit."""
    max_tilt_deg: float = 30.0
    """The ground plane's normal lies within this angle of the up axis (world +Z)."""
    inlier_fraction: float = 0.005
    """Plane inlier distance as a fraction of the cloud's scale (distance from the cameras to the scene centre)."""
    height_fraction: float = 0.01
    """Points less than this fraction of the scene scale above the plane are ground."""
    color_band: float = 3.0
    """Points up to ``color_band`` x the height threshold above the plane are removed when their colour matches the
    ground's (Mahalanobis distance below ``color_mahalanobis``)."""
    color_mahalanobis: float = 2.0
    """Mahalanobis radius (RGB) of the ground colour model."""
    cluster_fraction: float = 0.01
    """After removing the ground, connected components (radius graph) smaller than this fraction of the largest
    are dropped as floaters."""


@dataclass(frozen=True)
class SfMParams:
    """pycolmap feature extraction, matching and incremental mapping in SfM mode (``poses='sfm'``); COLMAP's
    defaults where a field gives none."""

    peak_threshold: float = 0.002
    """SIFT peak (contrast) threshold (COLMAP default 0.0067)."""
    octave_resolution: int = 4
    """SIFT scales per octave (COLMAP default 3)."""
    domain_size_pooling: bool = True
    """DSP-SIFT descriptors (Dong and Soatto 2015; COLMAP default off)."""
    estimate_affine_shape: bool = True
    """Affine-covariant keypoints (COLMAP default off)."""
    max_num_features: int = 8192
    """Most keypoints per image (COLMAP default 8192)."""
    guided_matching: bool = True
    """Re-match under the verified two-view geometry (recovers matches the ratio test dropped; COLMAP default off)."""
    init_min_num_inliers: int = 30
    """Verified matches needed by the initial pair (COLMAP default 100)."""
    abs_pose_min_num_inliers: int = 15
    """2D-3D inliers needed to register a view (COLMAP default 30)."""
    min_num_matches: int = 15
    """Fewest matches for an image pair to enter the scene graph (COLMAP default 15)."""


@dataclass(frozen=True)
class MVSParams:
    """Everything the ``mvs`` method does, with defaults."""

    poses: str = "known"
    """'known' (views/cameras.json) or 'sfm' (pycolmap SIFT + incremental mapping, aligned by Sim(3) afterwards)."""
    intrinsics: str = "known"
    """SfM mode only: 'known' (fixed from cameras.json) or 'unknown' (estimated by bundle adjustment)."""
    depth: str = "estimated"
    """'estimated' (plane sweep + PatchMatch) or 'oracle' (ground-truth depth plus noise; reads views/depth,
    views/instance and plant/plant.json, being an oracle)."""
    noise: float = 0.0
    """Oracle mode: Gaussian z-depth noise sigma as a fraction of the plant height (plant.json)."""
    max_size: int = 1024
    """Largest image side, pixels, at which depth is estimated: larger views are downscaled by area averaging (their
    cameras with them) before the sweep, and the filtered depth maps written at the views' own size (nearest
    neighbour); 0: every view at its own size. The window, filter and fusion parameters are in pixels of the image
    that is matched. 1024 (COLMAP's ``max_image_size`` practice): 2048 px views searched at 1024 px gave the sweep's
    most accurate cloud (4.01 cm against 5.23 searched whole and 5.02 at 512 px) in a quarter of the time [S:
    docs/tuning/mvs.md]."""
    write_depth: bool = False
    """With known poses the filtered depth maps are always written (out_dir/depth/NNNN.npz, key ``depth``: the leaf
    segmentation of guo reads them); this adds the raw depth, normal and cost maps (and writes them with SfM poses
    too, in the SfM model's frame)."""
    neighbours: NeighbourParams = field(default_factory=NeighbourParams)
    depth_params: DepthParams = field(default_factory=DepthParams)
    filter: FilterParams = field(default_factory=FilterParams)
    fusion: FusionParams = field(default_factory=FusionParams)
    ground: GroundParams = field(default_factory=GroundParams)
    sfm: SfMParams = field(default_factory=SfMParams)

    def __post_init__(self) -> None:
        if self.poses not in ("known", "sfm"):
            raise InputError(f"mvs: poses must be 'known' or 'sfm', got {self.poses!r}")
        if self.intrinsics not in ("known", "unknown"):
            raise InputError(f"mvs: intrinsics must be 'known' or 'unknown', got {self.intrinsics!r}")
        if self.depth not in ("estimated", "oracle"):
            raise InputError(f"mvs: depth must be 'estimated' or 'oracle', got {self.depth!r}")
        if not self.noise >= 0:
            raise InputError(f"mvs: noise must be >= 0, got {self.noise!r}")
        if not (isinstance(self.max_size, int) and (self.max_size == 0 or self.max_size >= 64)):
            raise InputError(f"mvs: max_size must be an integer >= 64 (pixels) or 0 (no limit), got {self.max_size!r}")

    @classmethod
    def from_options(cls, options: dict) -> MVSParams:
        """Build from flat keywords: top-level fields by name (``points`` is ``fusion.points``), and any nested
        field as ``GROUP__FIELD`` (e.g. ``depth_params__hypotheses=64``, ``ground__enabled=False``)."""
        top, nested = {}, {}
        groups = {f.name: f for f in dataclasses.fields(cls) if dataclasses.is_dataclass(f.default_factory)}
        for key, value in options.items():
            if key == "points":
                nested.setdefault("fusion", {})["points"] = int(value)
            elif "__" in key:
                group, name = key.split("__", 1)
                if group not in groups:
                    raise InputError("mvs: " + unknown_options([key], [f"{g}__..." for g in groups]))
                names = {f.name for f in dataclasses.fields(groups[group].default_factory)}
                if name not in names:
                    raise InputError("mvs: " + unknown_options([key], [f"{group}__{n}" for n in sorted(names)]))
                nested.setdefault(group, {})[name] = value
            elif key in {f.name for f in dataclasses.fields(cls)} and key not in groups:
                top[key] = value
            else:
                valid = ["points", *(f.name for f in dataclasses.fields(cls) if f.name not in groups),
                         *(f"{g}__..." for g in groups)]
                raise InputError("mvs: " + unknown_options([key], valid))
        for group, values in nested.items():
            top[group] = groups[group].default_factory(**values)
        return cls(**top)
