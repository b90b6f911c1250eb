"""A frozen dataset's manifest: what the runner needs of a dataset (reading and verifying the manifest, hashing
files), below the runner; packing a dataset, which runs a suite, is :mod:`plantbench.dataset`, above it.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

from pydantic import Field

from plantbench.errors import InputError
from plantbench.schemas import Strict, load_json

__all__ = ["DatasetCase", "Manifest", "verify_dataset", "open_dataset", "file_sha256", "manifest_sha256",
           "DATASET_FORMAT", "LICENCE", "CASE_PARTS", "case_files"]

DATASET_FORMAT = "plantbench.dataset/1"
LICENCE = "CC-BY-4.0"
CASE_PARTS = ("plant", "views", "scan")


class DatasetCase(Strict):
    id: str = Field(description="case id as in results tables: species-seed")
    species: str
    family: str
    seed: int
    capture_key: str = Field(description="the capture job's cache key when it was packed (provenance)")


class Manifest(Strict):
    format: str = DATASET_FORMAT
    suite: str
    suite_config: dict = Field(description="the suite as packed (model_dump of plantbench.suites.Suite)")
    plantbench_version: str
    git_sha: str | None
    code: dict[str, str] = Field(description="code hashes of the stages that made the data: generator, capture")
    llvm_target: str
    mitsuba_variant: str
    created: str
    licence: str = LICENCE
    cases: list[DatasetCase]
    files: dict[str, str] = Field(description="path relative to the dataset folder -> sha256 hex digest")
    bytes: int = Field(ge=0, description="total size of the files")


def file_sha256(path: Path, chunk: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while block := fh.read(chunk):
            h.update(block)
    return h.hexdigest()


def manifest_sha256(folder: str | os.PathLike) -> str:
    """sha256 of a dataset's manifest.json bytes: the identity of the dataset recorded with every table made from it."""
    return file_sha256(Path(folder) / "manifest.json")


def case_files(folder: Path) -> list[Path]:
    return sorted(p for p in (folder / "cases").rglob("*") if p.is_file() or p.is_symlink())


def verify_dataset(folder: str | os.PathLike) -> Manifest:
    """The dataset's manifest, after checking every file: present, unchanged (sha256) and listed.

    Raises :class:`InputError` naming the first file that is missing, altered or not in the manifest."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("no such dataset folder", path=folder)
    manifest = load_json(folder / "manifest.json", Manifest)
    if manifest.format != DATASET_FORMAT:
        raise InputError(f"format {manifest.format!r} is not {DATASET_FORMAT!r}", path=folder / "manifest.json")
    for rel, digest in sorted(manifest.files.items()):
        path = folder / rel
        if not path.is_file():
            raise InputError("missing: listed in manifest.json, not in the dataset", path=path)
        if file_sha256(path) != digest:
            raise InputError("corrupted: its sha256 differs from manifest.json", path=path)
    listed = set(manifest.files)
    for path in case_files(folder):
        if path.is_symlink() or str(path.relative_to(folder)) not in listed:
            raise InputError("not in manifest.json (added after packing?)", path=path)
    return manifest


def open_dataset(folder: str | os.PathLike, suite) -> tuple[Path, Manifest]:
    """(folder, manifest) of a dataset verified file by file (:func:`verify_dataset`) that holds ``suite`` as it is
    now: same name, cases, capture settings and root seed (the captures are frozen), else :class:`InputError`."""
    manifest = verify_dataset(folder)
    where = Path(folder) / "manifest.json"
    if manifest.suite != suite.name:
        raise InputError(f"the dataset holds suite {manifest.suite!r}, not {suite.name!r}", path=where)
    now = suite.model_dump(mode="json")
    for part in ("capture", "cases", "root_seed"):
        if manifest.suite_config.get(part) != now.get(part):
            raise InputError(f"the suite's {part} differ from the dataset's (the captures are frozen: run the suite "
                             "as packed, or pack it again)", path=where)
    return Path(folder), manifest
