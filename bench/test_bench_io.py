"""Mesh PLY reading: plantbench.io.ply.read_mesh (validation, range checks, float64 copies) beside bare plyfile's
fixed-length fast path on the same 500k-triangle file."""

import numpy as np
import pytest
from plyfile import PlyData

from plantbench.io.ply import read_mesh, write_mesh
from plantbench.plant import TriMesh


@pytest.fixture(scope="module")
def mesh_file(tmp_path_factory):
    rng = np.random.Generator(np.random.PCG64(0))
    n = 500_000
    path = tmp_path_factory.mktemp("ply") / "mesh.ply"
    write_mesh(path, TriMesh(rng.random((n, 3)), rng.integers(0, n, (n, 3))), face_fields={"leaf_id": np.arange(n)})
    return path


@pytest.mark.benchmark(group="read-mesh-500k")
def test_bare_plyfile(benchmark, mesh_file):
    def bare():
        ply = PlyData.read(str(mesh_file), known_list_len={"face": {"vertex_indices": 3}})
        return np.stack([ply["vertex"][k] for k in "xyz"], 1), np.array(ply["face"]["vertex_indices"])

    benchmark(bare)


@pytest.mark.benchmark(group="read-mesh-500k")
def test_plantbench_read_mesh(benchmark, mesh_file):
    mesh, fields = benchmark(read_mesh, mesh_file)
    assert len(mesh.faces) == 500_000 and "leaf_id" in fields
