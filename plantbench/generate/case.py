"""Writing a case's ``plant/`` folder and comparing the species library with Guo et al. 2018, Table 2."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

import plantbench
from plantbench.errors import InputError
from plantbench.io.plantio import write_plant
from plantbench.plant import Plant
from plantbench.schemas import PlantCounts, PlantJson
from plantbench.seeding import rng as seeded_rng
from plantbench.skeletons import branch_chains, chain_lengths

__all__ = ["grow_species", "plant_json", "plant_glb", "generate_case", "species_stats"]

_BARK = [0.42, 0.30, 0.20, 1.0]
_LEAF = [0.22, 0.50, 0.16, 1.0]


def grow_species(species: str, seed: int, *, scale: float = 1.0) -> tuple[Plant, object]:
    """Grow ``species`` with the stream ``rng(seed, "generate", species)``; returns (plant, validated spec)."""
    from plantbench.generate.families import FAMILIES
    from plantbench.species import load_species

    if not (0.0 < float(scale) <= 1.0):
        raise InputError(f"scale must be in (0, 1], got {scale}", field="scale")
    if not isinstance(seed, int | np.integer) or seed < 0:
        raise InputError(f"seed must be a non-negative integer, got {seed!r}", field="seed")
    spec = load_species(species)
    plant = FAMILIES[spec.family].grow(spec, seeded_rng(int(seed), "generate", species), scale=float(scale))
    return plant, spec


def plant_json(plant: Plant, spec, seed: int, scale: float) -> PlantJson:
    """The plant.json record of a grown plant."""
    sk = plant.skeleton
    chains = branch_chains(sk)
    lengths = chain_lengths(sk, chains)
    crown = plant.leaf_mesh.vertices if len(plant.leaf_mesh.vertices) else plant.branch_mesh.vertices
    if len(crown) == 0:
        crown = sk.positions
    extent = np.concatenate([crown.min(0), crown.max(0)]) if len(crown) else np.zeros(6)
    params = spec.model_dump(mode="json")
    params["scale"] = float(scale)
    params["derived"] = dict(plant.meta.get("derived", {}))
    return PlantJson(
        species=spec.name,
        family=spec.family,
        seed=int(seed),
        parameters=params,
        counts=PlantCounts(
            nodes=len(sk),
            branches=len(chains),
            leaves=len(plant.leaves),
            roots=len(sk.roots),
            branch_triangles=len(plant.branch_mesh.faces),
            leaf_triangles=len(plant.leaf_mesh.faces),
        ),
        height=round(float(plant.height), 9),
        crown_extent=[round(float(x), 9) for x in extent],
        mean_branch_length=round(float(lengths.mean()) if len(lengths) else 0.0, 9),
        version=plantbench.__version__,
    )


def plant_glb(plant: Plant) -> bytes:
    """Branches and leaves as a binary glTF (two meshes, bark and leaf materials), byte-deterministic."""
    import trimesh
    from trimesh.visual.material import PBRMaterial

    scene = trimesh.Scene()
    for name, mesh, colour in (("branches", plant.branch_mesh, _BARK), ("leaves", plant.leaf_mesh, _LEAF)):
        if len(mesh.faces) == 0:
            continue
        tm = trimesh.Trimesh(mesh.vertices.astype(np.float32), mesh.faces, process=False)
        tm.visual = trimesh.visual.TextureVisuals(
            material=PBRMaterial(name=name, baseColorFactor=colour, metallicFactor=0.0, roughnessFactor=0.9,
                                 doubleSided=(name == "leaves"))
        )
        scene.add_geometry(tm, node_name=name, geom_name=name)
    return scene.export(file_type="glb")


def generate_case(species: str, seed: int, case_dir: str | os.PathLike, *, scale: float = 1.0) -> PlantJson:
    """Grow ``species`` and write ``case_dir/plant/`` atomically (plant.json, skeleton.ply, branches.ply,
    leaves.ply, leaves.json, plant.glb). Same species, seed and scale give byte-identical files."""
    plant, spec = grow_species(species, seed, scale=scale)
    meta = plant_json(plant, spec, seed, scale)
    Path(case_dir).mkdir(parents=True, exist_ok=True)
    write_plant(case_dir, plant, meta, glb=plant_glb(plant))
    return meta


def species_stats(names: list[str] | None = None, seeds=(0, 1, 2), *, scale: float = 1.0) -> list[dict]:
    """Per species: generated H (m), |B| and l_B (m), means over ``seeds``, beside Guo et al. 2018, Table 2 (None where
    the species is not in the table). Also the spread over seeds (``*_sd``) and the relative errors (``*_err``)."""
    from plantbench.species import load_species, species

    rows = []
    for name in names if names is not None else species.names():
        spec = load_species(name)
        hs, bs, lbs = [], [], []
        for seed in seeds:
            plant, _ = grow_species(name, int(seed), scale=scale)
            chains = branch_chains(plant.skeleton)
            lengths = chain_lengths(plant.skeleton, chains)
            hs.append(plant.height)
            bs.append(len(chains))
            lbs.append(float(lengths.mean()) if len(lengths) else 0.0)
        ref = getattr(spec, "reference", None)
        row = {
            "species": name,
            "H": float(np.mean(hs)), "B": float(np.mean(bs)), "l_B": float(np.mean(lbs)),
            "H_sd": float(np.std(hs)), "B_sd": float(np.std(bs)), "l_B_sd": float(np.std(lbs)),
            "H_paper": ref.height if ref else None,
            "B_paper": float(ref.branches) if ref else None,
            "l_B_paper": ref.mean_branch_length if ref else None,
        }
        for key in ("H", "B", "l_B"):
            paper = row[f"{key}_paper"]
            row[f"{key}_err"] = None if paper is None else (row[key] - paper) / paper
        rows.append(row)
    return rows
