"""The ``plant/`` folder of a case (docs/design.md, On-disk contracts): write atomically, read with validation.

A method's output folder uses the same skeleton/mesh/leaves files (``skeleton.ply``, ``mesh.ply``,
``leaves.json``, ``points.ply``); :func:`read_reconstruction` reads it into a :class:`Reconstruction`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from plantbench.errors import InputError
from plantbench.io.atomic import atomic_dir, write_json
from plantbench.io.ply import read_mesh, read_points, read_skeleton, write_mesh, write_skeleton
from plantbench.plant import Leaf, Plant, Skeleton, TriMesh
from plantbench.schemas import LeafEntry, LeavesJson, PlantJson, load_json

__all__ = [
    "PLANT_FILES",
    "write_plant",
    "read_plant",
    "leaves_to_json",
    "leaves_from_json",
    "Reconstruction",
    "read_reconstruction",
    "write_reconstruction",
]

PLANT_FILES = ("plant.json", "skeleton.ply", "branches.ply", "leaves.ply", "leaves.json")


def leaves_to_json(leaves: list[Leaf]) -> dict:
    entries = [
        LeafEntry(
            id=leaf.id,
            node=leaf.node,
            transform=np.asarray(leaf.transform, float).tolist(),
            params=leaf.params,
            length=leaf.length,
            width=leaf.width,
        )
        for leaf in leaves
    ]
    return LeavesJson(leaves=entries).model_dump(mode="json")


def leaves_from_json(doc: LeavesJson) -> list[Leaf]:
    return [
        Leaf(e.id, e.node, np.asarray(e.transform, float).reshape(4, 4), dict(e.params), e.length, e.width)
        for e in doc.leaves
    ]


def write_plant(case_dir: str | os.PathLike, plant: Plant, plant_json: PlantJson, glb: bytes | None = None) -> Path:
    """Write ``case_dir/plant/`` (all files, or none: the folder is swapped in atomically)."""
    target = Path(case_dir) / "plant"
    with atomic_dir(target) as tmp:
        write_json(tmp / "plant.json", plant_json.model_dump(mode="json"))
        write_skeleton(tmp / "skeleton.ply", plant.skeleton)
        write_mesh(tmp / "branches.ply", plant.branch_mesh)
        write_mesh(tmp / "leaves.ply", plant.leaf_mesh, face_fields={"leaf_id": plant.leaf_mesh_ids.astype(np.int32)})
        write_json(tmp / "leaves.json", leaves_to_json(plant.leaves), compact=True)
        if glb is not None:
            (tmp / "plant.glb").write_bytes(glb)
    return target


def read_plant(case_dir: str | os.PathLike) -> tuple[Plant, PlantJson]:
    """Read ``case_dir/plant/``; a missing or corrupt file raises InputError naming it."""
    folder = Path(case_dir) / "plant"
    if not folder.is_dir():
        raise InputError("no plant/ folder (generate the case first)", path=Path(case_dir))
    meta = load_json(folder / "plant.json", PlantJson)
    skeleton = read_skeleton(folder / "skeleton.ply")
    branches, _ = read_mesh(folder / "branches.ply")
    leaf_mesh, fields = read_mesh(folder / "leaves.ply")
    if "leaf_id" not in fields:
        raise InputError("faces have no leaf_id property", path=folder / "leaves.ply")
    leaves = leaves_from_json(load_json(folder / "leaves.json", LeavesJson))
    plant = Plant(skeleton, branches, leaf_mesh, fields["leaf_id"].astype(np.int64), leaves, meta.model_dump())
    return plant, meta


@dataclass(frozen=True)
class Reconstruction:
    """A method's output folder. Parts are None when the file is absent.

    A full reconstruction has at least skeleton.ply; a point stage such as ``mvs`` writes only points.ply.
    """

    skeleton: Skeleton | None
    mesh: TriMesh | None
    leaves: list[Leaf] | None
    points: np.ndarray | None


def read_reconstruction(out_dir: str | os.PathLike) -> Reconstruction:
    out = Path(out_dir)
    if not out.is_dir():
        raise InputError("reconstruction folder not found", path=out)
    if not (out / "skeleton.ply").exists() and not (out / "points.ply").exists():
        raise InputError("neither skeleton.ply nor points.ply: not a method output", path=out)
    skeleton = read_skeleton(out / "skeleton.ply") if (out / "skeleton.ply").exists() else None
    mesh = read_mesh(out / "mesh.ply")[0] if (out / "mesh.ply").exists() else None
    leaves = leaves_from_json(load_json(out / "leaves.json", LeavesJson)) if (out / "leaves.json").exists() else None
    points = read_points(out / "points.ply")[0] if (out / "points.ply").exists() else None
    return Reconstruction(skeleton, mesh, leaves, points)


def write_reconstruction(
    out_dir: str | os.PathLike,
    skeleton: Skeleton | None,
    mesh: TriMesh | None = None,
    leaves: list[Leaf] | None = None,
    points: np.ndarray | None = None,
    point_fields: dict[str, np.ndarray] | None = None,
) -> None:
    """Write a method's output files into ``out_dir`` (each file atomically)."""
    from plantbench.io.ply import write_points

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if skeleton is not None:
        write_skeleton(out / "skeleton.ply", skeleton)
    if mesh is not None:
        write_mesh(out / "mesh.ply", mesh)
    if leaves is not None:
        write_json(out / "leaves.json", leaves_to_json(leaves), compact=True)
    if points is not None:
        write_points(out / "points.ply", points, point_fields)
