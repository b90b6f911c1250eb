"""The species library: ``scenes/species/*.toml``, one file per species, parameters only.

The file stem is the species name. A file's ``family`` field picks the generator that grows it and the pydantic
model that validates it (:data:`plantbench.generate.FAMILIES`); invalid values are reported with the file, the
field and the allowed range.
"""

from __future__ import annotations

from pathlib import Path

from plantbench.errors import InputError
from plantbench.paths import species_dir
from plantbench.registry import Registry
from plantbench.schemas import _validate, read_toml

__all__ = ["species", "load_species", "DEFAULT_FAMILY"]

DEFAULT_FAMILY = "space-colonisation"


def _discover(reg: Registry) -> None:
    folder = species_dir()
    for path in sorted(folder.glob("*.toml")) if folder.is_dir() else []:
        reg.register(path.stem, path)


species: Registry[Path] = Registry("species", _discover)


def load_species(name: str):
    """Validated species parameters (the family's pydantic model) for ``name``."""
    from plantbench.generate.families import FAMILIES

    path = species.get(name)
    data = read_toml(path)
    family = data.get("family", DEFAULT_FAMILY)
    if family not in FAMILIES:
        raise InputError(f"unknown family {family!r} (known: {', '.join(sorted(FAMILIES))})", path=path, field="family")
    spec = _validate(FAMILIES[family].params_model, data, path)
    if getattr(spec, "name", name) != name:
        raise InputError(f"name {spec.name!r} differs from the file name {name!r}", path=path, field="name")
    return spec
