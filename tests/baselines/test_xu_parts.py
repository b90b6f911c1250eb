"""Xu et al. 2007 building blocks (sections 4.1-4.4, 5.2) on configurations with known answers."""

import numpy as np
from scipy.sparse import csgraph

from reference_impl.common.graph import radius_graph
from reference_impl.common.radii import murray_angle
from reference_impl.xu.pipeline import adjust_branch_angles
from reference_impl.xu.skeleton import bin_skeleton, join_fragments, probe_extend
from reference_impl.xu.synthesis import (
    axil_angles,
    leaf_locations,
    prune_bare_twigs,
    section_nodes,
    similarity_transform,
    support,
    synthesize,
    triangle_angles,
)


def _line(z0, z1, n, rng, x=0.0):
    z = np.linspace(z0, z1, n)
    return np.c_[np.full(n, x) + rng.normal(0, 1e-3, n), rng.normal(0, 1e-3, n), z]


def test_bin_skeleton_of_a_fork(rng):
    stem = _line(0, 1, 200, rng)
    t = np.linspace(0.005, 1, 200)[:, None]
    left = np.array([0, 0, 1.0]) + t * np.array([-0.6, 0, 0.8])
    right = np.array([0, 0, 1.0]) + t * np.array([0.6, 0, 0.8])
    pts = np.vstack([stem, left, right])
    g = radius_graph(pts, 0.05)
    sk = bin_skeleton(pts, g, np.arange(len(pts)), np.array([0]), 0.05)
    par = sk.parents
    assert (par < 0).sum() == 1 and sk.positions[par < 0][0, 2] < 0.05
    nk = np.bincount(par[par >= 0], minlength=len(par))
    assert (nk >= 2).sum() == 1 and (nk == 0).sum() == 2  # one split, two tips
    split = sk.positions[np.flatnonzero(nk >= 2)[0]]
    assert abs(split[2] - 1.0) < 0.1
    # every node sits on the input curves (centroids of thin bins)
    d = np.min(np.linalg.norm(sk.positions[:, None] - pts[None], axis=2), axis=1)
    assert d.max() < 0.02
    # parents lie one bin lower along the geodesic
    assert np.all(sk.geodesic[par >= 0] > sk.geodesic[par[par >= 0]])
    ang = axil_angles(sk.positions, par, reach=3)
    assert len(ang) == 1 and abs(ang[0] - np.degrees(np.arctan2(0.6, 0.8))) < 8


def test_probing_joins_a_subgraph_across_a_gap(rng):
    stem = _line(0, 1, 100, rng)
    upper = _line(1.15, 2.0, 90, rng)  # a 15 cm occlusion gap, more than the 5 cm neighbourhood
    pts = np.vstack([stem, upper])
    g = radius_graph(pts, 0.05)
    ncomp, lab = csgraph.connected_components(g, directed=False)
    assert ncomp == 2
    main_mask = lab == lab[0]
    main = bin_skeleton(pts, g, np.flatnonzero(main_mask), np.array([0]), 0.05)
    ext, attached, joined = probe_extend(pts, g, lab, main, main_mask, width=0.05, cone_deg=45, gap=0.3,
                                         max_geodesic=10.0)
    assert joined == 1 and attached.all()
    assert (ext.parents < 0).sum() == 1 and len(ext.positions) > len(main.positions)
    assert ext.positions[:, 2].max() > 1.9
    # a gap wider than the probing range stays open
    ext2, attached2, joined2 = probe_extend(pts, g, lab, main, main_mask, width=0.05, cone_deg=45, gap=0.1,
                                            max_geodesic=10.0)
    assert joined2 == 0 and not attached2[~main_mask].any()


def test_probing_steps_through_the_returns_in_a_gap(rng):
    stem = _line(0, 1, 100, rng)
    upper = _line(1.4, 2.0, 70, rng)
    stones = np.array([[0.01, 0.0, 1.13], [-0.01, 0.0, 1.26]])  # two lone returns in the 40 cm gap
    pts = np.vstack([stem, upper, stones])
    g = radius_graph(pts, 0.05)
    _, lab = csgraph.connected_components(g, directed=False)
    main_mask = lab == lab[0]
    main = bin_skeleton(pts, g, np.flatnonzero(main_mask), np.array([0]), 0.05)
    kw = dict(width=0.05, cone_deg=45, gap=0.5, max_geodesic=10.0)
    for waypoints in (False, True):
        ext, attached, joined = probe_extend(pts, g, lab, main, main_mask, waypoints=waypoints, **kw)
        assert joined == 1 and ext.positions[:, 2].max() > 1.9
        d = np.linalg.norm(ext.positions[:, None] - stones[None], axis=2).min(axis=0)
        if waypoints:  # both returns are nodes of the join, in order up the gap, and count as explained
            assert np.all(d < 1e-12) and attached[-2:].all()
            i, j = (int(np.argmin(np.linalg.norm(ext.positions - s, axis=1))) for s in stones)
            assert ext.parents[j] == i and ext.positions[ext.parents[i], 2] < 1.13
            assert np.all(ext.geodesic[ext.parents >= 0] > ext.geodesic[ext.parents[ext.parents >= 0]])
        else:  # the straight join passes them by
            assert np.all(d > 1e-3) and not attached[-2:].any()


def test_fragments_outside_every_probing_cone_join_nearest_first(rng):
    """A limb seen as two pieces beside the stem, level with it (no cone along the stem points at it; a sparse scan's
    crown left of the stem), joins the skeleton through its nearest point, the nearer piece first and the farther one
    onto it; a piece beyond the gap, and one of fewer than ``min_points`` points, stay out."""
    stem = _line(0, 1, 100, rng)
    # 25 cm from the stem: a cone of 45 deg reaches it only from 25 cm below, 35 cm away, beyond the 30 cm gap
    near_piece = np.c_[np.linspace(0.25, 0.45, 30), rng.normal(0, 1e-3, 30), np.full(30, 0.5)]
    far_piece = np.c_[np.linspace(0.6, 0.9, 30), rng.normal(0, 1e-3, 30), np.full(30, 0.5)]  # 15 cm beyond it
    lone = np.c_[np.linspace(-0.24, -0.22, 2), np.zeros(2), np.full(2, 0.5)]  # two returns, 22 cm left
    away = np.c_[np.full(30, -2.0), rng.normal(0, 1e-3, 30), np.linspace(0.2, 0.5, 30)]  # 2 m off
    pts = np.vstack([stem, near_piece, far_piece, lone, away])
    g = radius_graph(pts, 0.05)
    ncomp, lab = csgraph.connected_components(g, directed=False)
    assert ncomp == 5
    main_mask = lab == lab[0]
    main = bin_skeleton(pts, g, np.flatnonzero(main_mask), np.array([0]), 0.05)
    kw = dict(width=0.05, cone_deg=45, gap=0.3, max_geodesic=10.0)
    probed, attached, joined = probe_extend(pts, g, lab, main, main_mask, **kw)
    assert joined == 0  # the cones point up the stem
    ext, attached, n = join_fragments(pts, g, lab, probed, attached, width=0.05, gap=0.3, min_points=3)
    assert n == 2 and attached[:160].all() and not attached[160:].any()
    assert (ext.parents < 0).sum() == 1 and ext.positions[:, 0].max() > 0.85
    # the far piece hangs from the near piece's skeleton, not from the stem (0.6 m away)
    tip = int(np.argmax(ext.positions[:, 0]))
    node = tip
    while ext.parents[node] >= 0 and ext.positions[ext.parents[node], 0] > 0.1:
        node = ext.parents[node]
    assert ext.positions[node, 0] < 0.5 and np.all(ext.geodesic[ext.parents >= 0] > -1e-9)


def test_similarity_transform_is_exact_for_similar_triangles(rng):
    src = rng.random((3, 3))
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1
    dst = 2.5 * src @ q.T + [1, 2, 3]
    s, rot, t = similarity_transform(src, dst)
    assert np.isclose(s, 2.5) and np.allclose(rot, q) and np.allclose(s * src @ rot.T + t, dst)
    ang = triangle_angles(src[0], src[1], src[2])
    assert np.isclose(ang.sum(), 180.0) and np.allclose(ang, triangle_angles(dst[0], dst[1], dst[2]))


def test_support_needs_a_feasible_angle_and_distance():
    pos = np.array([[0, 0, 0], [0, 0, 1.0]])
    par = np.array([-1, 0])
    # node 1 points up; a location at 35 deg from +z is feasible for I1 = [25, 45]; one straight above is not
    locs = np.array([[np.sin(np.radians(35)) * 0.05, 0, 1 + np.cos(np.radians(35)) * 0.05], [0, 0, 1.05],
                     [np.sin(np.radians(35)) * 0.5, 0, 1 + np.cos(np.radians(35)) * 0.5]])
    node, dist, sup = support(locs, pos, par, d0=0.1, interval=(25.0, 45.0))
    assert node[0] == 1 and sup[0]
    assert node[1] != 1 and not sup[1]
    assert node[2] == 1 and not sup[2] and np.isclose(dist[2], 0.5)


def test_leaf_locations_and_density(rng):
    pts = np.vstack([rng.random((200, 3)) * 0.1, rng.random((10, 3)) * 0.1 + 5])
    loc, dens = leaf_locations(pts, 0.05, 1.0)
    assert len(loc) > 2
    far = loc[:, 0] > 4
    assert np.all(dens[far] == far.sum() - 1) and np.all(dens[~far] == (~far).sum() - 1)


def _fork_and_leaves():
    """A scanned skeleton with one fork (the triangle library) and leaf locations out of reach to its side:
    positions, parents, locations, densities."""
    pos = np.array([[0, 0, 0], [0, 0, 0.5], [0, 0, 1.0], [-0.3, 0, 1.4], [0.3, 0, 1.4], [0, 0, 1.3]], float)
    par = np.array([-1, 0, 1, 2, 2, 2])
    locs = np.array([[0.35, 0.0, 0.85], [0.5, 0.0, 0.9], [0.42, 0.05, 0.88]])
    dens = np.array([2, 1, 2])
    return pos, par, locs, dens


def test_synthesis_supports_unsupported_leaves():
    pos, par, locs, dens = _fork_and_leaves()
    interval = (20.0, 60.0)
    _, _, sup0 = support(locs, pos, par, d0=0.08, interval=interval)
    res = synthesize(pos, par, locs, dens, d0=0.08, interval=interval, group=0.02, iterations=3,
                     max_nodes=1000)
    assert not sup0.all() and res.branches >= 1 and res.synthetic.sum() > 0
    assert np.all(res.parents[res.synthetic] >= 0)
    # the synthesised nodes are new, hang from the old skeleton, and bring the leaves closer
    _, d1, _ = support(locs, res.positions, res.parents, d0=0.08, interval=interval)
    _, d0_, _ = support(locs, pos, par, d0=0.08, interval=interval)
    assert np.nanmin(np.where(np.isfinite(d1), d1, np.nan)) < np.nanmin(np.where(np.isfinite(d0_), d0_, 10.0))


def test_synthesis_needs_two_separate_locations():
    """Section 4.3 synthesises from a triangle OAB of two separate leaf locations: a node with a single associated
    location, or with all of them within ``group`` of A, gets no branch (no straight twig to the location)."""
    pos, par, locs, dens = _fork_and_leaves()
    kw = dict(d0=0.08, interval=(20.0, 60.0), iterations=3, max_nodes=1000)
    one = synthesize(pos, par, locs[:1], dens[:1], group=0.02, **kw)
    assert one.branches == 0 and one.synthetic.sum() == 0 and len(one.positions) == len(pos)
    spread = float(np.max(np.linalg.norm(locs[:, None] - locs[None], axis=2)))
    close = synthesize(pos, par, locs, dens, group=spread + 1e-6, **kw)  # every location within group of A
    assert close.branches == 0 and close.synthetic.sum() == 0
    apart = synthesize(pos, par, locs, dens, group=0.02, **kw)
    assert apart.branches >= 1 and apart.synthetic.sum() > 1  # a copied section, not a single node


def test_copied_section_is_the_two_paths():
    """Section 4.3: "the skeleton structure from O' to A' and B' is copied": the nodes on the paths up from A' and
    from B' to O' (O' excluded), checked against a walk up the parent links; a side branch hanging from the path
    O' -> A' is not copied."""
    pos = [[0, 0, 0], [0, 0, 0.5], [0, 0, 1.0], [-0.15, 0, 1.2], [-0.3, 0, 1.4], [0.3, 0, 1.4]]
    par = [-1, 0, 1, 2, 3, 2]
    prev = 3
    for i in range(1, 6):  # side branch from M = node 3, out to x = -1.5
        pos.append([-0.15 - 0.27 * i, 0.0, 1.2 - 0.02 * i])
        par.append(prev)
        prev = len(pos) - 1
    par = np.asarray(par)

    def walk(v, stop):
        out = []
        while v != stop:
            out.append(v)
            v = int(par[v])
        return out

    assert section_nodes(par, 2, 4, 5).tolist() == sorted(walk(4, 2) + walk(5, 2)) == [3, 4, 5]
    # A' at the side branch's tip: the path runs through M and the side branch, B' the other child of O'
    assert section_nodes(par, 2, 10, 5).tolist() == sorted(walk(10, 2) + walk(5, 2)) == [3, 5, 6, 7, 8, 9, 10]


def test_prune_bare_twigs_keeps_a_quarter(rng):
    # 200 synthetic single-node twigs on a stem, none supporting a leaf
    n = 200
    pos = np.vstack([[0, 0, 0], [0, 0, 1], rng.random((n, 3))])
    par = np.concatenate([[-1, 0], np.ones(n, int)])
    synth = np.concatenate([[False, False], np.ones(n, bool)])
    keep, kept = prune_bare_twigs(pos, par, synth, np.zeros(n + 2, bool), 0.25, rng)
    assert keep[:2].all() and 0.15 < keep[2:].mean() < 0.35 and len(kept) == keep[2:].sum()
    sup = np.zeros(n + 2, bool)
    sup[2:] = True
    keep, _ = prune_bare_twigs(pos, par, synth, sup, 0.25, rng)
    assert keep.all()


def test_branch_angle_moves_towards_murray():
    # parent thick, lateral thin: Eq. 3 predicts nearly 90 deg; the lateral leaves at 20 deg
    pos = np.array([[0, 0, 0], [0, 0, 1.0], [0, 0, 2.0], [np.sin(0.35), 0, 1 + np.cos(0.35)]])
    par = np.array([-1, 0, 1, 1])
    radii = np.array([0.1, 0.1, 0.09, 0.02])
    pred = np.degrees(murray_angle(0.1, 0.02))
    npos, npar, nrad, n = adjust_branch_angles(pos, par, radii, tolerance_deg=5, shift_limit=0.5)
    assert n == 1
    s = npar[3]
    new_angle = np.degrees(np.arccos(np.clip((npos[3] - npos[s])[2] / np.linalg.norm(npos[3] - npos[s]), -1, 1)))
    assert abs(new_angle - pred) < abs(np.degrees(0.35) - pred)
    assert np.isclose(npos[s][0], 0) and 1.0 < npos[s][2] <= 1.5  # the split moved up along the main axis


def test_stub_root_trees_are_dropped_but_real_stems_stay():
    """Three roots: a 1 m stem, a 0.5 m second stem and a 2 cm stub (a fragment of a stem base): with a 5 cm spur
    length only the stub's two nodes go."""
    from reference_impl.xu.pipeline import _stub_root_trees

    pos = np.array([[0, 0, 0], [0, 0, 1.0], [0.3, 0, 0], [0.3, 0, 0.5], [0.02, 0, 0], [0.02, 0, 0.02]], float)
    par = np.array([-1, 0, -1, 2, -1, 4])
    assert _stub_root_trees(pos, par, 0.05).tolist() == [True, True, True, True, False, False]
    # a lone short tree is never dropped
    assert _stub_root_trees(pos[4:], np.array([-1, 0]), 0.05).all()


def test_empty_segments_against_dense_sampling(rng):
    """empty_segments flags a segment with a point farther than the tolerance from the cloud, never one whose every
    point is within it (checked against the segment sampled 200 times densely, with brute-force distances)."""
    from scipy.spatial import cKDTree

    from reference_impl.common.graph import empty_segments

    # a cloud along two strands with a 0.3 m gap in the first
    strand = np.r_[np.linspace(0, 1.0, 400), np.linspace(1.3, 2.0, 300)]
    cloud = np.vstack([np.c_[strand, np.zeros_like(strand), np.zeros_like(strand)],
                       np.c_[np.linspace(0, 2, 800), np.full(800, 0.5), np.zeros(800)]])
    cloud += rng.normal(0, 0.002, cloud.shape)
    tol = 0.05
    a = rng.uniform([-0.1, -0.2, -0.05], [2.1, 0.7, 0.05], (300, 3))
    b = a + rng.normal(0, 0.4, (300, 3)) * [1, 0.3, 0.1]
    got = empty_segments(a, b, cKDTree(cloud), tol)
    t = np.linspace(0, 1, 200)
    dmax = np.array([np.min(np.linalg.norm((p + t[:, None] * (q - p))[:, None] - cloud[None], axis=2), axis=1).max()
                     for p, q in zip(a, b)])
    assert np.all(got[dmax > 1.5 * tol + 1e-3])  # a point farther than 1.5 tol: always empty
    assert not np.any(got[dmax < tol - 1e-3])  # every point within tol: never empty
    assert (dmax > 1.5 * tol).sum() > 20 and (dmax < tol).sum() > 5  # both kinds occur
    # the gap: a segment along the first strand across it is empty, the same along the full second strand is not
    assert empty_segments(np.array([[0.8, 0, 0]]), np.array([[1.5, 0, 0]]), cKDTree(cloud), tol)[0]
    assert not empty_segments(np.array([[0.8, 0.5, 0]]), np.array([[1.5, 0.5, 0]]), cKDTree(cloud), tol)[0]


def test_synthesis_refuses_copies_across_empty_space():
    """Issue 25: with the input cloud given, a copy any of whose edges crosses empty space is refused;
    where the cloud has points along the copy, the same synthesis goes ahead."""
    from scipy.spatial import cKDTree

    pos, par, locs, dens = _fork_and_leaves()
    kw = dict(d0=0.08, interval=(20.0, 60.0), group=0.02, iterations=3, max_nodes=1000)
    free = synthesize(pos, par, locs, dens, **kw)
    assert free.synthetic.sum() > 0 and free.refused == 0
    # cloud: the scanned skeleton's own points only (the leaves float in empty space beside it)
    t = np.linspace(0, 1, 50)[:, None]
    own = np.vstack([pos[par[c]] + t * (pos[c] - pos[par[c]]) for c in range(1, len(pos))])
    sparse = synthesize(pos, par, locs, dens, cloud=cKDTree(own), tolerance=0.03, **kw)
    assert sparse.refused > 0 and sparse.synthetic.sum() == 0
    # cloud filled around the copies the free synthesis made: they go ahead, and each new edge is on the cloud
    new = np.flatnonzero(free.synthetic)
    fill = np.vstack([own] + [free.positions[free.parents[c]] + t * (free.positions[c] - free.positions[free.parents[c]])
                              for c in new])
    full = synthesize(pos, par, locs, dens, cloud=cKDTree(fill), tolerance=0.03, **kw)
    assert full.synthetic.sum() == free.synthetic.sum() and full.refused == 0
    np.testing.assert_allclose(full.positions, free.positions)


def test_synthesis_reach_limits_the_association():
    """A location whose nearest feasible node lies beyond ``max_reach`` gets no copy (never across the crown)."""
    pos, par, locs, dens = _fork_and_leaves()
    node, nd, _ = support(locs, pos, par, d0=0.08, interval=(20.0, 60.0))
    kw = dict(d0=0.08, interval=(20.0, 60.0), group=0.02, iterations=1, max_nodes=1000)
    near = synthesize(pos, par, locs, dens, max_reach=float(nd.max()) + 1e-9, **kw)
    far = synthesize(pos, par, locs, dens, max_reach=float(nd[node >= 0].min()) - 1e-9, **kw)
    assert near.synthetic.sum() > 0 and far.synthetic.sum() == 0


def test_branch_angle_two_split_points_on_one_edge_keep_the_axis():
    """A split whose lateral leaves too steeply moves its S up the edge to its main child, and that child's own
    lateral leaves downwards, so its S moves down the same edge. Whatever the order the splits are visited in (the
    child here has the lower index), both points must end on the axis: walking down the thickest children from the
    root reaches the top, every inserted point with the axis radius carries the axis, and the axis keeps its length
    (the points are inserted in order along the edge, no zig-zag)."""
    up, down = np.radians(15.0), np.radians(160.0)
    pos = np.array([[0, 0, 0], [0, 0, 2.0], [0, 0, 1.0], [0, 0, 3.0],
                    [0.3 * np.sin(up), 0, 1 + 0.3 * np.cos(up)],      # lateral of node 2 (z 1), steep
                    [0.3 * np.sin(down), 0, 2 + 0.3 * np.cos(down)]])  # lateral of node 1 (z 2), hanging
    par = np.array([-1, 2, 0, 1, 2, 1])
    radii = np.array([0.1, 0.1, 0.1, 0.1, 0.02, 0.02])
    npos, npar, nrad, n = adjust_branch_angles(pos, par, radii, tolerance_deg=5, shift_limit=0.5)
    assert n == 2 and len(npos) == 8
    kids = [np.flatnonzero(npar == i) for i in range(len(npar))]
    node, axis = 0, [0]
    while len(kids[node]):
        node = int(kids[node][np.argmax(nrad[kids[node]])])
        axis.append(node)
    assert node == 3  # the thickest-child walk reaches the top of the axis
    for s in (6, 7):  # both inserted points on the axis, each with an axis-radius child
        assert s in axis and nrad[kids[s]].max() == 0.1
    z = npos[axis, 2]
    assert np.all(np.diff(z) > 0) and np.allclose(npos[axis, :2], 0)  # in order along the axis
    for lat in (4, 5):  # each lateral hangs from an inserted point
        assert npar[lat] in (6, 7)
