import numpy as np
import pytest

from plantbench.errors import InputError
from plantbench.plant import Skeleton, TriMesh
from plantbench.skeletons import branch_chains, chain_lengths, topological_order


def _naive_is_forest(parents):
    for i in range(len(parents)):
        seen, j = set(), i
        while parents[j] >= 0:
            if j in seen:
                return False
            seen.add(j)
            j = parents[j]
    return True


def test_is_forest_matches_naive(rng):
    for _ in range(200):
        n = int(rng.integers(1, 12))
        parents = rng.integers(-1, n, n)
        s = Skeleton(rng.random((n, 3)), np.ones(n), parents)
        assert s.is_forest() == _naive_is_forest(parents)


def test_skeleton_validation():
    with pytest.raises(InputError, match="NaN"):
        Skeleton(np.array([[0, 0, np.nan]]), [1.0], [-1])
    with pytest.raises(InputError, match="shape"):
        Skeleton(np.zeros((2, 2)), [1.0, 1.0], [-1, 0])
    with pytest.raises(InputError, match="out of range"):
        Skeleton(np.zeros((2, 3)), [1.0, 1.0], [-1, 5])


def test_branch_chains_y_shape():
    #      3   4
    #       \ /
    #        2
    #        |
    #        1
    #        |
    #        0
    pos = np.array([[0, 0, 0], [0, 0, 1], [0, 0, 2], [-1, 0, 3], [1, 0, 3]], float)
    s = Skeleton(pos, np.ones(5), [-1, 0, 1, 2, 2])
    chains = branch_chains(s)
    assert [c.tolist() for c in chains] == [[0, 1, 2], [2, 3], [2, 4]]
    assert np.allclose(chain_lengths(s, chains), [2, np.sqrt(2), np.sqrt(2)])
    order = topological_order(s)
    pos_in = {n: i for i, n in enumerate(order)}
    assert all(pos_in[p] < pos_in[c] for p, c in s.edges)


def test_branch_chains_multi_root_junction_root():
    # a root that is itself a junction gives no zero-length chain
    pos = np.array([[0, 0, 0], [1, 0, 1], [-1, 0, 1], [5, 5, 0], [5, 5, 1]], float)
    s = Skeleton(pos, np.ones(5), [-1, 0, 0, -1, 3])
    assert sorted(c.tolist() for c in branch_chains(s)) == [[0, 1], [0, 2], [3, 4]]


def test_trimesh_concatenate_and_area():
    a = TriMesh(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float), [[0, 1, 2]])
    b = TriMesh(np.array([[0, 0, 1], [2, 0, 1], [0, 2, 1]], float), [[0, 1, 2]])
    m = TriMesh.concatenate([a, b])
    assert m.faces.tolist() == [[0, 1, 2], [3, 4, 5]]
    assert np.allclose(m.face_areas(), [0.5, 2.0])
