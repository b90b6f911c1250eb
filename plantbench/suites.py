"""Suites: ``scenes/suites/*.toml`` describe cases x methods x capture settings (docs/design.md, Runner and cache)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from pydantic import Field, ValidationError, ValidationInfo, field_validator, model_serializer, model_validator

from plantbench.errors import InputError
from plantbench.paths import suites_dir
from plantbench.registry import Registry
from plantbench.schemas import Strict, read_toml, validation_message

__all__ = ["Suite", "CaseSet", "CaptureSettings", "Sweep", "suites", "load_suite", "check_method_options",
           "apply_override"]


REFERENCE_TOOLS = ("treeqsm", "simpleforest", "archi")
"""The QSM tools whose cylinder tables a real case may name as references (:mod:`plantbench.io.references`)."""


class CaseSet(Strict):
    """Plants of one species (``species`` and ``seeds``), one case folder (``path``: a real capture as
    ``plantbench import scan`` / ``import views`` makes it, or any folder with scan/ and/or views/), or one scan file
    (``scan``: imported when the suite runs, as ``plantbench import scan`` does, with ``units`` and ``up``), whose
    ``species``, if given, is the species hint the methods receive (none without it). A path that starts with
    ``data:`` is relative to the data folder (:func:`plantbench.paths.data_dir`, ``PLANTBENCH_DATA``), any other
    relative path to the suite file's folder. A scan case may name reference cylinder models of the same cloud
    (``references``: tool -> table, in the scan file's frame), which the report holds the methods' traits to."""

    species: str | None = Field(default=None, description="species name (scenes/species/NAME.toml); beside "
                                                          "``path``: the species hint (scenes/hints/NAME.toml)")
    seeds: list[int] | None = Field(default=None, min_length=1, description="one plant per seed")
    scale: float = Field(default=1.0, gt=0, le=1.0, description="growth budget factor: < 1 grows smaller plants")
    path: str | None = Field(default=None, description="a case folder (relative to the suite file's folder); "
                                                       "stored resolved, absolute")
    scan: str | None = Field(default=None, description="a scan file (.xyz[.gz] .txt .csv .ply .las .laz .pcd), "
                                                       "imported when the suite runs; stored resolved, absolute")
    units: Literal["m", "cm", "mm"] = Field(default="m", description="units of the scan file's coordinates")
    up: Literal["z", "-z", "y", "-y", "x", "-x"] = Field(default="z", description="the scan file's up axis")
    references: dict[str, str] = Field(
        default_factory=dict, description="reference QSM cylinder tables of the scan's cloud: tool (treeqsm, "
                                          "simpleforest, archi) -> file, in the scan file's frame")

    @field_validator("path", "scan")
    @classmethod
    def _resolve(cls, value: str | None, info: ValidationInfo) -> str | None:
        from plantbench.paths import resolve_data_path

        return None if value is None else str(resolve_data_path(value, (info.context or {}).get("base", ".")))

    @field_validator("references")
    @classmethod
    def _resolve_references(cls, value: dict[str, str], info: ValidationInfo) -> dict[str, str]:
        from plantbench.paths import resolve_data_path

        for tool in value:
            if tool not in REFERENCE_TOOLS:
                raise ValueError(f"unknown reference tool {tool!r} (one of {', '.join(REFERENCE_TOOLS)})")
        out = {t: str(resolve_data_path(v, (info.context or {}).get("base", "."))) for t, v in value.items()}
        for tool, file in out.items():
            if not Path(file).is_file():
                raise ValueError(f"reference {tool} file {file} not found")
        return out

    @model_validator(mode="after")
    def _one_source(self):
        if self.scan is not None:
            if self.path is not None or self.seeds is not None or self.scale != 1.0:
                raise ValueError(f"a scan case ({self.scan}) takes no path, seeds or scale")
            if not Path(self.scan).is_file():
                raise ValueError(f"scan file {self.scan} not found (a data: path is under the data folder, "
                                 "PLANTBENCH_DATA)")
            self._check_hint(self.scan)
            return self
        if self.references or self.units != "m" or self.up != "z":
            raise ValueError("units, up and references belong to a scan case (scan = FILE)")
        if self.path is None:
            if self.species is None or self.seeds is None:
                raise ValueError("a case gives species and seeds (generated plants), path (a case folder) or scan "
                                 "(a scan file)")
            return self
        if self.seeds is not None:
            raise ValueError(f"give species and seeds (generated plants) or path (a case folder, with species as "
                             f"its optional hint), not seeds and path ({self.path})")
        if self.scale != 1.0:
            raise ValueError(f"scale grows generated plants; it does not apply to a case folder ({self.path})")
        folder = Path(self.path)
        if not folder.is_dir():
            raise ValueError(f"case folder {self.path} not found")
        if not ((folder / "scan" / "scan.ply").is_file() or (folder / "views" / "cameras.json").is_file()):
            raise ValueError(f"case folder {self.path} holds neither scan/scan.ply nor views/cameras.json")
        self._check_hint(self.path)
        return self

    def _check_hint(self, where: str) -> None:
        if self.species is not None:
            from plantbench.hints import load_hint

            try:
                load_hint(self.species)
            except InputError as exc:
                raise ValueError(f"species hint of case {where}: {exc}") from None

    @model_serializer(mode="wrap")
    def _without_absent(self, handler):
        """The fields given, as before case folders existed: a generated case dumps as {species, seeds, scale}, so
        that config hashes and packed datasets' suite configs stay what they were."""
        defaults = {"species": None, "seeds": None, "path": None, "scan": None, "units": "m", "up": "z",
                    "references": {}}
        return {k: v for k, v in handler(self).items() if not (k in defaults and v == defaults[k])}

    @property
    def count(self) -> int:
        """Number of cases: one per seed, or the one folder or scan file."""
        return 1 if self.path is not None or self.scan is not None else len(self.seeds or ())


class CaptureSettings(Strict):
    views: int = Field(default=20, ge=1, le=200, description="number of views")
    width: int = Field(default=512, ge=16, le=4096, description="image width, pixels")
    height: int = Field(default=512, ge=16, le=4096, description="image height, pixels")
    spp: int = Field(default=16, ge=1, le=4096, description="samples per pixel of the path tracer")
    denoise: bool = Field(default=False, description="denoise the colour renders with Intel Open Image Denoise "
                                                     "(albedo and normal guides rendered beside the colour)")
    elevation: tuple[float, float] = Field(default=(5.0, 45.0), description="degrees above the horizon, low and high")
    scan: bool = Field(default=True, description="also simulate a terrestrial laser scan")
    stations: int = Field(default=1, ge=1, le=16, description="scanner stations on a circle")
    scan_spacing: float | None = Field(
        default=None, gt=0.0, le=1.0,
        description="scanner beam spacing at the plant's axis, metres: sets the angular step to spacing / station "
                    "distance (None: the scanner's angular_step_deg, 0.05 deg)")
    registration_error: float = Field(
        default=0.0, ge=0.0, le=1.0,
        description="RMS displacement, metres, of each station's points after the first by a random rigid "
                    "misregistration (half of the variance a rotation about the plant's centre, half a translation)")
    range_noise_per_m: float = Field(
        default=0.0, ge=0.0, le=0.1,
        description="range noise sigma growing with range: sigma(r) = range_noise + range_noise_per_m * r")
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
    ``"capture.views"`` or ``"method_options.mvs.noise"``. ``linked`` settings follow it, one value per sweep value
    (e.g. a scanner's registration error growing with its beam spacing); the swept value names the level."""

    parameter: str
    values: list[float | int | str] = Field(min_length=1)
    linked: dict[str, list[float | int | str]] = Field(
        default_factory=dict, description="dotted setting -> its value at each sweep value (same length as values)")
    labels: list[str] | None = Field(
        default=None, description="a name per level (same length as values; default: the values), for sweeps whose "
                                  "levels share a value of the swept parameter and differ in a linked one")

    @model_validator(mode="after")
    def _linked_lengths(self):
        for name, vals in self.linked.items():
            if len(vals) != len(self.values):
                raise ValueError(f"sweep.linked {name!r} has {len(vals)} values for {len(self.values)} sweep values")
            if name == self.parameter:
                raise ValueError(f"sweep.linked {name!r} is the swept parameter itself")
        names = self.labels if self.labels is not None else [str(v) for v in self.values]
        if len(names) != len(self.values):
            raise ValueError(f"sweep.labels has {len(names)} labels for {len(self.values)} sweep values")
        if len(set(names)) != len(names):
            raise ValueError("sweep levels must have distinct names (give sweep.labels where values repeat)")
        return self

    def levels(self) -> list[tuple[Any, dict[str, Any]]]:
        """(level name: the label, or the sweep value, {dotted setting: value}) per level, the swept parameter
        first."""
        names = self.labels if self.labels is not None else self.values
        return [(names[i], {self.parameter: v, **{k: vals[i] for k, vals in self.linked.items()}})
                for i, v in enumerate(self.values)]


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


def apply_override(suite: Suite, settings: dict[str, Any]) -> Suite:
    """A copy of ``suite`` with each dotted setting of ``settings`` (e.g. ``{"capture.views": 3}``; a sweep level
    with its linked settings) set to its value, validated again."""
    data = suite.model_dump(mode="python")
    for name, val in settings.items():
        node = data
        *path, last = name.split(".")
        for key in path:
            node = node.setdefault(key, {})
            if not isinstance(node, dict):
                raise InputError(f"setting {name!r}: {key!r} is not a table")
        node[last] = val
    data["sweep"] = None
    try:
        return Suite.model_validate(data)
    except ValidationError as exc:
        what = ", ".join(f"{k} = {v!r}" for k, v in settings.items())
        raise InputError(f"{what}: {validation_message(exc)}") from None


def _discover(reg: Registry) -> None:
    folder = suites_dir()
    for path in sorted(folder.glob("*.toml")) if folder.is_dir() else []:
        reg.register(path.stem, path)


suites: Registry[Path] = Registry("suite", _discover)


def load_suite(name_or_path: str) -> Suite:
    """A suite by name, or by path to a TOML file (a case's ``path`` is relative to the file's folder). Its
    ``[method_options.NAME]`` tables are checked here (:func:`check_method_options`), before anything runs."""
    path = Path(name_or_path)
    if not (path.suffix == ".toml" and path.exists()):
        path = suites.get(name_or_path)
    try:
        suite = Suite.model_validate(read_toml(path), context={"base": str(Path(path).resolve().parent)})
    except ValidationError as exc:
        raise InputError(validation_message(exc), path=path) from None
    check_method_options(suite, path=path)
    return suite


def check_method_options(suite: Suite, *, path: object = None) -> None:
    """Every ``[method_options.NAME]`` names a known method, and the method accepts its options: InputError naming
    ``path`` (the suite file), the table and the option, with a did-you-mean, otherwise. A method checks its options
    when it has ``check_options(options)`` (every shipped method does); the others see them only when they run."""
    from plantbench.methods.api import method_from_spec

    for name, options in suite.method_options.items():
        try:
            method = method_from_spec(name)
            check = getattr(method, "check_options", None)
            if check is not None:
                check(dict(options))
        except InputError as exc:
            raise InputError(str(exc), path=path, field=f"[method_options.{name}]") from None
