"""Ground truth: procedural Xfrog-like plants with exact skeletons, branch surfaces and Bezier leaves.

:data:`FAMILIES` maps a species file's ``family`` to its parameter model and growth function. Geometry shared by
every family lives in :mod:`plantbench.geometry` (:mod:`~plantbench.geometry.tubes` generalised cylinders and
radii, :mod:`~plantbench.geometry.leaf` the Bezier leaf) and in :mod:`.foliage` (leaf placement).
:mod:`.space_colonisation` grows the species files with ``family = "space-colonisation"`` (markers in a crown
envelope, Palubicki et al. 2009's growth in :mod:`.palubicki`), :mod:`.weber_penn` those with
``family = "weber-penn"`` (Weber and Penn 1995 recursive stems).
"""

from __future__ import annotations

from plantbench.generate.families import FAMILIES, Family

__all__ = ["Family", "FAMILIES", "generate_case", "grow_species", "species_stats", "plant_glb"]


def __getattr__(name: str):  # lazy: case.py imports trimesh only when used
    if name in ("generate_case", "grow_species", "species_stats", "plant_glb"):
        from plantbench.generate import case

        return getattr(case, name)
    raise AttributeError(name)

