"""Where the project's data lives. ``PLANTBENCH_SCENES`` overrides the scenes folder, ``PLANTBENCH_DATA`` the
data folder (real scans that are not the project's: :func:`data_dir`)."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["project_root", "scenes_dir", "species_dir", "suites_dir", "cache_dir", "data_dir", "DATA_PREFIX",
           "resolve_data_path"]

DATA_PREFIX = "data:"
"""A suite path that starts with it is relative to :func:`data_dir` (``data:real/adtree/tree1.xyz.gz``)."""


def project_root() -> Path:
    return Path(__file__).resolve().parent.parent


def scenes_dir() -> Path:
    return Path(os.environ.get("PLANTBENCH_SCENES", project_root() / "scenes"))


def species_dir() -> Path:
    return scenes_dir() / "species"


def suites_dir() -> Path:
    return scenes_dir() / "suites"


def cache_dir() -> Path:
    """User cache (probe results); ``PLANTBENCH_CACHE`` or ``$XDG_CACHE_HOME/plantbench``."""
    base = os.environ.get("PLANTBENCH_CACHE") or Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "plantbench"
    return Path(base)


def data_dir() -> Path:
    """The folder of data that is read in place, never copied into the repository (real tree scans and their
    reference models): ``PLANTBENCH_DATA``, or ``../shared/data`` beside the project (where a development checkout
    finds it). The one setting that names it."""
    return Path(os.environ.get("PLANTBENCH_DATA") or project_root().parent / "shared" / "data")


def resolve_data_path(value: str, base: str | os.PathLike = ".") -> Path:
    """``value`` as an absolute path: ``data:REL`` under :func:`data_dir`, a relative path under ``base``."""
    if value.startswith(DATA_PREFIX):
        return (data_dir() / value[len(DATA_PREFIX):]).resolve()
    path = Path(value).expanduser()
    return (path if path.is_absolute() else Path(base) / path).resolve()
