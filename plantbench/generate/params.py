"""Species parameters of the space-colonisation family: the pydantic model a ``scenes/species/*.toml`` validates against.

Groups:

- ``table1``: the five-parameter model of Guo et al. 2018 (Table 1): internode length l, roll angle phi, branching angle
  psi, diameter coefficient gamma (Eq. 5). The fifth, growth units rho (internodes per shoot per cycle), is not
  set: it emerges from Borchert-Honda allocation and is reported in plant.json (``parameters.derived``).
- ``reference``: the species' statistics in Guo et al. 2018, Table 2 (H, |B|, l_B), when the species is in that table.
- ``envelope``: the crown volume filled with markers (Weber-Penn shape ratio).
- ``growth``: Palubicki et al. 2009 self-organisation (perception cone, occupancy, apical control, tropism,
  shedding).
- ``roots``: number and placement of stems (Cercis is a multi-stem shrub).
- ``wood``: branch radii and tube tessellation.
- ``leaves``: arrangement, size, per-leaf variation and the 21 Bezier leaf parameters (Chaurasia and Beardsley 2017).

Every numeric field has bounds, so an out-of-range value is reported as ``file: field: Input should be ...``.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from plantbench.schemas import Strict

__all__ = [
    "SHAPES",
    "Table1",
    "Reference",
    "Envelope",
    "Growth",
    "Roots",
    "Wood",
    "LeafShape",
    "Leaves",
    "SpeciesBase",
    "SpaceColonisationSpecies",
]

SHAPES = ("conical", "spherical", "hemispherical", "cylindrical", "tapered_cylindrical", "flame", "inverse_conical",
          "tend_flame")
Shape = Literal["conical", "spherical", "hemispherical", "cylindrical", "tapered_cylindrical", "flame",
                "inverse_conical", "tend_flame"]


class Table1(Strict):
    """Guo et al. 2018, Table 1 (the growth units rho are derived, not set)."""

    internode_length: float = Field(ge=0.005, le=0.5, description="l, metres: length of one internode (metamer)")
    roll_angle: float = Field(ge=0, le=360, description="phi, degrees: roll of the lateral bud between successive nodes")
    branching_angle: float = Field(ge=5, le=90, description="psi, degrees: angle between a lateral bud and its parent")
    diameter_coefficient: float = Field(ge=0.2, le=1.0, description="gamma of Eq. 5: d_child = d_parent (l_c / sum l)^gamma")


class Reference(Strict):
    """Guo et al. 2018, Table 2: statistics of the reconstructed plant (what generated plants are compared with)."""

    figure: str = Field(default="", description="where the plant appears in Guo et al. 2018")
    height: float = Field(gt=0, le=100, description="H, metres")
    branches: int = Field(gt=0, le=10**6, description="|B|: unbranched chains between junctions or tips")
    mean_branch_length: float = Field(gt=0, le=100, description="l_B, metres")


class Envelope(Strict):
    """Crown envelope: a solid of revolution about the z axis, radius R(z) = radius * ShapeRatio(shape, r)."""

    height: float = Field(gt=0.05, le=60, description="top of the envelope, metres (scaled by scale^(1/3))")
    crown_base: float = Field(ge=0, le=0.95, description="bottom of the envelope as a fraction of its height")
    radius: float = Field(gt=0.02, le=40, description="largest crown radius, metres (scaled by scale^(1/3))")
    shape: Shape = Field(description="Weber-Penn shape of the radius profile")
    offset: float = Field(default=0.0, ge=0, le=1, description="radius of a ring of markers excluded near the z axis, "
                          "as a fraction of radius (hollow crowns of multi-stem shrubs)")
    marker_density: float = Field(gt=0, le=5, description="markers per cubic internode length")


class Growth(Strict):
    """Palubicki et al. 2009 space colonisation with Borchert-Honda allocation."""

    perception_angle: float = Field(default=90, ge=10, le=180, description="theta, degrees: full opening of the cone")
    perception_radius: float = Field(default=5, ge=2, le=20, description="r, internode lengths (paper: 4-6)")
    occupancy_radius: float = Field(default=2, ge=0.5, le=6, description="rho, internode lengths (paper: 2)")
    apical_control: float = Field(default=0.55, ge=0.05, le=0.95, description="lambda of Borchert-Honda allocation")
    vigour: float = Field(default=2.0, ge=0.5, le=10, description="alpha: resource at the base per bud with light")
    max_shoot: int = Field(default=4, ge=1, le=20, description="most metamers a bud grows in one cycle")
    direction_weight: float = Field(default=1.0, ge=0, le=5, description="xi: weight of the marker direction V")
    tropism: float = Field(default=0.1, ge=-2, le=2, description="eta: weight of +z (negative bends shoots down)")
    max_turn: float = Field(default=20, ge=1, le=180, description="largest heading change per internode, degrees")
    noise: float = Field(default=0.1, ge=0, le=1, description="random deflection of each new internode (radians)")
    bud_break: float = Field(default=0.2, ge=0.001, le=1, description="probability per cycle that a lit lateral bud with vigour breaks (else it stays dormant)")
    max_iterations: int = Field(default=40, ge=1, le=200, description="growth cycles")
    shed_age: int = Field(default=3, ge=1, le=50, description="cycles without light before a small branch is shed")
    shed_max_internodes: int = Field(default=4, ge=0, le=1000, description="largest branch (internodes) that is shed")


class Roots(Strict):
    """Stems starting at the ground."""

    count: int = Field(default=1, ge=1, le=32, description="number of stems (roots)")
    spread: float = Field(default=0.0, ge=0, le=5, description="radius of the circle the stems start on, metres")
    lean: float = Field(default=0.0, ge=0, le=60, description="outward lean of the stems, degrees")


class Wood(Strict):
    """Branch radii (Eq. 5 with supported length) and the generalised cylinders."""

    tip_radius: float = Field(default=0.001, gt=0.0001, le=0.05, description="radius of a one-internode twig, metres")
    max_sides: int = Field(default=12, ge=3, le=64, description="sides of the thickest tubes")
    min_sides: int = Field(default=4, ge=3, le=16, description="sides of the thinnest tubes")


class LeafShape(Strict):
    """The 21 Bezier leaf parameters (plantbench.geometry.leaf.BezierLeaf), unit leaf frame."""

    axis1_x: float = Field(default=1 / 3, ge=-0.5, le=1.5)
    axis1_y: float = Field(default=0.0, ge=-0.5, le=0.5)
    axis1_z: float = Field(default=0.0, ge=-0.5, le=0.5)
    axis2_x: float = Field(default=2 / 3, ge=-0.5, le=1.5)
    axis2_y: float = Field(default=0.0, ge=-0.5, le=0.5)
    axis2_z: float = Field(default=0.0, ge=-0.5, le=0.5)
    sil_v1: float = Field(default=0.15, ge=0, le=1)
    sil_v2: float = Field(default=0.45, ge=0, le=1)
    sil_v3: float = Field(default=0.85, ge=0, le=1)
    sil_x1: float = Field(default=0.25, ge=0, le=1.5)
    sil_x2: float = Field(default=0.35, ge=0, le=1.5)
    sil_x3: float = Field(default=0.15, ge=0, le=1.5)
    sil_z1: float = Field(default=0.0, ge=-0.5, le=0.5)
    sil_z2: float = Field(default=0.0, ge=-0.5, le=0.5)
    sil_z3: float = Field(default=0.0, ge=-0.5, le=0.5)
    f_z1: float = Field(default=0.0, ge=-0.5, le=0.5)
    f_z2: float = Field(default=0.0, ge=-0.5, le=0.5)
    f_z3: float = Field(default=0.0, ge=-0.5, le=0.5)
    g_z1: float = Field(default=0.0, ge=-0.5, le=0.5)
    g_z2: float = Field(default=0.0, ge=-0.5, le=0.5)
    g_z3: float = Field(default=0.0, ge=-0.5, le=0.5)


class Leaves(Strict):
    """Foliage: where leaves go, how big, how varied, and their Bezier shape."""

    arrangement: Literal["spiral", "opposite", "whorl"] = Field(description="phyllotaxis of the leaves on a twig")
    divergence: float = Field(default=137.5, ge=0, le=360, description="spiral: degrees between successive leaves")
    whorl_count: int = Field(default=3, ge=2, le=8, description="whorl: leaves per node")
    max_branch_radius: float = Field(default=0.004, gt=0, le=0.1, description="leaves on nodes thinner than this, metres")
    insertion_angle: float = Field(default=50, ge=5, le=90, description="petiole angle to the twig, degrees")
    droop: float = Field(default=0.5, ge=0, le=1, description="how far the blade turns from the petiole to horizontal")
    petiole_length: float = Field(default=0.01, ge=0, le=0.3, description="metres")
    petiole_radius: float = Field(default=0.0006, gt=0, le=0.01, description="metres")
    length: float = Field(gt=0.002, le=1.0, description="mean blade length, metres")
    length_sd: float = Field(default=0.15, ge=0, le=1, description="log-normal spread of blade length")
    width_sd: float = Field(default=0.08, ge=0, le=1, description="log-normal spread of blade width")
    shape_jitter: float = Field(default=0.03, ge=0, le=0.3, description="sd of the bend/fold/curl parameters")
    roll_sd: float = Field(default=15, ge=0, le=90, description="sd of the blade roll about its axis, degrees")
    random_phase: bool = Field(default=False, description="the phyllotaxis starts at a random azimuth, one per plant "
                               "(a single-stemmed plant whose leaves would otherwise stand at the same azimuths in "
                               "every seed: a pot stands at any angle to the cameras)")
    resolution: tuple[Annotated[int, Field(ge=1, le=32)], Annotated[int, Field(ge=2, le=64)]] = Field(default=(3, 6), description="tessellation (segments across each half, along)")
    shape: LeafShape = Field(default_factory=LeafShape,
                             description="mean Bezier leaf (Chaurasia and Beardsley 2017, 21 parameters)")


class SpeciesBase(Strict):
    """What every species file (one ``scenes/species/*.toml``) says about itself, whatever its family; a family's
    model adds its parameter groups and fixes ``family``."""

    name: str = Field(pattern=r"^[a-z][a-z0-9_]*$", description="the file stem")
    family: str = Field(description="the generator family (plantbench.generate.FAMILIES)")
    display_name: str = Field(min_length=1)
    description: str = ""
    habit: str = Field(default="", description="growth habit in words (upright, spreading, shrubby, excurrent, "
                       "weeping, palm ...)")


class SpaceColonisationSpecies(SpeciesBase):
    """A species of the ``space-colonisation`` family (one ``scenes/species/*.toml``)."""

    family: Literal["space-colonisation"] = "space-colonisation"
    reference: Reference | None = Field(default=None,
                                        description="row of Guo et al. 2018, Table 2, if the species has one")
    table1: Table1
    envelope: Envelope
    growth: Growth = Field(default_factory=Growth)
    roots: Roots = Field(default_factory=Roots)
    wood: Wood = Field(default_factory=Wood)
    leaves: Leaves
