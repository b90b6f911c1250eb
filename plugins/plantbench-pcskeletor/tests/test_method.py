"""The pcskeletor plugin on a synthetic tree with known axes: a 1 m vertical trunk and two straight side branches,
~3000 points sampled on cylinders of radius 1-2 cm around them.

Run from the main repository: ``.venv/bin/python -m pytest -q plugins/plantbench-pcskeletor/tests``.
"""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest
from plantbench_pcskeletor import MAX_RADIUS, MIN_POINTS, MIN_RADIUS, PCSkeletor, graph_to_skeleton

from plantbench.errors import InputError
from plantbench.io.plantio import read_reconstruction
from plantbench.io.ply import write_points
from plantbench.methods.api import MethodFailed

needs_tool = pytest.mark.skipif(importlib.util.find_spec("pc_skeletor") is None,
                                reason="pc-skeletor not installed: pip install --no-deps pc-skeletor==1.0.0 (README.md)")

# (start, end, cylinder radius): the trunk and two side branches
AXES = [
    (np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]), 0.02),
    (np.array([0.0, 0.0, 0.45]), np.array([0.35, 0.0, 0.80]), 0.015),
    (np.array([0.0, 0.0, 0.65]), np.array([-0.25, 0.15, 0.90]), 0.01),
]
TRUNK_HEIGHT = 1.0


def sample_tree(n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` points on the cylinder surfaces around AXES, shared in proportion to each cylinder's area."""
    area = np.array([np.linalg.norm(b - a) * r for a, b, r in AXES])
    counts = rng.multinomial(n, area / area.sum())
    out = []
    for (a, b, r), c in zip(AXES, counts):
        d = (b - a) / np.linalg.norm(b - a)
        u = np.cross(d, [1.0, 0.0, 0.0] if abs(d[0]) < 0.9 else [0.0, 1.0, 0.0])
        u /= np.linalg.norm(u)
        v = np.cross(d, u)
        t = rng.uniform(0.0, np.linalg.norm(b - a), c)
        phi = rng.uniform(0.0, 2 * np.pi, c)
        out.append(a + t[:, None] * d + r * (np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v))
    return np.vstack(out)


def distance_to_axes(q: np.ndarray) -> np.ndarray:
    """Brute force: distance of each row of ``q`` to the nearest of the true axis segments."""
    best = np.full(len(q), np.inf)
    for a, b, _ in AXES:
        d = b - a
        t = np.clip((q - a) @ d / (d @ d), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(q - (a + t[:, None] * d), axis=1))
    return best


def length_within(skeleton, tol: float, step: float = 0.002) -> tuple[float, float]:
    """(length of the skeleton's edges within ``tol`` of the true axes, total length), by sampling every edge."""
    near = total = 0.0
    for p, c in skeleton.edges:
        a, b = skeleton.positions[p], skeleton.positions[c]
        seg = float(np.linalg.norm(b - a))
        k = max(2, int(np.ceil(seg / step)) + 1)
        s = a + np.linspace(0.0, 1.0, k)[:, None] * (b - a)
        mid = 0.5 * (s[1:] + s[:-1])  # one sample per piece of length seg / (k - 1)
        near += seg * float(np.mean(distance_to_axes(mid) <= tol))
        total += seg
    return near, total


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    folder = tmp_path_factory.mktemp("capture")
    write_points(folder / "points.ply", sample_tree(3000, np.random.default_rng(7)))
    return folder


@pytest.fixture(scope="module")
def result(capture, tmp_path_factory):
    out = tmp_path_factory.mktemp("out")
    returned = PCSkeletor().reconstruct(capture, out, seed=0)
    return returned, read_reconstruction(out).skeleton


@needs_tool
def test_writes_a_forest(result):
    returned, skeleton = result
    assert skeleton is not None and len(skeleton) >= 10
    assert np.all((skeleton.parents >= -1) & (skeleton.parents < len(skeleton)))
    assert skeleton.is_forest()
    assert np.all(skeleton.parents[skeleton.roots] == -1) and len(skeleton.roots) >= 1
    assert np.all((skeleton.radii >= MIN_RADIUS * (1 - 1e-6)) & (skeleton.radii <= MAX_RADIUS * (1 + 1e-6)))
    np.testing.assert_allclose(skeleton.positions, returned.positions, atol=1e-6)  # float32 on disk
    np.testing.assert_array_equal(skeleton.parents, returned.parents)


@needs_tool
def test_spans_the_trunk_height(result):
    skeleton = result[0]
    z = skeleton.positions[:, 2]
    assert abs((z.max() - z.min()) - TRUNK_HEIGHT) <= 0.1 * TRUNK_HEIGHT


@needs_tool
def test_lies_on_the_true_axes(result):
    near, total = length_within(result[0], 0.05)
    assert total > 0.5
    assert near / total >= 0.8, f"{near:.3f} of {total:.3f} m within 5 cm of the axes"


@needs_tool
def test_radii_and_orders_are_plausible(result):
    skeleton = result[0]
    assert 0.005 <= np.median(skeleton.radii) <= 0.05  # cylinders of 1-2 cm
    assert skeleton.order.min() == 0 and skeleton.order.max() >= 1  # a trunk and at least one branch
    v = int(np.argmax(skeleton.positions[:, 2]))  # the top of the trunk is reached from a root at its base
    while skeleton.parents[v] >= 0:
        assert skeleton.order[v] == 0
        v = int(skeleton.parents[v])
    assert skeleton.positions[v, 2] < 0.1


@needs_tool
def test_deterministic(capture, result, tmp_path):
    again = PCSkeletor().reconstruct(capture, tmp_path, seed=0)
    np.testing.assert_array_equal(again.positions, result[0].positions)
    np.testing.assert_array_equal(again.parents, result[0].parents)


def test_registered():
    from plantbench.registry import methods

    method = methods.get("pcskeletor")
    assert isinstance(method, PCSkeletor)
    assert method.name == "pcskeletor" and method.inputs == "points"


@pytest.mark.parametrize("n", [0, 5, MIN_POINTS - 1])
def test_too_small_cloud_is_a_clear_error(tmp_path, n):
    pts = sample_tree(max(n, 1), np.random.default_rng(1))[:n]
    write_points(tmp_path / "points.ply", pts)
    with pytest.raises(InputError, match=f"{n} points; pcskeletor needs at least {MIN_POINTS}"):
        PCSkeletor().reconstruct(tmp_path, tmp_path / "out", seed=0)
    assert not (tmp_path / "out" / "skeleton.ply").exists()


def test_missing_cloud_is_a_clear_error(tmp_path):
    with pytest.raises(InputError, match="no points.ply"):
        PCSkeletor().reconstruct(tmp_path, tmp_path / "out", seed=0)


@needs_tool
def test_unknown_option_is_refused(capture, tmp_path):
    with pytest.raises(InputError, match="unknown option.*nope"):
        PCSkeletor().reconstruct(capture, tmp_path, seed=0, nope=1)


@needs_tool
def test_tool_failure_is_a_method_failure(capture, tmp_path):
    # init_attraction = 0 is refused by pc_skeletor.LBC itself (ValueError): it must surface as MethodFailed
    with pytest.raises(MethodFailed, match="pc-skeletor failed.*attraction"):
        PCSkeletor().reconstruct(capture, tmp_path, seed=0, init_attraction=0)


def test_graph_to_skeleton_handles_cycles_components_and_nan():
    # a square with a diagonal (cycles), a separate segment, a NaN node and an isolated node
    pos = np.array([[0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 1], [5, 0, 2], [5, 0, 3], [np.nan, 0, 0], [9, 9, 9.0]])
    edges = np.array([[0, 1], [1, 2], [2, 3], [3, 0], [0, 2], [2, 0], [4, 5], [5, 6], [3, 3]])
    cloud = np.array([[0.01, 0, 0], [5, 0.02, 2.5]])
    sk = graph_to_skeleton(pos, edges, cloud)
    assert len(sk) == 6 and sk.is_forest()
    assert len(sk.roots) == 2
    assert set(map(tuple, sk.positions[sk.roots].round(6))) == {(0, 0, 0), (5, 0, 2)}  # lowest node of each part
    assert len(sk.edges) == 4  # a spanning tree of each part
    assert np.all((sk.radii >= MIN_RADIUS) & (sk.radii <= MAX_RADIUS))
    with pytest.raises(MethodFailed, match="empty skeleton"):
        graph_to_skeleton(pos[:2], np.zeros((0, 2), int), cloud)


def test_auto_voxel_keeps_the_cloud_within_its_budget():
    """down_sample = 'auto': none for a small cloud; otherwise the smallest 0.008 x 1.25^k voxel that Open3D's voxel
    down-sampling brings within max_points (checked against Open3D itself, one step finer is over)."""
    import open3d as o3d
    from plantbench_pcskeletor import AUTO_VOXEL_START, LBCParams, params_from_options, voxel_size

    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 1.0, (20_000, 3)) * [1.0, 1.0, 0.05]
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    assert voxel_size(pcd, LBCParams(max_points=20_000)) == -1.0
    v = voxel_size(pcd, LBCParams(max_points=5_000))
    k = np.log(v / AUTO_VOXEL_START) / np.log(1.25)
    assert np.isclose(k, round(k)) and v >= AUTO_VOXEL_START
    assert len(pcd.voxel_down_sample(v).points) <= 5_000
    if v > AUTO_VOXEL_START:
        assert len(pcd.voxel_down_sample(v / 1.25).points) > 5_000
    assert voxel_size(pcd, LBCParams(down_sample=0.02)) == 0.02
    for bad in ({"down_sample": 0}, {"down_sample": "fine"}, {"max_points": 5}):
        with pytest.raises(InputError):
            params_from_options(bad)
