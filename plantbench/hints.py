"""The species hint: the one piece of prior knowledge a method may receive (docs/design.md, Method API and isolation).

A hint is what a user of Guo et al. 2018 knows about a species before looking at the data: its Table 2 columns
(internode length l, roll angle phi, branching angle psi, diameter coefficient gamma; the growth units rho are
computed from the data), whether it grows several stems, the mean leaf length and the leaf arrangement, each with
its source. One published file per species under ``scenes/hints/``, separate from the generator's species files,
which no method reads. The runner copies the hint into a method's input folder as ``hint.json``.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Literal

from pydantic import Field

from plantbench.errors import InputError
from plantbench.io.atomic import write_json
from plantbench.paths import scenes_dir
from plantbench.registry import Registry
from plantbench.schemas import Strict, load_json, load_toml

__all__ = ["SpeciesHint", "hints", "load_hint", "read_hint", "write_hint", "HINT_FILE"]

HINT_FILE = "hint.json"


class SpeciesHint(Strict):
    """A published species hint (units metres and degrees)."""

    species: str = Field(description="species name, as in the suites")
    display_name: str
    habit: str = Field(description="growth habit in words")
    source: str = Field(description="where each value comes from")
    internode_length: float = Field(gt=0, description="l, metres")
    roll_angle: float = Field(ge=0, le=360, description="phi, degrees")
    branching_angle: float = Field(gt=0, lt=180, description="psi, degrees")
    diameter_coefficient: float = Field(gt=0, le=1, description="gamma of Eq. 5")
    multi_stem: bool = Field(description="several stems from the ground: a method counts them in the data")
    twig_radius: float = Field(gt=0, description="radius of the thinnest twig, metres")
    leaf_length: float = Field(gt=0, description="mean leaf blade length, metres")
    leaf_arrangement: Literal["spiral", "opposite", "whorl"]


def _discover(reg: Registry) -> None:
    folder = scenes_dir() / "hints"
    for path in sorted(folder.glob("*.toml")) if folder.is_dir() else []:
        reg.register(path.stem, path)


hints: Registry[Path] = Registry("species hint", _discover)


def load_hint(species: str) -> SpeciesHint:
    """The published hint of ``species`` (InputError with suggestions for an unknown name)."""
    path = hints.get(species)
    hint = load_toml(path, SpeciesHint)
    if hint.species != species:
        raise InputError(f"the hint file names species {hint.species!r}, not {species!r}", path=path)
    return hint


def write_hint(folder: str | os.PathLike, hint: SpeciesHint) -> Path:
    """Write ``hint`` as ``folder/hint.json`` (atomically); returns the path."""
    path = Path(folder) / HINT_FILE
    write_json(path, hint.model_dump(mode="json"))
    return path


def read_hint(folder: str | os.PathLike) -> SpeciesHint | None:
    """The hint of an input folder (``folder/hint.json``), or None when the run gave no hint."""
    path = Path(folder) / HINT_FILE
    return load_json(path, SpeciesHint) if path.exists() else None
