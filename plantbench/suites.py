"""Suites: ``scenes/suites/*.toml`` describe cases x methods x capture settings (DESIGN.md section 8)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from pydantic import Field, ValidationError, model_validator

from plantbench.errors import InputError
from plantbench.paths import suites_dir
from plantbench.registry import Registry
from plantbench.schemas import Strict, load_toml, validation_message

__all__ = ["Suite", "CaseSet", "CaptureSettings", "Sweep", "suites", "load_suite", "apply_override"]


class CaseSet(Strict):
    """Plants of one species."""

    species: str = Field(description="species name (scenes/species/NAME.toml)")
    seeds: list[int] = Field(min_length=1, description="one plant per seed")
    scale: float = Field(default=1.0, gt=0, le=1.0, description="growth budget factor: < 1 grows smaller plants")


class CaptureSettings(Strict):
    views: int = Field(default=20, ge=1, le=200, description="number of views")
    width: int = Field(default=512, ge=16, le=4096)
    height: int = Field(default=512, ge=16, le=4096)
    spp: int = Field(default=16, ge=1, le=4096, description="samples per pixel of the path tracer")
    elevation: tuple[float, float] = Field(default=(5.0, 45.0), description="degrees above the horizon, low and high")
    scan: bool = Field(default=True, description="also simulate a terrestrial laser scan")
    stations: int = Field(default=1, ge=1, le=16, description="scanner stations on a circle")
    image_noise: int = Field(default=0, ge=0, le=16,
                             description="grey levels of uniform integer noise added to each image channel (0: none; "
                                         "the variability study uses 1)")
    image_noise_seed: int = Field(default=0, ge=0, description="which draw of the image noise (the study repeats it)")

    @model_validator(mode="after")
    def _elevation_order(self):
        lo, hi = self.elevation
        if not (-10.0 <= lo <= hi <= 89.0):
            raise ValueError(f"elevation must satisfy -10 <= low <= high <= 89, got {self.elevation}")
        return self


class Sweep(Strict):
    """Repeat the suite over values of one setting: ``parameter`` is a dotted path into the suite, e.g.
    ``"capture.views"`` or ``"method_options.mvs.noise"``."""

    parameter: str
    values: list[float | int | str] = Field(min_length=1)


class Suite(Strict):
    name: str
    description: str
    root_seed: int = Field(default=0, ge=0)
    cases: list[CaseSet] = Field(min_length=1)
    methods: list[str] = Field(min_length=1)
    capture: CaptureSettings = CaptureSettings()
    source: Literal["views", "scan"] = Field(
        default="views", description="what point-cloud methods reconstruct from: the mvs cloud of the views, or the scan"
    )
    method_options: dict[str, dict[str, Any]] = Field(
        default_factory=dict, description="per-method keyword options, e.g. [method_options.mvs] depth = 'oracle'"
    )
    timeout_s: float = Field(default=600.0, gt=0, description="per method call")
    sweep: Sweep | None = None


def apply_override(suite: Suite, parameter: str, value: Any) -> Suite:
    """A copy of ``suite`` with the dotted ``parameter`` set to ``value`` (validated again)."""
    data = suite.model_dump(mode="python")
    node = data
    *path, last = parameter.split(".")
    for key in path:
        node = node.setdefault(key, {})
        if not isinstance(node, dict):
            raise InputError(f"sweep parameter {parameter!r}: {key!r} is not a table")
    node[last] = value
    data["sweep"] = None
    try:
        return Suite.model_validate(data)
    except ValidationError as exc:
        raise InputError(f"sweep value {value!r} for {parameter}: {validation_message(exc)}") from None


def _discover(reg: Registry) -> None:
    folder = suites_dir()
    for path in sorted(folder.glob("*.toml")) if folder.is_dir() else []:
        reg.register(path.stem, path)


suites: Registry[Path] = Registry("suite", _discover)


def load_suite(name_or_path: str) -> Suite:
    """A suite by name, or by path to a TOML file."""
    path = Path(name_or_path)
    if not (path.suffix == ".toml" and path.exists()):
        path = suites.get(name_or_path)
    return load_toml(path, Suite)
