"""plantbench method plugin: PC Skeletor's Laplacian-based contraction (LBC), registered as the ``pcskeletor`` method.

`PC Skeletor <https://github.com/meyerls/pc-skeletor>`_ (Lukas Meyer, MIT licence, PyPI ``pc-skeletor`` 1.0.0) is an
independently developed Python re-implementation of Cao et al. 2010, "Point Cloud Skeletons via Laplacian-Based
Contraction": the cloud is contracted by iterated sparse least squares ``[W_L L; W_H] P' = [0; W_H P]`` with the
robust point-cloud Laplacian of Sharp & Crane 2020 (``robust_laplacian``, 30 neighbours), the contracted cloud is
thinned by farthest-point sampling (10 % of the points, at least 15) and the samples are joined by a minimum spanning
tree over their 15 nearest neighbours (``mistree``). This plugin is a thin adapter, the proof that plantbench's
method API serves someone else's code:

1. read ``capture_dir/points.ply`` (x, y, z) and refuse fewer than :data:`MIN_POINTS` points (InputError);
2. run ``pc_skeletor.LBC(point_cloud, **LBCParams())`` then ``extract_skeleton()`` and ``extract_topology()`` with
   the defaults of LBC's signature in 1.0.0 (:class:`LBCParams`; a suite's ``[method_options.pcskeletor]`` overrides
   them by name). The semantic variant (S-LBC) needs a trunk/branch segmentation that a capture does not give;
3. turn the tool's ``skeleton_graph`` (networkx, nodes = the sampled skeleton points ``lbc.skeleton.points``) into a
   plantbench :class:`~plantbench.plant.Skeleton` (:func:`graph_to_skeleton`);
4. write ``skeleton.ply`` (no mesh, leaves or points: the tool produces none).

Frame: the cloud is translated so that its bounding box starts at (1, 1, 1) m before it is handed to the tool, and
the skeleton translated back. LBC itself is translation invariant, but ``extract_topology`` deletes every contracted
point within 1 cm of the origin (its guard against points the solver collapsed to zero), and plantbench puts the root
of every plant at the origin: in the original frame that guard would cut the base of the stem.

Determinism: the tool draws no random numbers (farthest-point sampling starts at point 0, the solvers are direct);
NumPy's legacy global generator is nevertheless seeded from ``seed`` for the call and restored afterwards.
Threads: when plantbench sets ``PLANTBENCH_THREADS`` (:func:`plantbench.backend.thread_budget`), the BLAS and OpenMP
pools that threadpoolctl can see are capped to it for the call and scipy's KD-tree queries use that many workers;
Open3D's statically linked OpenMP (outlier filter) reads ``OMP_NUM_THREADS``, which the runner sets beside it.
The tool's prints, tqdm bars and log records are captured (``logging.basicConfig`` in its constructor would
otherwise configure the host's root logger); they are quoted in the error when the tool fails.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from plantbench.errors import InputError
from plantbench.methods.api import MethodFailed
from plantbench.methods.inputs import check_cloud, read_input_points
from plantbench.plant import Skeleton

__all__ = [
    "PCSkeletor",
    "LBCParams",
    "params_from_options",
    "load_points",
    "run_lbc",
    "graph_to_skeleton",
    "skeletonize",
    "MIN_POINTS",
    "MIN_RADIUS",
    "MAX_RADIUS",
    "TOOL_VERSION",
]

TOOL_VERSION = "1.0.0"
"""The pc-skeletor release this adapter was written and tested against (``pip install --no-deps pc-skeletor==1.0.0``)."""

MIN_POINTS = 100
"""Fewer input points are refused with InputError: the tool's Laplacian uses 30 neighbours per point and its
statistical outlier filter 20, and farthest-point sampling keeps 10 % of the points; below ~100 points the contraction
has nothing to contract."""

MIN_RADIUS, MAX_RADIUS = 1e-3, 0.5
"""Node radii (median distance of the input points nearest to the node) are clipped to [1 mm, 0.5 m]."""

_FRAME_MARGIN = 1.0
"""Metres between the origin and the translated cloud's bounding box (see the module docstring, Frame)."""


@dataclass(frozen=True)
class LBCParams:
    """Keyword arguments of ``pc_skeletor.LBC``; every default is the default of LBC's signature in pc-skeletor 1.0.0
    (``pc_skeletor/laplacian.py``, ``class LBC.__init__``). Suite options override them by name."""

    init_contraction: float = 1.0
    """Initial contraction weight W_L (scaled inside the tool by 1e3 x sqrt of the mean point area)."""
    init_attraction: float = 0.5
    """Initial attraction (positional) weight W_H."""
    max_contraction: float = 2048
    """Upper clip of the contraction weights."""
    max_attraction: float = 1024
    """Upper clip of the attraction weights."""
    step_wise_contraction_amplification: float | str = "auto"
    """Factor applied to W_L per iteration; 'auto' picks it from the point count (2 below 10k points, 5 below 500k)."""
    termination_ratio: float = 0.003
    """Stop when the mean point area falls below this fraction of the initial one."""
    max_iteration_steps: int = 20
    """Most contraction iterations."""
    down_sample: float | str = "auto"
    """Voxel size for Open3D down-sampling before contraction, metres; -1: none (the tool's default; its README
    example uses 0.008); 'auto' (this plugin's default): -1 when the cloud has at most ``max_points`` points, else
    the smallest voxel of 0.008 x 1.25^k metres that leaves at most that many (the tool's memory grows with the
    cloud: ~17 GB at 740k points, an OOM kill on a 24 GB machine)."""
    max_points: int = 30_000
    """Point budget of ``down_sample = 'auto'`` (not an argument of the tool)."""
    filter_nb_neighbors: int = 20
    """Neighbours of Open3D's statistical outlier removal applied before contraction (0 disables the filter)."""
    filter_std_ratio: float = 2.0
    """Standard-deviation ratio of that filter."""


def params_from_options(options: dict) -> LBCParams:
    """:class:`LBCParams` from a suite's ``[method_options.pcskeletor]``; unknown names or a bad ``down_sample`` /
    ``max_points`` raise InputError."""
    names = [f.name for f in dataclasses.fields(LBCParams)]
    bad = sorted(set(options) - set(names))
    if bad:
        from plantbench.schemas import unknown_options

        raise InputError("pcskeletor: " + unknown_options(bad, names))
    params = LBCParams(**options)
    ds = params.down_sample
    if not (ds == "auto" or (isinstance(ds, int | float) and (ds == -1 or ds > 0))):
        raise InputError(f"pcskeletor: down_sample must be 'auto', -1 or a voxel size > 0 (metres), got {ds!r}")
    if not (isinstance(params.max_points, int) and params.max_points >= MIN_POINTS):
        raise InputError(f"pcskeletor: max_points must be an integer >= {MIN_POINTS}, got {params.max_points!r}")
    return params


def load_points(capture_dir: str | Path) -> np.ndarray:
    """(n, 3) float64 coordinates of ``capture_dir/points.ply``; InputError naming the file when missing,
    non-finite, fewer than :data:`MIN_POINTS` or all coincident."""
    return read_input_points(capture_dir, min_points=MIN_POINTS, method="pcskeletor", why=_WHY)


_WHY = "pc-skeletor's Laplacian uses 30 neighbours per point"


def _check_points(points: np.ndarray) -> np.ndarray:
    return check_cloud(points, min_points=MIN_POINTS, method="pcskeletor", why=_WHY)


def _import_tool():
    try:
        import pc_skeletor
    except ImportError as exc:
        raise MethodFailed(
            f"pcskeletor: cannot import pc_skeletor ({exc}). Install it without its declared dependencies, which "
            f"clash with plantbench's open3d-cpu: pip install --no-deps pc-skeletor=={TOOL_VERSION} "
            "(plugins/plantbench-pcskeletor/README.md)") from exc
    return pc_skeletor


@contextlib.contextmanager
def _captured(buffer: io.StringIO):
    """Route the tool's stdout/stderr (prints, tqdm) into ``buffer``; undo its ``logging.basicConfig``."""
    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    try:
        with contextlib.redirect_stdout(buffer), contextlib.redirect_stderr(buffer):
            yield
    finally:
        for handler in list(root.handlers):
            if handler not in handlers:
                root.removeHandler(handler)
        root.setLevel(level)


@contextlib.contextmanager
def _thread_cap():
    from plantbench.backend import thread_budget

    n = thread_budget()
    if n is None:
        yield
        return
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=n):
        yield


@contextlib.contextmanager
def _seeded_global_numpy(seed: int):
    from plantbench.seeding import derive_seed

    # the legacy global generator on purpose: it is the one third-party code draws from without being handed one
    state = np.random.get_state()  # noqa: NPY002
    np.random.seed(derive_seed(seed, "pcskeletor") % 2**32)  # noqa: NPY002
    try:
        yield
    finally:
        np.random.set_state(state)  # noqa: NPY002


def _tail(text: str, n: int = 600) -> str:
    text = " | ".join(line.strip() for line in text.replace("\r", "\n").splitlines() if line.strip())
    return text[-n:] if text else "(none)"


AUTO_VOXEL_START = 0.008
"""First voxel size tried by ``down_sample = 'auto'``, metres (the tool's README example)."""


def voxel_size(pcd, params: LBCParams) -> float:
    """The ``down_sample`` argument handed to the tool: ``params.down_sample`` when it is a number, else (auto) -1
    for a cloud within ``params.max_points`` points, or the smallest 0.008 x 1.25^k m voxel that brings Open3D's
    voxel down-sampling within it."""
    if params.down_sample != "auto":
        return float(params.down_sample)
    if len(pcd.points) <= params.max_points:
        return -1.0
    voxel = AUTO_VOXEL_START
    while len(pcd.voxel_down_sample(voxel).points) > params.max_points:
        voxel *= 1.25
    return voxel


def run_lbc(points: np.ndarray, params: LBCParams = LBCParams(), *, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Run pc-skeletor's LBC on ``points`` and return its skeleton graph.

    Parameters
    ----------
    points : (n, 3) float
        The cloud, metres.
    params : the tool's keyword arguments
    seed : seeds NumPy's legacy global generator during the call (the tool draws nothing from it in 1.0.0)

    Returns
    -------
    positions : (k, 3) float
        The skeleton points (``lbc.skeleton.points``, farthest-point samples of the contracted cloud), in the frame
        of ``points``.
    edges : (m, 2) int
        The edges of ``lbc.skeleton_graph`` (its minimum spanning tree), indices into ``positions``.

    Raises MethodFailed when the tool raises (its output quoted).
    """
    pts = _check_points(points)
    tool = _import_tool()
    import open3d as o3d

    offset = pts.min(axis=0) - _FRAME_MARGIN
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts - offset))
    kwargs = dataclasses.asdict(params)
    kwargs.pop("max_points")  # the plugin's, not the tool's
    kwargs["down_sample"] = voxel_size(pcd, params)
    log = io.StringIO()
    with _captured(log), _thread_cap(), _seeded_global_numpy(seed):
        try:
            lbc = tool.LBC(point_cloud=pcd, **kwargs)
            lbc.extract_skeleton()
            lbc.extract_topology()
            positions = np.asarray(lbc.skeleton.points, dtype=np.float64) + offset
            edges = np.array([(int(a), int(b)) for a, b in lbc.skeleton_graph.edges()], dtype=np.int64).reshape(-1, 2)
        except Exception as exc:  # the tool's own errors (numpy, scipy, open3d, robust_laplacian, mistree)
            raise MethodFailed(f"pcskeletor: pc-skeletor failed on {len(pts)} points: {type(exc).__name__}: {exc}; "
                               f"tool output: {_tail(log.getvalue())}") from exc
    return positions, edges


def graph_to_skeleton(positions: np.ndarray, edges: np.ndarray, points: np.ndarray, *,
                      workers: int = -1) -> Skeleton:
    """A plantbench Skeleton from a skeleton graph and the cloud it came from.

    Parameters
    ----------
    positions : (k, 3) float
        Graph nodes; rows with NaN or infinite coordinates are dropped with their edges.
    edges : (m, 2) int
        Undirected edges (indices into ``positions``); duplicates and self-loops are ignored, cycles are broken by a
        Euclidean minimum spanning tree.
    points : (n, 3) float
        The input cloud, for the radii.
    workers : scipy KD-tree query workers

    Returns
    -------
    Skeleton whose parents form a forest: one tree per connected component, rooted at its lowest node (least z),
    parents from a breadth-first search of the spanning tree. Radius of a node: the median distance to it of the
    input points whose nearest node it is (a node no point is nearest to takes the radius of the nearest node that
    has points), clipped to [MIN_RADIUS, MAX_RADIUS]. Order: 0 along the path from each root to the highest node of
    its tree; at every branching the child continuing the axis keeps its parent's order (on the order-0 path the
    child towards the highest node, elsewhere the child with the longest path below it) and the others take +1.

    Raises MethodFailed when no edge survives (an empty skeleton).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_order, connected_components, minimum_spanning_tree

    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    finite = np.all(np.isfinite(pos), axis=1)
    if len(e) and (e.min() < 0 or e.max() >= len(pos)):
        raise MethodFailed("pcskeletor: the tool's skeleton graph has edges to nodes it does not have")
    new_index = np.cumsum(finite) - 1
    e = e[finite[e].all(axis=1)]
    e = new_index[e]
    pos = pos[finite]
    e = e[e[:, 0] != e[:, 1]]
    e = np.unique(np.sort(e, axis=1), axis=0)
    if len(e) == 0:
        raise MethodFailed(f"pcskeletor: pc-skeletor returned an empty skeleton ({len(pos)} finite nodes, no edge)")
    # only nodes on an edge: an isolated sample carries no branch
    used = np.zeros(len(pos), bool)
    used[e.ravel()] = True
    new_index = np.cumsum(used) - 1
    pos, e = pos[used], new_index[e]
    n = len(pos)

    length = np.linalg.norm(pos[e[:, 0]] - pos[e[:, 1]], axis=1)
    weight = np.maximum(length, 1e-12)  # csgraph reads an explicit 0 as "no edge"
    graph = coo_matrix((weight, (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    tree = minimum_spanning_tree(graph)
    tree = (tree + tree.T).tocsr()
    n_comp, labels = connected_components(tree, directed=False)
    z = pos[:, 2]
    # lowest node of each component (ties: lowest index); one BFS from a virtual node joined to every root
    by_comp = np.lexsort((np.arange(n), z, labels))
    first = np.searchsorted(labels[by_comp], np.arange(n_comp))
    roots = by_comp[first]
    tree = tree.tocoo()
    rows = np.concatenate([tree.row, np.full(n_comp, n), roots])
    cols = np.concatenate([tree.col, roots, np.full(n_comp, n)])
    vals = np.concatenate([tree.data, np.ones(2 * n_comp)])
    joined = coo_matrix((vals, (rows, cols)), shape=(n + 1, n + 1)).tocsr()
    bfs, pred = breadth_first_order(joined, n, directed=False, return_predecessors=True)
    bfs = bfs[1:]  # parents before children
    parents = pred[:n].astype(np.int64)
    parents[parents == n] = -1
    parents[roots] = -1

    order = _branch_orders(pos, parents, bfs, labels, roots)
    radii = _radii(pos, pts, workers)
    return Skeleton(pos, radii, parents, order)


def _branch_orders(pos: np.ndarray, parents: np.ndarray, bfs: np.ndarray, labels: np.ndarray,
                   roots: np.ndarray) -> np.ndarray:
    n = len(pos)
    has_parent = parents >= 0
    edge_len = np.zeros(n)
    edge_len[has_parent] = np.linalg.norm(pos[has_parent] - pos[parents[has_parent]], axis=1)
    reach = np.zeros(n)  # longest path from the node down to a leaf of its subtree
    for v in bfs[::-1]:
        p = parents[v]
        if p >= 0:
            reach[p] = max(reach[p], reach[v] + edge_len[v])
    on_main = np.zeros(n, bool)
    for c in range(len(roots)):
        members = np.flatnonzero(labels == c)
        v = members[np.argmax(pos[members, 2])]
        while v >= 0:
            on_main[v] = True
            v = parents[v]
    children: list[list[int]] = [[] for _ in range(n)]
    for v in bfs:
        if parents[v] >= 0:
            children[parents[v]].append(int(v))
    order = np.zeros(n, np.int64)
    for v in bfs:
        kids = children[v]
        if not kids:
            continue
        main_kids = [c for c in kids if on_main[c]] if on_main[v] else []
        main = main_kids[0] if main_kids else max(kids, key=lambda c: reach[c] + edge_len[c])
        for c in kids:
            order[c] = order[v] if c == main else order[v] + 1
    return order


def _radii(pos: np.ndarray, pts: np.ndarray, workers: int) -> np.ndarray:
    from scipy.spatial import cKDTree

    n = len(pos)
    dist, nearest = cKDTree(pos).query(pts, workers=workers)
    radii = np.full(n, np.nan)
    srt = np.argsort(nearest, kind="stable")
    nearest_s, dist_s = nearest[srt], dist[srt]
    start = np.searchsorted(nearest_s, np.arange(n), side="left")
    stop = np.searchsorted(nearest_s, np.arange(n), side="right")
    for v in np.flatnonzero(stop > start):
        radii[v] = np.median(dist_s[start[v]:stop[v]])
    has = np.isfinite(radii)
    if not has.any():  # cannot happen with a non-empty cloud; kept for a clear answer
        radii[:] = MIN_RADIUS
    elif not has.all():
        _, j = cKDTree(pos[has]).query(pos[~has], workers=workers)
        radii[~has] = radii[has][j]
    return np.clip(radii, MIN_RADIUS, MAX_RADIUS)


def skeletonize(points: np.ndarray, params: LBCParams = LBCParams(), *, seed: int = 0) -> Skeleton:
    """pc-skeletor's LBC skeleton of ``points`` as a plantbench Skeleton (:func:`run_lbc`, :func:`graph_to_skeleton`)."""
    from plantbench.backend import kdtree_workers

    pts = _check_points(points)
    positions, edges = run_lbc(pts, params, seed=seed)
    return graph_to_skeleton(positions, edges, pts, workers=kdtree_workers())


class PCSkeletor:
    """The ``pcskeletor`` method: pc-skeletor 1.0.0's Laplacian-based contraction on the input cloud."""

    name = "pcskeletor"
    inputs = "points"

    def check_options(self, options: dict) -> None:
        """Raise InputError on an unknown or invalid option (the planner calls it before any job runs)."""
        params_from_options(options)

    def reconstruct(self, capture_dir: Path, out_dir: Path, *, seed: int, species: str | None = None,
                    **options) -> Skeleton:
        """Read ``capture_dir/points.ply``, skeletonize it with pc-skeletor, write ``out_dir/skeleton.ply``.

        ``species`` is ignored (the tool uses no prior). ``options`` override :class:`LBCParams` fields by name.
        Returns the skeleton written.
        """
        from plantbench.io.plantio import write_reconstruction

        params = params_from_options(options)
        points = load_points(capture_dir)
        skeleton = skeletonize(points, params, seed=seed)
        write_reconstruction(out_dir, skeleton)
        return skeleton
