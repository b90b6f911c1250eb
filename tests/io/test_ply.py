import numpy as np
import pytest
import trimesh

from plantbench.errors import InputError
from plantbench.io.ply import read_mesh, read_points, read_skeleton, write_mesh, write_points, write_skeleton
from plantbench.plant import Skeleton, TriMesh


def test_skeleton_roundtrip(tmp_path, rng):
    n = 50
    parents = np.array([-1] + [int(rng.integers(0, i)) for i in range(1, n)])
    s = Skeleton(rng.random((n, 3)), rng.random(n) + 0.1, parents, rng.integers(0, 4, n))
    write_skeleton(tmp_path / "s.ply", s)
    r = read_skeleton(tmp_path / "s.ply")
    assert np.array_equal(r.positions, s.positions) and np.array_equal(r.radii, s.radii)
    assert np.array_equal(r.parents, s.parents) and np.array_equal(r.order, s.order)


def test_mesh_roundtrip_read_by_trimesh(tmp_path, rng):
    v = rng.random((30, 3))
    f = rng.integers(0, 30, (40, 3))
    ids = rng.integers(0, 5, 40)
    write_mesh(tmp_path / "m.ply", TriMesh(v, f), face_fields={"leaf_id": ids})
    m, fields = read_mesh(tmp_path / "m.ply")
    assert np.array_equal(m.faces, f) and np.allclose(m.vertices, v, atol=1e-7)
    assert np.array_equal(fields["leaf_id"], ids)
    # an independent reader sees the same geometry
    tm = trimesh.load(tmp_path / "m.ply", process=False)
    assert np.array_equal(np.asarray(tm.faces), f) and np.allclose(tm.vertices, v, atol=1e-7)


def test_reads_ascii_quads_from_other_tools(tmp_path):
    text = """ply
format ascii 1.0
element vertex 4
property float x
property float y
property float z
element face 1
property list uchar int vertex_index
end_header
0 0 0
1 0 0
1 1 0
0 1 0
4 0 1 2 3
"""
    (tmp_path / "q.ply").write_text(text)
    m, _ = read_mesh(tmp_path / "q.ply")
    assert m.faces.tolist() == [[0, 1, 2], [0, 2, 3]]
    assert np.isclose(m.face_areas().sum(), 1.0)


def test_points_roundtrip(tmp_path, rng):
    p = rng.random((100, 3))
    write_points(tmp_path / "p.ply", p, {"label": rng.integers(0, 2, 100).astype(np.uint8)})
    q, fields = read_points(tmp_path / "p.ply")
    assert np.allclose(p, q, atol=1e-6) and set(fields) == {"label"}


def test_bad_files_name_the_file(tmp_path):
    (tmp_path / "junk.ply").write_bytes(b"not a ply at all")
    with pytest.raises(InputError, match="junk.ply"):
        read_mesh(tmp_path / "junk.ply")
    with pytest.raises(InputError, match="missing.ply: file not found"):
        read_skeleton(tmp_path / "missing.ply")


def test_skeleton_cycle_rejected(tmp_path):
    text = """ply
format ascii 1.0
element vertex 3
property float x
property float y
property float z
element edge 3
property int vertex1
property int vertex2
end_header
0 0 0
0 0 1
0 0 2
0 1
1 2
2 0
"""
    (tmp_path / "cyc.ply").write_text(text)
    with pytest.raises(InputError, match="cycle"):
        read_skeleton(tmp_path / "cyc.ply")


def test_write_is_atomic_on_failure(tmp_path):
    write_points(tmp_path / "p.ply", np.zeros((3, 3)))
    before = (tmp_path / "p.ply").read_bytes()
    with pytest.raises(TypeError):
        write_points(tmp_path / "p.ply", np.zeros((3, 3)), {"bad": np.array(["a", "b", "c"])})
    assert (tmp_path / "p.ply").read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["p.ply"]
