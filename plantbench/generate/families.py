"""The generator families: :data:`FAMILIES` maps a species file's ``family`` to its parameter model and growth
function. It imports the growth modules only, never the species loader (which imports it)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import plantbench.generate.space_colonisation as _sc
import plantbench.generate.weber_penn as _wp
from plantbench.generate.params import SpaceColonisationSpecies
from plantbench.generate.params_wp import WeberPennSpecies
from plantbench.plant import Plant
from plantbench.schemas import Strict

__all__ = ["Family", "FAMILIES"]


@dataclass(frozen=True)
class Family:
    """A generator family: the model that validates its species files and the function that grows a plant."""

    name: str
    params_model: type[Strict]
    grow: Callable[..., Plant]
    """``grow(spec, rng, *, scale=1.0) -> Plant``"""


FAMILIES: dict[str, Family] = {
    "space-colonisation": Family("space-colonisation", SpaceColonisationSpecies, _sc.grow),
    "weber-penn": Family("weber-penn", WeberPennSpecies, _wp.grow),
}
