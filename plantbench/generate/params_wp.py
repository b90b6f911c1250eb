"""Species parameters of the ``weber-penn`` family (Weber and Penn 1995): the pydantic model a species file with
``family = "weber-penn"`` validates against.

Names follow the paper with the level prefix moved into the group: the paper's ``nLength``, ``nCurve`` ... of level
n are ``[trunk]`` (n = 0), ``[level1]``, ``[level2]``, ``[level3]`` fields; the global parameters (Shape, BaseSize,
Scale, Ratio, RatioPower, Flare, 0BaseSplits) are the ``[tree]`` group. Leaves are one more level on the deepest
stems (W&P's Leaves, LeafDistrib) and use the same Bezier leaves as every other family (``[leaves]``, the
:class:`~plantbench.generate.params.Leaves` model with the W&P placement fields added).

Dropped from the paper (docs/design.md, Generator): Lobes/LobeDepth, pruning, LeafQuality, helical curvature
(negative CurveV). Added (Xfrog-like): an explicit child arrangement per level (spiral, alternate,
opposite, whorl) and a leaf size profile along a twig.

Every numeric field has bounds, so an out-of-range value is reported as ``file: field: Input should be ...``.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from plantbench.generate.params import Leaves, Shape, SpeciesBase
from plantbench.schemas import Strict

__all__ = ["Tree", "StemLevel", "Trunk", "BranchLevel", "WeberPennLeaves", "WeberPennWood", "WeberPennSpecies"]


class Tree(Strict):
    """Global parameters (Weber and Penn Table 1, first block)."""

    shape: Shape = Field(description="Shape: crown shape, ShapeRatio(shape, r) scales level-1 lengths along the trunk")
    base_size: float = Field(ge=0, le=0.99, description="BaseSize: fraction of the trunk without branches")
    scale: float = Field(gt=0.1, le=60, description="Scale: tree size, metres (trunk length = scale * trunk.length)")
    scale_v: float = Field(default=0.0, ge=0, le=30, description="ScaleV: uniform variation of scale, metres")
    ratio: float = Field(gt=0.001, le=0.2, description="Ratio: trunk base radius / trunk length")
    ratio_power: float = Field(default=1.2, ge=0, le=4,
                               description="RatioPower: child radius = parent radius (L_child / L_parent)^RatioPower")
    flare: float = Field(default=0.0, ge=0, le=3, description="Flare: radius increase at the trunk base (x (1 + flare))")
    base_splits: int = Field(default=0, ge=0, le=5, description="0BaseSplits: clones of the trunk at the crown base")


class StemLevel(Strict):
    """Per-level stem parameters shared by the trunk and the branch levels."""

    length: float = Field(gt=0, le=2, description="nLength: relative length (trunk: of scale; level 1: of the trunk, "
                          "times ShapeRatio; deeper: of the parent length left beyond the child, L_p - 0.7 offset)")
    length_v: float = Field(default=0.0, ge=0, le=1, description="nLengthV: uniform variation of length")
    taper: float = Field(default=1.0, ge=0, le=2,
                         description="nTaper: 0 cylinder, 1 cone to a point, (1, 2] a rounded (spherical) end")
    curve_res: int = Field(default=3, ge=1, le=24, description="nCurveRes: segments per stem")
    curve: float = Field(default=0.0, ge=-360, le=360,
                         description="nCurve, degrees: total bend (positive away from the parent's direction)")
    curve_back: float = Field(default=0.0, ge=-360, le=360, description="nCurveBack, degrees: bend of the second half "
                              "(S-curve; 0: the whole stem bends by curve)")
    curve_v: float = Field(default=0.0, ge=0, le=720, description="nCurveV, degrees: random bend (uniform +-curve_v "
                           "over the stem, about a random axis per segment)")
    seg_splits: float = Field(default=0.0, ge=0, le=2, description="nSegSplits: clones per segment (fractional parts "
                              "carried over)")
    split_angle: float = Field(default=0.0, ge=0, le=90, description="nSplitAngle, degrees: deflection of each clone")
    split_angle_v: float = Field(default=0.0, ge=0, le=90, description="nSplitAngleV, degrees")
    attraction_up: float = Field(default=0.0, ge=-10, le=10, description="AttractionUp: per segment the heading turns "
                                 "min(1, |a| / curve_res) of its angle towards +z (a > 0) or -z (a < 0)")


class Trunk(StemLevel):
    """Level 0: the trunk."""

    length: float = Field(default=1.0, gt=0, le=2, description="0Length: trunk length / scale")


class BranchLevel(StemLevel):
    """Levels 1-3: stems on the previous level's stems."""

    branches: float = Field(ge=0, le=400, description="nBranches: most stems of this level on one parent stem")
    base_size: float = Field(default=0.0, ge=0, le=0.95,
                             description="fraction of this level's stems (from their base) without children or leaves")
    down_angle: float = Field(ge=-180, le=180, description="nDownAngle, degrees: angle from the parent's direction")
    down_angle_v: float = Field(default=0.0, ge=-180, le=180, description="nDownAngleV, degrees: >= 0 uniform "
                                "variation; < 0 varies the angle along the parent (W&P: down + V (1 - 2 ShapeRatio("
                                "conical, r)), r = 1 at the parent's base)")
    rotate: float = Field(default=137.5, ge=0, le=360, description="nRotate, degrees: roll between successive "
                          "children (spiral) or successive pairs / whorls")
    rotate_v: float = Field(default=0.0, ge=0, le=180, description="nRotateV, degrees")
    arrangement: Literal["spiral", "alternate", "opposite", "whorl"] = Field(
        default="spiral", description="children per node: spiral (1, rolled by rotate), alternate (1, two-ranked in "
        "the plane of the parent and the horizontal), opposite (2), whorl (whorl_count)")
    whorl_count: int = Field(default=4, ge=2, le=12, description="whorl: children per node")


class WeberPennLeaves(Leaves):
    """The shared Bezier :class:`~plantbench.generate.params.Leaves` plus W&P's leaf placement.

    Leaves sit on the deepest level's stems (``max_branch_radius`` of the shared model is not used by this family).
    """

    per_stem: float = Field(ge=0, le=400, description="Leaves: most leaves on one stem of the deepest level")
    distribution: Shape = Field(default="tapered_cylindrical", description="LeafDistrib: leaves on a stem = per_stem "
                                "* ShapeRatio(distribution, offset / L_parent) of the stem's offset on its parent")
    start: float = Field(default=0.1, ge=0, le=0.95, description="fraction of a leaf-bearing stem (from its base) "
                         "without leaves")
    size_profile: Shape = Field(default="cylindrical", description="leaf length along its twig: length * ShapeRatio("
                                "size_profile, r), r = 1 at the twig's base, 0 at its tip (cylindrical: constant)")


class WeberPennWood(Strict):
    """Radii floor and the generalised cylinders."""

    min_radius: float = Field(default=0.0008, gt=0.00005, le=0.05, description="smallest branch radius, metres")
    max_sides: int = Field(default=12, ge=3, le=64, description="sides of the thickest tubes")
    min_sides: int = Field(default=4, ge=3, le=16, description="sides of the thinnest tubes")
    edge_length: float = Field(default=0.025, gt=0.001, le=1.0, description="target ring edge length, metres")
    ground_clearance: float = Field(default=0.05, ge=0, le=2, description="a branch that would reach below this "
                                    "height stops there (weeping branches end above the ground), metres")


class WeberPennSpecies(SpeciesBase):
    """A species of the ``weber-penn`` family (one ``scenes/species/*.toml``)."""

    family: Literal["weber-penn"] = "weber-penn"
    tree: Tree
    trunk: Trunk = Field(default_factory=Trunk)
    level1: BranchLevel | None = Field(default=None, description="first branch level (W&P Levels >= 2)")
    level2: BranchLevel | None = Field(default=None, description="second branch level (W&P Levels >= 3)")
    level3: BranchLevel | None = Field(default=None, description="third branch level (W&P Levels = 4)")
    wood: WeberPennWood = Field(default_factory=WeberPennWood)
    leaves: WeberPennLeaves

    @model_validator(mode="after")
    def _contiguous_levels(self) -> WeberPennSpecies:
        if self.level3 is not None and self.level2 is None:
            raise ValueError("level3 needs level2")
        if self.level2 is not None and self.level1 is None:
            raise ValueError("level2 needs level1")
        if self.wood.min_sides > self.wood.max_sides:
            raise ValueError("wood.min_sides must not exceed wood.max_sides")
        return self

    @property
    def branch_levels(self) -> list[BranchLevel]:
        """The branch levels present, level 1 first."""
        return [lv for lv in (self.level1, self.level2, self.level3) if lv is not None]
