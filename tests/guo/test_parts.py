"""Weights (Eq. 8), roots (Fig. 9), hull fill (Fig. 8) and refinement against naive or analytic answers."""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull, Delaunay, cKDTree

from reference_impl.guo.hull import crown_mask, poisson_disk_in_hull, shell_ratio
from reference_impl.guo.refine import collapse, smooth
from reference_impl.guo.roots import density_roots, root_axes_and_radii
from reference_impl.guo.weights import eq8_weights, point_weights, principal_directions


def test_weights_match_a_naive_count(rng):
    pts = rng.random((300, 3)) * 0.2
    dirs = principal_directions(pts, 0.04, max_neighbours=300, min_neighbours=6)
    w = point_weights(pts, dirs, 0.05, 0.9, max_neighbours=300)
    d = np.linalg.norm(pts[:, None] - pts[None], axis=2)
    agree = np.abs(dirs @ dirs.T) > 0.9
    np.testing.assert_array_equal(w, np.sum((d < 0.05) & agree, axis=1))
    dirs2, w2 = eq8_weights(pts, 0.04, 0.9, max_neighbours=300)
    np.testing.assert_allclose(np.abs(np.sum(dirs2 * dirs, 1)), 1.0, atol=1e-9)
    np.testing.assert_array_equal(w2, point_weights(pts, dirs2, 0.04, 0.9, max_neighbours=300))
    # naive PCA of the 0.04 ball (at least the 6 nearest points)
    for i in range(0, 300, 7):
        order = np.argsort(d[i])
        sel = order[(d[i][order] < 0.04) | (np.arange(300) < 6)]
        q = pts[sel] - pts[sel].mean(0)
        v = np.linalg.eigh(q.T @ q)[1][:, 2]
        assert abs(abs(v @ dirs[i]) - 1) < 1e-6


def test_branch_points_outweigh_leaf_points(rng):
    # a thin cylinder (branch) and a scatter of small randomly oriented discs (leaves), same point density
    t = rng.random(2000)
    ang = rng.uniform(0, 2 * np.pi, 2000)
    branch = np.c_[0.004 * np.cos(ang), 0.004 * np.sin(ang), t * 0.5]
    leaves = []
    for c in rng.random((40, 3)) * 0.5 + [0.3, 0, 0]:
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        u = np.cross(n, [1.0, 0, 0])
        u /= np.linalg.norm(u)
        v = np.cross(n, u)
        r = 0.02 * np.sqrt(rng.random(50))
        a = rng.uniform(0, 2 * np.pi, 50)
        leaves.append(c + (r * np.cos(a))[:, None] * u + (r * np.sin(a))[:, None] * v)
    pts = np.concatenate([branch] + leaves)
    w = point_weights(pts, principal_directions(pts, 0.02), 0.02, 0.9)
    assert w[:2000].mean() > 2 * w[2000:].mean()


def test_density_roots_find_the_stems(rng):
    centres = np.array([[0.0, 0.0], [0.6, 0.1], [-0.3, 0.7]])
    counts = [900, 600, 300]
    xy = np.concatenate([c + rng.normal(0, 0.02, (k, 2)) for c, k in zip(centres, counts)]
                        + [rng.uniform(-1, 1, (200, 2))])
    res = density_roots(xy, 0.05)
    assert len(res.centroids) == 3
    for c in centres:
        assert np.min(np.linalg.norm(res.centroids - c, axis=1)) < 0.03
    assert np.all(np.diff(res.density) <= 0)
    top2 = density_roots(xy, 0.05, k=2)
    np.testing.assert_allclose(np.sort(top2.centroids[:, 0]), np.sort(centres[:2, 0]), atol=0.03)


def test_trunk_radius_from_a_cylinder(rng):
    n = 3000
    z = rng.random(n) * 1.0
    a = rng.uniform(0, 2 * np.pi, n)
    pts = np.c_[0.2 + 0.03 * np.cos(a), -0.1 + 0.03 * np.sin(a), z] + rng.normal(0, 0.001, (n, 3))
    base, axis, radius = root_axes_and_radii(pts, pts[:, 2], np.array([[0.21, -0.1]]), np.zeros(1), height=1.0,
                                             fit_height=0.1, fallback=0.5)
    assert abs(radius[0] - 0.03) < 0.003
    np.testing.assert_allclose(base[0, :2], [0.2, -0.1], atol=0.005)
    assert axis[0, 2] > 0.98


def test_a_thick_trunk_is_one_root_on_its_axis(rng):
    # a 0.44 m trunk's bark projects to a ring 18 cells across: one cluster, centred on the axis (a window around
    # the ring's densest cell put the root on the bark), and the circle fit gives its radius
    n = 6000
    a = rng.uniform(0, 2 * np.pi, n)
    z = rng.random(n) * 1.0
    pts = np.c_[1.0 + 0.44 * np.cos(a), 2.0 + 0.44 * np.sin(a), z] + rng.normal(0, 0.003, (n, 3))
    res = density_roots(pts[:, :2], 0.05)
    assert len(res.centroids) == 1
    np.testing.assert_allclose(res.centroids[0], [1.0, 2.0], atol=0.03)
    base, axis, radius = root_axes_and_radii(pts, pts[:, 2], res.centroids, np.zeros(1), height=10.0,
                                             fit_height=0.06, fallback=0.05)
    assert abs(radius[0] - 0.44) < 0.02
    np.testing.assert_allclose(base[0, :2], [1.0, 2.0], atol=0.01)


def test_leaves_beside_a_thin_stem_do_not_tilt_it(rng):
    # a vertical 2.5 cm stem with a dense leaf cluster 6 cm to one side in the upper half of the fit band: the
    # axis comes from the points near the fitted circle (the band's centroids would tilt it towards the leaves)
    n = 800
    a = rng.uniform(0, 2 * np.pi, n)
    stem = np.c_[0.025 * np.cos(a), 0.025 * np.sin(a), rng.random(n) * 0.1] + rng.normal(0, 0.0005, (n, 3))
    leaves = np.c_[0.06 + rng.normal(0, 0.01, (600, 2)), rng.uniform(0.035, 0.06, 600)]
    pts = np.concatenate([stem, leaves])
    base, axis, radius = root_axes_and_radii(pts, pts[:, 2], np.array([[0.0, 0.0]]), np.zeros(1), height=1.0,
                                             fit_height=0.06, fallback=0.05)
    assert np.degrees(np.arccos(axis[0, 2])) < 3.0
    assert abs(radius[0] - 0.025) < 0.003
    np.testing.assert_allclose(base[0, :2], [0.0, 0.0], atol=0.003)


def test_poisson_disk_samples_fill_the_hull(rng):
    pts = rng.normal(size=(500, 3))
    samples, spacing = poisson_disk_in_hull(pts, 0.3, rng)
    assert spacing == 0.3
    hull = ConvexHull(pts)
    assert np.all(Delaunay(pts[hull.vertices]).find_simplex(samples) >= 0)
    d, _ = cKDTree(samples).query(samples, k=2)
    assert d[:, 1].min() >= 0.3
    # close to maximal: a random point of the hull is within one spacing of a sample
    probe = rng.normal(size=(2000, 3)) * 0.5
    probe = probe[Delaunay(pts[hull.vertices]).find_simplex(probe) >= 0]
    assert np.mean(cKDTree(samples).query(probe)[0] < 0.3) > 0.97
    capped, sp2 = poisson_disk_in_hull(pts, 0.05, rng, max_samples=300)
    assert len(capped) <= 300 and sp2 > 0.05


def test_shell_ratio_tells_a_shell_from_a_ball(rng):
    v = rng.normal(size=(4000, 3))
    shell = v / np.linalg.norm(v, axis=1, keepdims=True)
    ball = shell * rng.random((4000, 1)) ** (1 / 3)
    assert shell_ratio(shell, rng) < 0.2
    assert 0.7 < shell_ratio(ball, rng) < 1.3


def test_crown_mask_cuts_the_bare_trunk(rng):
    trunk = np.c_[rng.normal(0, 0.01, (500, 2)), rng.random(500) * 1.0]
    crown = rng.normal(0, 0.4, (3000, 3)) + [0, 0, 1.6]
    pts = np.concatenate([trunk, crown[crown[:, 2] > 1.0]])
    m = crown_mask(pts, pts[:, 2])
    assert m[:500][trunk[:, 2] < 0.8].sum() == 0
    assert m[500:].mean() > 0.95


def test_collapse_keeps_bends_and_junctions():
    # a straight chain of 10 nodes, a 30 deg bend, then 5 more straight nodes; a side branch at node 3
    pos = [np.array([0.0, 0, 0.1 * i]) for i in range(10)]
    d = np.array([np.sin(np.radians(30)), 0, np.cos(np.radians(30))])
    pos += [pos[9] + 0.1 * (i + 1) * d for i in range(5)]
    pos.append(pos[3] + [0.1, 0.0, 0.0])
    par = np.r_[-1, np.arange(14), 3]
    pos = np.array(pos)
    keep, new_par = collapse(pos, par, np.full(16, 0.01), max_angle_deg=10, max_radius_change=0.1)
    assert keep[[0, 3, 9, 14, 15]].all()            # root, junction, bend, tips
    assert keep.sum() == 5
    kept = pos[keep]
    # the kept skeleton still runs root -> junction -> bend -> tip
    c = new_par >= 0
    assert np.isclose(np.sum(np.linalg.norm(kept[c] - kept[new_par[c]], axis=1)), 1.4 + 0.1)
    # different radii are not collapsed
    keep2, _ = collapse(pos, par, np.linspace(0.05, 0.001, 16), max_angle_deg=10, max_radius_change=0.1)
    assert keep2.sum() > 5


def test_smooth_rounds_chain_corners_but_not_junctions():
    # chain with a 90 deg corner at node 2; junction at node 4 with two children at +-40 deg
    pos = np.array([[0, 0, 0], [0, 0, 0.1], [0, 0, 0.2], [0.1, 0, 0.2], [0.2, 0, 0.2],
                    [0.2 + 0.1 * np.cos(0.7), 0, 0.2 + 0.1 * np.sin(0.7)],
                    [0.2 + 0.1 * np.cos(0.7), 0, 0.2 - 0.1 * np.sin(0.7)]], float)
    par = np.array([-1, 0, 1, 2, 3, 4, 4])
    out, new_par, origin = smooth(pos, par, angle_deg=20, min_spacing=0.0)
    assert 2 not in origin.tolist()                  # the corner node is replaced by a curve
    assert np.sum(origin < 0) >= 2
    j = int(np.flatnonzero(origin == 4)[0])
    for child in (5, 6):                             # the junction's children keep their directions
        c = int(np.flatnonzero(origin == child)[0])
        assert new_par[c] == j
        np.testing.assert_allclose(out[c] - out[j], pos[child] - pos[4])


def test_species_prior_comes_from_the_published_hint():
    """guo's prior is the hint file's values (scenes/hints), not the generator's species parameters."""
    import tomllib

    from plantbench.paths import scenes_dir
    from reference_impl.guo import species_prior

    for name in ("wp_conifer", "cercis", "maple"):
        hint = tomllib.loads((scenes_dir() / "hints" / f"{name}.toml").read_text())
        prior = species_prior(name)
        assert (prior.internode_length, prior.roll_angle, prior.branching_angle, prior.diameter_coefficient,
                prior.tip_radius) == (hint["internode_length"], hint["roll_angle"], hint["branching_angle"],
                                      hint["diameter_coefficient"], hint["twig_radius"])
        assert prior.roots == (None if hint["multi_stem"] else 1)
        assert prior.leaves.length == hint["leaf_length"] and prior.leaves.arrangement == hint["leaf_arrangement"]
        assert prior.leaves.divergence == hint["roll_angle"]
    # the generator's conifer limbs droop at 55-80 degrees; the botanist's hint says 70
    assert species_prior("wp_conifer").branching_angle == 70.0


def test_select_leaves_keeps_supported_leaves_once(rng):
    """Leaves on a chain of nodes; the 'cloud' samples the blades of every third leaf, twice over (two copies of a
    leaf at the same place). The kept leaves are exactly the sampled ones, one per place, with a consistent mesh."""
    from dataclasses import replace

    from plantbench.geometry.tubes import node_frames
    from plantbench.geometry.vectors import levels
    from plantbench.plant import TriMesh
    from reference_impl.guo.leaves import LeafConfig, place_leaves
    from reference_impl.guo.pipeline import select_leaves

    n = 13
    pos = np.c_[np.zeros(n), np.zeros(n), np.arange(n) * 0.2]
    par = np.arange(n) - 1
    main = par >= 0
    tangent, normal, _, _ = node_frames(pos, par, main)
    fol = place_leaves(pos, par, np.full(n, 0.001), main, tangent, normal, levels(par), np.ones(n, bool),
                       LeafConfig(length=0.08), rng)
    m = len(fol.leaves)
    q = (len(fol.mesh.vertices) - 6 * m) // m
    blades = fol.mesh.vertices[: m * q].reshape(m, q, 3)
    seen = np.arange(m) % 3 == 0
    cloud = np.concatenate([blades[seen].reshape(-1, 3), rng.normal(0, 5.0, (50, 3)) + [0, 0, 40]])
    # duplicate every leaf: the copy k + m sits on leaf k
    mesh2 = TriMesh(np.concatenate([blades.reshape(-1, 3), blades.reshape(-1, 3),
                                    fol.mesh.vertices[m * q:], fol.mesh.vertices[m * q:]]), np.zeros((0, 3), int))
    leaves2 = fol.leaves + [replace(lf, id=lf.id + m) for lf in fol.leaves]
    spacing = float(np.median(cKDTree(cloud).query(cloud, k=2)[0][:, 1]))
    kept_mesh, kept, counts = select_leaves(mesh2, leaves2, cKDTree(cloud), spacing, support=1.5, dedup=True)
    # naive: a leaf is supported when every blade vertex is a cloud point (distance 0)
    assert counts["unsupported"] == 2 * int((~seen).sum())
    assert counts["duplicates"] == int(seen.sum())
    assert [lf.id for lf in kept] == list(range(int(seen.sum())))
    assert sorted(lf.node for lf in kept) == sorted(lf.node for lf, s in zip(fol.leaves, seen) if s)
    np.testing.assert_allclose(kept_mesh.vertices[: len(kept) * q], blades[seen].reshape(-1, 3))
    # the real mesh (with faces) keeps exactly the kept leaves' faces, re-indexed onto their vertices
    kmesh, kl, _ = select_leaves(fol.mesh, fol.leaves, cKDTree(cloud), spacing, support=1.5, dedup=True)
    assert len(kl) == int(seen.sum()) and len(kmesh.faces) == len(fol.mesh.faces) * len(kl) // m
    assert kmesh.faces.max() == len(kmesh.vertices) - 1
    np.testing.assert_allclose(kmesh.vertices[kmesh.faces[0]], fol.mesh.vertices[fol.mesh.faces[0]])
    # support 0 and no dedup: unchanged
    same_mesh, same, c0 = select_leaves(fol.mesh, fol.leaves, cKDTree(cloud), spacing, support=0.0, dedup=False)
    assert same_mesh is fol.mesh and len(same) == m and c0 == {"unsupported": 0, "duplicates": 0}


def test_hint_leaves_follow_the_arrangement_and_length(rng):
    """guo's own leaf placement: opposite leaves come in pairs half a turn apart, spiral ones one per node, whorls
    per_whorl; thick nodes and ineligible nodes bear none; every blade has the hint's length."""
    from plantbench.geometry.tubes import node_frames
    from plantbench.geometry.vectors import levels
    from reference_impl.guo.leaves import LeafConfig, place_leaves

    n = 9
    pos = np.c_[np.zeros(n), np.zeros(n), np.arange(n) * 0.1]
    par = np.arange(n) - 1
    radii = np.where(np.arange(n) < 3, 0.01, 0.001)       # nodes 0-2 too thick to bear leaves
    eligible = np.arange(n) != 5                           # node 5 excluded by the caller
    main = par >= 0
    tangent, normal, _, _ = node_frames(pos, par, main)
    bearing = [i for i in range(1, n) if radii[i] <= 0.002 and eligible[i]]
    for arrangement, per in (("spiral", 1), ("opposite", 2), ("whorl", 3)):
        cfg = LeafConfig(length=0.07, arrangement=arrangement)
        placed = place_leaves(pos, par, radii, main, tangent, normal, levels(par), eligible, cfg, rng)
        assert [lf.node for lf in placed.leaves] == [i for i in bearing for _ in range(per)]
        assert all(lf.length == 0.07 for lf in placed.leaves)
        m = len(placed.leaves)
        q = (len(placed.mesh.vertices) - 6 * m) // m
        assert len(placed.mesh.vertices) == m * (q + 6) and placed.mesh.faces.max() == len(placed.mesh.vertices) - 1
        if arrangement == "opposite":  # the two blade bases of a node lie on opposite sides of the stem
            b = np.array([lf.transform[:2, 3] for lf in placed.leaves]).reshape(-1, 2, 2)
            cos = np.sum(b[:, 0] * b[:, 1], axis=1) / np.linalg.norm(b[:, 0], axis=1) / np.linalg.norm(b[:, 1], axis=1)
            assert np.all(cos < -0.5)  # pi apart, up to the 10-degree azimuth jitter of each
