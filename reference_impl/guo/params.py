"""Parameters of the Guo et al. reference (Guo et al. 2018, section 5; Guo et al. 2017) and the species prior.

Two kinds of parameters:

- :class:`GuoParams`: the method's constants, each with its source ([P] the text of Guo et al. 2018, [P4]
  Guo et al. 2017, [Pal] Palubicki et al. 2009 as quoted in Guo et al. 2018, section 5.2, [S] our choice where the
  paper gives no value; lengths that the paper states in metres are for its clouds "scaled into a 10 m x 10 m x 10 m
  bounding box" (section 6.1) and are scaled here by the plant's size / 10 m).
- :class:`SpeciesPrior`: the species library entry (Table 1: internode length l, roll phi, branching angle psi,
  diameter coefficient gamma; number of stems; twig radius; leaves), built from a species TOML by
  :func:`prior_from_species`, or :data:`GENERIC_PRIOR` (the run without the species hint: the means of the six
  species of Guo et al. 2018, Table 2, generic leaves, stems counted from the cloud).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from plantbench import schemas
from plantbench.errors import InputError

__all__ = ["GuoParams", "SpeciesPrior", "GENERIC_PRIOR", "prior_from_hint", "params_from_options"]


@dataclass(frozen=True)
class GuoParams:
    """Constants of the method (source in brackets, see the module docstring)."""

    # --- Eq. 8: point importance weights
    eps_d: float = 0.03
    """epsilon_D, metres in the paper's 10 m frame (3 cm) [P]; scaled by extent / 10 m, and at least
    ``eps_d_min_spacing`` point spacings so that a sparse cloud still has neighbours [S]."""
    eps_d_min_spacing: float = 2.0
    """Lower bound of epsilon_D in median point spacings [S]."""
    eps_a: float = 0.9
    """epsilon_A: |n_i . n_j| above this counts as the same principal direction [P] (the sign of an eigenvector is
    arbitrary, so the absolute dot product is compared)."""
    pca_min_neighbours: int = 6
    """The PCA giving each point's main direction uses its eps_D ball, and at least this many neighbours [S: the
    paper does not say]."""
    weight_neighbours: int = 48
    """Largest neighbour count examined for the PCA and Eq. 8 (the weight saturates there) [S: bounds the cost]."""

    # --- L-system 1 and space colonisation (section 5.2)
    perception_angle: float = 90.0
    """theta, degrees: full opening of the perception cone [Pal, quoted in 5.2]."""
    kill_factor: float = 0.5
    """d_k = kill_factor * d_i [Pal, quoted in 5.2]."""
    occupy_branch_radius: bool = True
    """The occupancy zone of a node also covers its branch's allometric radius (Eq. 5), so the points on the surface
    of a thick trunk do not attract its own lateral buds [S: a cloud sampled on branch surfaces has markers at the
    branch radius, which a kill distance 0.5 d_i smaller than the trunk radius leaves alive]."""
    h0: float = 2.0
    """H_0 of Eq. 6 (internodes) [P]."""
    rho0: float = 0.3
    """rho_0 of Eq. 6-7 [P]."""
    integer_rho: bool = False
    """Use the integer part of rho_t for d_i and the shoot length (Guo et al. 2017) instead of rho_t
    (Guo et al. 2018) [P4]."""
    rho_min: float = 4.0
    """d_i is at least rho_min * l: Eq. 7 starts at rho_0 H_0 (1 - H_0/K) < 1 internode (0 with the integer part of
    Guo et al. 2017), which would stall the first cycles [S: the bottom of the range d_i in [4 l, 12 l] that section
    5.2 quotes and of Palubicki's 4-6 internodes; docs/tuning/guo.md]."""
    rho_max: float = 4.0
    """d_i is at most rho_max * l: a wider perception cone holds the markers of neighbouring limbs and Eq. 9 aims
    the shoot between them; with rho_min = rho_max d_i is the same on every plant, and Eq. 7 drives d_i again when
    rho_max is raised (Guo et al. 2018: 12 l) [S: measured, docs/tuning/guo.md]."""
    alpha: float = 1.6
    """Weight of V_opt in Eq. 9 [P]."""
    beta: float = 0.3
    """Weight of the tropism in Eq. 9 [P]."""
    tropism: tuple[float, float, float] = (0.0, 0.0, -1.0)
    """V_tropism: the paper's (0, -1, 0) in its Y-up frame, i.e. down in our Z-up frame [P]."""
    lateral_vigour: float = 1.0
    """Bud fate by Borchert-Honda allocation (Palubicki et al. 2009; lambda = 0.5): the
    resource v = alpha x (number of lit buds) is shared among the lit buds in proportion to the marker weight Q
    each perceives, and a bud receiving v grows floor(v) metamers, so a lateral bud whose share is below this many
    metamers (1: the floor rule) stays dormant this cycle; apical buds keep growing while lit; 0 disables (every lit
    lateral bud breaks) [Pal; docs/tuning/guo.md]."""
    bh_alpha: float = 2.0
    """alpha of the Borchert-Honda allocation: mean vigour of a lit bud in metamers (the original code's
    v = 5 + 2 Q has the same slope 2) [Pal]."""
    max_iterations: int = 120
    """Upper bound on growth cycles (the logistic saturates after ~ (ln 99 + ln(K/H0)) / rho0 cycles; growth also
    stops when no bud perceives a marker) [S]."""
    max_nodes: int = 400_000
    """Growth stops before the skeleton exceeds this many nodes (bounded memory on bad input) [S]."""
    marker_voxel: float = 0.5
    """Markers: the points merged per voxel of this many internode lengths, each carrying the summed Eq. 8 weight of
    its points (the paper downsamples its clouds too, section 6.1; one marker per half internode keeps every branch
    resolvable) [S]."""
    max_widen: int = 3
    """Most doublings of the perception radius in a cycle where no bud perceives a marker (gaps in the cloud) [S]."""
    neighbours: int = 8
    """Closest buds examined per marker when assigning markers to perception cones [S]."""

    outlier_neighbours: int = 8
    """Isolated points are dropped before anything else: those whose distance to their outlier_neighbours-th
    nearest neighbour exceeds ... [S: multi-view floaters would attract branches across empty space]"""
    outlier_factor: float = 4.0
    """... this many times the median of that distance [S]."""

    # --- roots (section 5.3, Fig. 9)
    root_slab: float = 0.05
    """Points lower than this fraction of the height are projected on the ground plane for the density map (the
    stems' bases; the crown's projection would otherwise mask them): low enough that a shrub's low crown and the
    lowest leaves stay out of the slab [S: measured, docs/tuning/guo.md]."""
    root_central: float = 0.4
    """... and, for a single-stem species, within this fraction of the crown radius (90th percentile of the points'
    horizontal distances from their median) of the plant's centre, when at least 3 slab points are: branch tips
    bending down to the ground at the crown's rim are not its stem (the stems of a multi-stem shrub may stand apart)
    [S: the same fraction as reference_impl.common.roots.find_roots]."""
    root_cell: float = 1.0
    """Density map cell, in internode lengths [S]."""
    root_min_density: float = 0.25
    """Without a species prior, every density peak above this fraction of the highest one is a root [S]."""
    trunk_fit_height: float = 0.06
    """The cross-section fit uses the points between 1 % and this fraction of the height above the root [S]."""
    stem_sections: bool = True
    """Move each stem's lowest 30 % onto the axis of circles fitted to the cloud's stem sections where they are one
    stem's bark ring (:func:`reference_impl.common.roots.recentre_stems`): shoots grown towards markers on a thick
    trunk's bark run along its bark [S: docs/tuning/xu.md]. False: the stems stay where the growth put them."""
    breast_height_fit: bool = True
    """Scale every radius so the stem's radius 1.3 m above the base matches a circle fitted to the cloud there, on
    plants taller than 3 m whose stem shows bark at breast height (:func:`reference_impl.common.roots.
    breast_height_scale`): the base fit takes in the root flare and the allometric taper overshoots the DBH [S]."""

    # --- occluded crowns (Fig. 8)
    hull_fill: str = "auto"
    """'auto' (fill when the crown's interior is empty), 'on' or 'off' [P: applied to occluded crowns]."""
    hull_spacing: float = 2.0
    """Poisson-disk spacing of the interior samples, internode lengths [S]."""
    hull_shell_ratio: float = 0.7
    """'auto' fills when the crown points' median depth inside the hull is below this fraction of the interior
    samples' (the visible points form a shell around an empty interior) [S]."""
    hull_max_samples: int = 60_000
    """At most this many interior samples (the spacing grows if needed) [S]."""

    # --- refinement (section 5.3)
    shed: bool = True
    """Shed, on the fly, lateral branches whose Eq. 5 radius (anchored on the measured trunk radius) falls below
    ``shed_radius`` times the species' twig radius and that stopped growing ("unreasonable branches can be shed once
    they do not satisfy the allometric rules", section 6.2, Fig. 12) [P]. A tree grown longer than its trunk can
    feed gets twigs thinner than the species makes, and loses its smallest stopped laterals."""
    shed_radius: float = 1.0
    """Shedding threshold as a fraction of the species' one-internode twig radius [S]."""
    shed_age: int = 3
    """Cycles without growth before a thin branch is shed [S, Palubicki's shedding delay]."""
    prune_tips: float = 8.0
    """After growth, terminal branches (a fork to a tip) shorter than this many internode lengths, and than
    ``prune_cap`` x the plant's height, are shed until none is left (the shedding of section 6.2 applied once the
    crown is grown: a shoot that grew this little toward the cloud is a twig the cloud's noise lit) [S: measured,
    docs/tuning/guo.md]. 0: none."""
    prune_cap: float = 0.05
    """``prune_tips``'s length is at most this fraction of the plant's height: the species' internode is a large
    share of a small shrub, where a few internodes are a real twig [S]."""
    merge_forks: float = 2.0
    """After growth, two forks joined by a chain shorter than this many internode lengths become one fork (laterals
    that broke from neighbouring metamers) [S: docs/tuning/guo.md]. 0: none."""
    trim_tips: float = 1.0
    """After that, every tip farther than this many internode lengths from every point of the cloud (and every hull
    sample) is trimmed back along its chain to the first node within it (reference_impl.common.skeleton_ops.
    trim_unsupported_tips): space colonisation stops a shoot only once its last markers die, up to the kill distance
    (two internodes) short of them, and on a sparse scan a shoot whose markers a neighbour killed grows on across
    the gap [S: measured, docs/tuning/guo.md: the share of the skeleton on AdTree's tree1 scan 0.776 -> 0.811,
    tree7 0.786 -> 0.849, 6-11 % of the length trimmed; on multi-view clouds 0.7-1.4 % and vF1 within 0.001]. 0: none."""
    collapse_angle: float = 10.0
    """Branch collapse: a degree-2 node whose edges turn by less than this (degrees) ... [S: no value in the paper]."""
    collapse_radius: float = 0.1
    """... and whose radii differ by less than this fraction is collapsed into its parent [S]."""
    smooth_angle: float = 20.0
    """theta of the Hermite smoothing, degrees [P]."""

    leaf_tip_internodes: int = 0
    """Leaves go on the thin nodes (species' max_branch_radius) at most this many internodes below a tip
    ("distributed at the tip nodes", section 5.3); 0 puts them on every thin node, the generator's rule [S]."""
    leaf_fit: bool = True
    """Turn each procedural leaf about its base into the cloud around it (blade normal = the local points' smallest
    principal direction), the data-driven part of the leaf configuration of ref. [40] of Guo et al. 2018
    [P: "considering ... the normal direction"; S: the rule]."""

    leaf_support: float = 1.5
    """A leaf is kept only when the mean distance from its blade's vertices to the cloud is at most this many median
    point spacings of the cloud, i.e. when the blade lies on points the cameras saw; 0 keeps every leaf [S: a
    procedural leaf off the cloud is a guess that the data contradicts; docs/tuning/guo.md]."""
    leaf_dedup: bool = True
    """After fitting, a leaf whose blade centre lies within half a leaf length of a better-supported kept leaf's is
    dropped: several procedural leaves snapped onto the same observed leaf count once [S]."""

    # --- analysis-by-synthesis (Guenard et al. 2014, Eq. 4)
    candidates: int = 1
    """Candidates grown and scored against the input views; 1 disables analysis-by-synthesis."""
    candidate_jitter: float = 0.1
    """Relative standard deviation of l and of the angles phi and psi across candidates; also the sigma of the
    species prior p(M) (a product of Gaussians of the relative deviations) [S]."""
    mask_dilation: int = 2
    """Estimated input masks: the cloud splatted into each view, closed with this many pixels [S]."""


@dataclass(frozen=True)
class SpeciesPrior:
    """What the species hint tells the method (:class:`plantbench.hints.SpeciesHint`: Table 2 and the leaves)."""

    name: str
    internode_length: float
    """l, metres."""
    roll_angle: float
    """phi, degrees."""
    branching_angle: float
    """psi, degrees."""
    diameter_coefficient: float
    """gamma of Eq. 5."""
    roots: int | None
    """Number of stems (None: count density peaks in the cloud, for a multi-stem species)."""
    tip_radius: float
    """Radius of a one-internode twig, metres (the thinnest branch the species makes)."""
    leaves: object | None = field(default=None, repr=False)
    """reference_impl.guo.leaves.LeafConfig from the hint, or None for the generic leaf."""


GENERIC_PRIOR = SpeciesPrior(
    name="generic",
    internode_length=0.0485,   # mean l of Guo et al. 2018, Table 2 (0.050, 0.038, 0.051, 0.049, 0.052, 0.051)
    roll_angle=104.8,          # mean phi (120, 97, 95, 130, 87, 100)
    branching_angle=37.2,      # mean psi (38, 37, 35, 34, 41, 38)
    diameter_coefficient=0.44,  # mean gamma (0.45, 0.50, 0.43, 0.42, 0.43, 0.41)
    roots=None,
    tip_radius=0.001,
    leaves=None,
)
"""The run without the species hint: Table 2's mean parameters, generic leaves, stems counted from the cloud."""


def prior_from_hint(hint) -> SpeciesPrior:
    """The prior of a published species hint (:class:`plantbench.hints.SpeciesHint`): its Table 2 values, one stem
    unless it is multi-stem (then counted in the cloud), its twig radius, and leaves of its arrangement and mean
    length (divergence phi, leaf-bearing branches up to twice the twig radius) [S]."""
    from reference_impl.guo.leaves import LeafConfig

    return SpeciesPrior(
        name=hint.species,
        internode_length=float(hint.internode_length),
        roll_angle=float(hint.roll_angle),
        branching_angle=float(hint.branching_angle),
        diameter_coefficient=float(hint.diameter_coefficient),
        roots=None if hint.multi_stem else 1,
        tip_radius=float(hint.twig_radius),
        leaves=LeafConfig(length=float(hint.leaf_length), arrangement=hint.leaf_arrangement,
                          divergence=float(hint.roll_angle), max_radius=2.0 * float(hint.twig_radius)),
    )


def params_from_options(options: dict) -> GuoParams:
    """GuoParams from suite options (:func:`plantbench.schemas.params_from_options`: unknown names raise InputError
    listing the valid ones); values the method cannot run with raise InputError too."""
    p = schemas.params_from_options(GuoParams, options, method="guo",
                                    also=("prior", "leaves", "leaf_depth", "leaf__..."))
    if p.hull_fill not in ("auto", "on", "off"):
        raise InputError(f"guo: hull_fill must be 'auto', 'on' or 'off', got {p.hull_fill!r}")
    if p.candidates < 1:
        raise InputError(f"guo: candidates must be >= 1, got {p.candidates}")
    if not (0 < p.kill_factor <= 1) or not (0 < p.perception_angle <= 180):
        raise InputError("guo: kill_factor must be in (0, 1] and perception_angle in (0, 180]")
    if not 0 < p.rho_min <= p.rho_max:
        raise InputError(f"guo: need 0 < rho_min <= rho_max, got {p.rho_min}, {p.rho_max}")
    if p.max_iterations < 1 or p.max_nodes < 10:
        raise InputError("guo: max_iterations must be >= 1 and max_nodes >= 10")
    if p.trim_tips < 0:
        raise InputError(f"guo: trim_tips must be >= 0 (0: none), got {p.trim_tips}")
    return p
