"""write_mesh's packed triangle writer (added for the generator's large leaf meshes) must give exactly the bytes
plyfile's generic writer gives, and read back."""

import numpy as np
from plyfile import PlyElement

from plantbench.io.ply import _vertex_element, _write, read_mesh, write_mesh
from plantbench.plant import TriMesh


def test_packed_writer_matches_plyfile_bytes(tmp_path, rng):
    mesh = TriMesh(rng.random((60, 3)), rng.integers(0, 60, (90, 3)))
    ids = rng.integers(0, 7, 90)
    weight = rng.random(90).astype(np.float32)
    write_mesh(tmp_path / "fast.ply", mesh, face_fields={"leaf_id": ids, "w": weight})
    v = mesh.vertices.astype(np.float32)
    vert = _vertex_element({"x": v[:, 0], "y": v[:, 1], "z": v[:, 2]})
    rec = np.empty(90, dtype=[("vertex_indices", "i4", (3,)), ("leaf_id", "i4"), ("w", "f4")])
    rec["vertex_indices"] = mesh.faces
    rec["leaf_id"] = ids
    rec["w"] = weight
    face = PlyElement.describe(rec, "face", len_types={"vertex_indices": "u1"})
    _write(tmp_path / "slow.ply", [vert, face])
    assert (tmp_path / "fast.ply").read_bytes() == (tmp_path / "slow.ply").read_bytes()
    back, fields = read_mesh(tmp_path / "fast.ply")
    np.testing.assert_array_equal(back.faces, mesh.faces)
    np.testing.assert_array_equal(fields["leaf_id"], ids)
