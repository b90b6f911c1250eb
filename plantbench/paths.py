"""Where the project's data lives. ``PLANTBENCH_SCENES`` overrides the scenes folder."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["project_root", "scenes_dir", "species_dir", "suites_dir", "cache_dir"]


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
