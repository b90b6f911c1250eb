"""Pydantic models for every JSON/TOML file plantbench reads or writes (``extra="forbid"``).

Loading goes through :func:`load_json` / :func:`load_toml`, which turn a parse or validation failure into one
:class:`~plantbench.errors.InputError` naming the file and the field.
"""

from __future__ import annotations

import dataclasses
import json
import os
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Literal, TypeVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from plantbench.errors import InputError

__all__ = [
    "Strict",
    "PlantCounts",
    "PlantJson",
    "LeafEntry",
    "LeavesJson",
    "CameraModel",
    "CamerasJson",
    "ResultRow",
    "load_json",
    "load_toml",
    "validation_message",
    "params_from_options",
    "unknown_options",
    "jsonable",
]

M = TypeVar("M", bound=BaseModel)
P = TypeVar("P")


class Strict(BaseModel):
    """Base model: unknown fields are an error, instances are immutable."""

    model_config = ConfigDict(extra="forbid", frozen=True)


# ------------------------------------------------------------------------------------------------ plant folder


class PlantCounts(Strict):
    nodes: int = Field(ge=0, description="skeleton nodes")
    branches: int = Field(ge=0, description="unbranched chains between junctions or tips")
    leaves: int = Field(ge=0, description="leaf instances")
    roots: int = Field(ge=0, description="root (stem) count")
    branch_triangles: int = Field(ge=0)
    leaf_triangles: int = Field(ge=0)


class PlantJson(Strict):
    """plant/plant.json"""

    format: Literal["plantbench.plant/1"] = "plantbench.plant/1"
    species: str
    family: str = Field(description="generator family, e.g. 'space-colonisation' or 'weber-penn'")
    seed: int
    parameters: dict[str, Any] = Field(description="the species parameters the plant was grown with")
    counts: PlantCounts
    height: float = Field(ge=0, description="metres, top of the highest surface")
    crown_extent: list[float] = Field(description="[x_min, y_min, z_min, x_max, y_max, z_max] of the crown (leaves)")
    mean_branch_length: float = Field(ge=0, description="l_B, metres")
    version: str = Field(description="plantbench version that wrote the file")


class LeafEntry(Strict):
    id: int = Field(ge=0)
    node: int = Field(ge=-1, description="skeleton node of the petiole, -1 when unknown")
    transform: list[list[float]] = Field(description="4x4 leaf-to-world matrix, row major")
    params: dict[str, Any] = Field(description="Bezier leaf parameters")
    length: float = Field(gt=0)
    width: float = Field(gt=0)


class LeavesJson(Strict):
    """plant/leaves.json and a method's optional leaves.json"""

    format: Literal["plantbench.leaves/1"] = "plantbench.leaves/1"
    leaves: list[LeafEntry]


# ----------------------------------------------------------------------------------------------------- cameras


class CameraModel(Strict):
    """One view, OpenCV pinhole: x_pix = K (R X + t), pixel (u, v)'s centre at integer (u, v)."""

    id: int = Field(ge=0)
    image: str = Field(description="file name under views/images")
    width: int = Field(gt=0)
    height: int = Field(gt=0)
    K: list[list[float]] = Field(description="3x3 intrinsics")
    R: list[list[float]] = Field(description="3x3 world-to-camera rotation")
    t: list[float] = Field(description="world-to-camera translation (3,)")


class CamerasJson(Strict):
    """views/cameras.json"""

    format: Literal["plantbench.cameras/1"] = "plantbench.cameras/1"
    convention: Literal["opencv"] = "opencv"
    cameras: list[CameraModel]


# ----------------------------------------------------------------------------------------------------- results


class ResultRow(Strict):
    """One row of a run's tidy results table."""

    case: str
    species: str
    family: str
    seed: int
    method: str
    metric: str
    value: float | None
    status: Literal["ok", "failed", "timeout", "invalid", "skipped"]


# ----------------------------------------------------------------------------------------------------- loading


def validation_message(exc: ValidationError) -> str:
    """First error of a pydantic ValidationError as 'field.path: message'."""
    err = exc.errors()[0]
    loc = ".".join(str(x) for x in err["loc"]) or "(top level)"
    msg = err["msg"]
    if err["type"] == "extra_forbidden":
        msg = "unknown field"
    return f"{loc}: {msg}" + (f" (got {err['input']!r})" if err["type"] != "missing" and "input" in err and not isinstance(err["input"], dict | list) else "")


def _validate(model: type[M], data: Any, path: os.PathLike | str) -> M:
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise InputError(validation_message(exc), path=path) from None


def load_json(path: str | os.PathLike, model: type[M]) -> M:
    path = Path(path)
    if not path.is_file():
        raise InputError("file not found", path=path)
    try:
        data = json.loads(path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"malformed JSON ({exc})", path=path) from None
    return _validate(model, data, path)


def read_toml(path: str | os.PathLike) -> dict[str, Any]:
    path = Path(path)
    if not path.is_file():
        raise InputError("file not found", path=path)
    try:
        return tomllib.loads(path.read_text())
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise InputError(f"malformed TOML ({exc})", path=path) from None


def load_toml(path: str | os.PathLike, model: type[M]) -> M:
    return _validate(model, read_toml(path), path)


# ---------------------------------------------------------------------------------- method options and statistics


def unknown_options(names: Sequence[str], valid: Sequence[str]) -> str:
    """'unknown option 'x' (did you mean 'y'?); valid: ...' for the option names ``names`` not among ``valid``."""
    import difflib

    parts = []
    for name in names:
        close = difflib.get_close_matches(name, list(valid), n=2, cutoff=0.6)
        parts.append(repr(name) + (f" (did you mean {' or '.join(map(repr, close))}?)" if close else ""))
    return f"unknown option{'s' if len(names) > 1 else ''} {', '.join(parts)}; valid: {', '.join(valid)}"


def params_from_options(cls: type[P], options: Mapping[str, Any], *, method: str | None = None,
                        also: Sequence[str] = ()) -> P:
    """``cls(**options)`` for a method's frozen parameter dataclass, from a suite's ``[method_options.NAME]``.

    Unknown names raise InputError listing the valid ones (the fields, then ``also``: the options the method reads
    itself); a list becomes a tuple where the field's default is one (TOML has no tuples); a TypeError of ``cls``
    becomes an InputError. ``method`` prefixes the messages (``"guo: unknown option(s) ..."``).
    """
    prefix = f"{method}: " if method else ""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    bad = sorted(set(options) - set(fields))
    if bad:
        raise InputError(prefix + unknown_options(bad, [*sorted(fields), *also]))
    values = {k: tuple(v) if isinstance(v, list) and isinstance(fields[k].default, tuple) else v
              for k, v in options.items()}
    try:
        return cls(**values)
    except TypeError as exc:
        raise InputError(f"{prefix}{exc}") from None


def jsonable(obj: Any, *, digits: int | None = None) -> Any:
    """``obj`` as plain JSON values, recursively: dict keys become strings, tuples lists and numpy scalars Python
    numbers; with ``digits``, Python floats (not numpy's) are rounded to that many decimals."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v, digits=digits) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [jsonable(v, digits=digits) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    if digits is not None and isinstance(obj, float):
        return round(obj, digits)
    return obj
