"""The ground-truth oracle method: writes the case's ground truth in the method output format.

It is the upper-bound row of every table and the fixed point of the metrics (scoring it must give S_T = 1,
D = 0, reprojection error 0). Being an oracle, it reads ``plant/``, which no other method may.
"""

from __future__ import annotations

from pathlib import Path

from plantbench.io.plantio import read_plant, write_reconstruction
from plantbench.plant import TriMesh

__all__ = ["GroundTruth"]


class GroundTruth:
    name = "gt"
    inputs = "views"
    oracle = True

    def reconstruct(
        self, capture_dir: Path, out_dir: Path, *, seed: int, species: str | None = None, **options
    ) -> None:
        plant, _ = read_plant(capture_dir)
        mesh = TriMesh.concatenate([plant.branch_mesh, plant.leaf_mesh])
        write_reconstruction(out_dir, plant.skeleton, mesh=mesh, leaves=plant.leaves)
