"""generate_case: byte-identical files per seed, a valid skeleton, consistent leaf bookkeeping, a GLB a real
client reads."""

import json

import numpy as np
import pytest

from plantbench.generate import generate_case
from plantbench.io.plantio import read_plant
from plantbench.io.ply import read_mesh
from plantbench.skeletons import branch_chains, chain_lengths

FILES = ("plant.json", "skeleton.ply", "branches.ply", "leaves.ply", "leaves.json", "plant.glb")
SCALE = 0.15


@pytest.fixture(scope="module")
def laurel_case(tmp_path_factory):
    out = tmp_path_factory.mktemp("laurel")
    meta = generate_case("laurel", 7, out, scale=SCALE)
    return out, meta


def test_same_seed_same_bytes_other_seed_differs(tmp_path, laurel_case):
    first, _ = laurel_case
    generate_case("laurel", 7, tmp_path / "again", scale=SCALE)
    for name in FILES:
        assert (first / "plant" / name).read_bytes() == (tmp_path / "again" / "plant" / name).read_bytes(), name
    generate_case("laurel", 8, tmp_path / "other", scale=SCALE)
    for name in ("skeleton.ply", "leaves.ply"):
        assert (first / "plant" / name).read_bytes() != (tmp_path / "other" / "plant" / name).read_bytes()


def test_skeleton_is_a_rooted_forest_on_the_ground(laurel_case):
    plant, meta = read_plant(laurel_case[0])
    sk = plant.skeleton
    assert sk.is_forest()  # every node reaches a root
    roots = sk.roots
    assert len(roots) == meta.counts.roots == 1
    np.testing.assert_array_equal(sk.positions[roots, 2], 0.0)
    assert np.all(sk.radii > 0)
    child = np.flatnonzero(sk.parents >= 0)
    assert np.all(sk.radii[child] <= sk.radii[sk.parents[child]])
    assert np.all(sk.positions[:, 2] >= 0)


def test_leaf_bookkeeping(laurel_case):
    out, meta = laurel_case
    leaves_doc = json.loads((out / "plant" / "leaves.json").read_text())
    _, fields = read_mesh(out / "plant" / "leaves.ply")
    ids = np.unique(fields["leaf_id"])
    assert meta.counts.leaves == len(leaves_doc["leaves"]) == len(ids) > 0
    np.testing.assert_array_equal(ids, np.arange(meta.counts.leaves))
    assert [e["id"] for e in leaves_doc["leaves"]] == list(range(meta.counts.leaves))


def test_leaves_json_reproduces_the_leaf_mesh(laurel_case):
    """Each leaf's blade is the Bezier leaf of its recorded parameters, length and transform."""
    from plantbench.geometry.leaf import PARAM_NAMES, tessellate

    plant, meta = read_plant(laurel_case[0])
    res = tuple(meta.parameters["leaves"]["resolution"])
    for leaf in plant.leaves[:: max(1, len(plant.leaves) // 15)]:
        omega = np.array([leaf.params[k] for k in PARAM_NAMES])
        local = tessellate(omega, leaf.length, res).vertices
        world = local @ leaf.transform[:3, :3].T + leaf.transform[:3, 3]
        faces = plant.leaf_mesh.faces[plant.leaf_mesh_ids == leaf.id]
        verts = np.unique(plant.leaf_mesh.vertices[np.unique(faces)], axis=0)
        # every tessellated point is a vertex of the stored mesh (float32 on disk)
        d = np.min(np.linalg.norm(world[:, None, :] - verts[None], axis=2), axis=1)
        assert d.max() < 1e-5
        rot = leaf.transform[:3, :3]
        np.testing.assert_allclose(rot.T @ rot, np.eye(3), atol=1e-8)
        assert np.linalg.det(rot) > 0


def test_plant_json_matches_the_files(laurel_case):
    plant, meta = read_plant(laurel_case[0])
    chains = branch_chains(plant.skeleton)
    assert meta.counts.nodes == len(plant.skeleton)
    assert meta.counts.branches == len(chains)
    assert meta.mean_branch_length == pytest.approx(chain_lengths(plant.skeleton, chains).mean(), rel=1e-6)
    assert meta.height == pytest.approx(plant.height, abs=1e-6)
    assert meta.counts.branch_triangles == len(plant.branch_mesh.faces)
    assert meta.species == "laurel" and meta.seed == 7 and meta.family == "space-colonisation"
    assert meta.parameters["table1"]["internode_length"] == 0.051
    assert meta.parameters["derived"]["growth_units"] >= 1


def test_glb_opens_in_trimesh(laurel_case):
    import trimesh

    plant, meta = read_plant(laurel_case[0])
    scene = trimesh.load(laurel_case[0] / "plant" / "plant.glb", force="scene")
    assert sorted(scene.geometry) == ["branches", "leaves"]
    assert len(scene.geometry["leaves"].faces) == meta.counts.leaf_triangles
    assert len(scene.geometry["branches"].faces) == meta.counts.branch_triangles
    assert scene.bounds[1][2] == pytest.approx(meta.height, abs=1e-4)


def test_multi_stem_cercis_has_several_roots(tmp_path):
    meta = generate_case("cercis", 0, tmp_path, scale=0.1)
    plant, _ = read_plant(tmp_path)
    assert meta.counts.roots == len(plant.skeleton.roots) >= 3
    np.testing.assert_array_equal(plant.skeleton.positions[plant.skeleton.roots, 2], 0.0)
