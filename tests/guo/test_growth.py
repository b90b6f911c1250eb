"""Growth (Guo et al. 2018, Eq. 5-7, 9; L-system 1) against hand computations and naive versions."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.spatial import cKDTree

from plantbench.geometry.vectors import levels
from reference_impl.guo.growth import (
    allometric_radii,
    assign_markers,
    grow,
    growing_buds,
    growth_units,
    influence_distance,
    logistic_height,
)
from reference_impl.guo.params import GENERIC_PRIOR, GuoParams

PRIOR = replace(GENERIC_PRIOR, internode_length=0.05, tip_radius=0.0005)


def test_growth_units_is_the_derivative_of_the_logistic_height():
    t = np.linspace(0, 40, 401)
    h = logistic_height(t, 100.0, 2.0, 0.3)
    assert h[0] == 2.0
    numeric = np.gradient(h, t)
    np.testing.assert_allclose(growth_units(t, 100.0, 2.0, 0.3)[2:-2], numeric[2:-2], rtol=2e-3)
    # integrating rho_t gives the height gained
    assert abs(np.trapezoid(growth_units(t, 100.0, 2.0, 0.3), t) - (h[-1] - h[0])) < 0.05


def test_influence_distance_clamps_and_floors():
    p = GuoParams(rho_min=1.0, rho_max=100.0)
    k = 120.0
    for t in (0, 5, 10, 20):
        rho = growth_units(t, k, 2.0, 0.3)
        r, d = influence_distance(t, k, 0.05, p)
        assert r == max(rho, 1.0) and d == r * 0.05
        r4, _ = influence_distance(t, k, 0.05, replace(p, integer_rho=True))
        assert r4 == max(np.floor(rho), 1.0)
    r, _ = influence_distance(0, k, 0.05, GuoParams())
    assert r == GuoParams().rho_min


def test_assign_markers_matches_brute_force(rng):
    markers = rng.random((400, 3))
    buds = rng.random((30, 3))
    dirs = rng.normal(size=(30, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    apical = rng.random(30) < 0.5
    got = assign_markers(markers, buds, dirs, apical, radius=0.3, cos_half_angle=np.cos(np.pi / 4), neighbours=30)
    for i, m in enumerate(markers):
        v = m - buds
        d = np.linalg.norm(v, axis=1)
        ok = (d < 0.3) & (np.sum(v * dirs, 1) >= np.cos(np.pi / 4) * d)
        want = int(np.flatnonzero(ok)[np.argmin(d[ok])]) if ok.any() else -1
        assert got[i] == want


def test_assign_markers_tie_goes_to_the_apical_bud():
    # the apical and the lateral bud of one node share its position; a marker in both cones feeds the apical one
    bud = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    dirs = np.array([[0.0, 0.0, 1.0], [np.sin(0.6), 0.0, np.cos(0.6)]])
    markers = np.array([[0.05, 0.0, 0.2], [0.0, 0.0, 0.2]])
    for order in ([0, 1], [1, 0]):
        got = assign_markers(markers, bud[order], dirs[order], np.array([True, False])[order], radius=1.0,
                             cos_half_angle=np.cos(np.pi / 4))
        assert np.all(got == order.index(0))


def test_allometric_radii_follow_eq5_at_a_junction():
    # root -> a (0.1 m) -> junction; child b: 0.3 m, child c: 0.1 m
    pos = np.array([[0, 0, 0], [0, 0, 0.1], [0, 0, 0.4], [0.1, 0, 0.1]], float)
    par = np.array([-1, 0, 1, 1])
    gamma = 0.45
    r = allometric_radii(pos, par, np.array([0.02]), gamma, levels=levels(par))
    l_b, l_c, own = 0.3, 0.1, 0.1
    # Eq. 5 with the parent's own internode in the sum (the ratios telescope)
    assert np.isclose(r[2] / r[1], (l_b / (l_b + l_c + own)) ** gamma)
    assert np.isclose(r[3] / r[1], (l_c / (l_b + l_c + own)) ** gamma)
    assert r[1] == r[0] == 0.02
    # dead nodes support nothing
    r2 = allometric_radii(pos, par, np.array([0.02]), gamma, levels=levels(par),
                          alive=np.array([True, True, True, False]))
    assert np.isclose(r2[2] / r2[1], (l_b / (l_b + own)) ** gamma)


def test_grow_follows_a_vertical_line_and_stops():
    z = np.arange(0.02, 2.0, 0.01)
    markers = np.c_[np.zeros_like(z), np.zeros_like(z), z]
    out = grow(markers, np.ones(len(z)), np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]), np.array([0.02]), 2.0,
               PRIOR, GuoParams())
    assert out.iterations < GuoParams().max_iterations
    top = out.positions[:, 2].max()
    assert 1.8 < top < 2.15
    # a single straight stem: every node near the axis, internodes of length l
    assert np.abs(out.positions[:, :2]).max() < 0.02
    c = out.parents >= 0
    np.testing.assert_allclose(np.linalg.norm(out.positions[c] - out.positions[out.parents[c]], axis=1), 0.05)


def test_growth_follows_both_limbs_of_a_fork(rng):
    """A trunk forking into two limbs 70 deg apart, sampled every centimetre: the default perception radius (4 l)
    keeps every node within 7 cm of the limbs, while Eq. 7's range [6 l, 12 l] lets a bud below the fork perceive
    both limbs and grow up between them (the averaging the defaults avoid, docs/tuning/guo.md)."""
    fork = np.array([0.0, 0.0, 0.5])
    tips = fork + np.array([[np.sin(np.radians(35)), 0.0, np.cos(np.radians(35))],
                            [-np.sin(np.radians(35)), 0.0, np.cos(np.radians(35))]])

    def polyline(step):
        parts = [np.linspace([0.0, 0.0, 0.0], fork, int(0.5 / step) + 1)]
        parts += [np.linspace(fork, tip, int(1.0 / step) + 1) for tip in tips]
        return np.concatenate(parts)

    samples = polyline(0.01)
    markers = samples + rng.normal(scale=0.003, size=samples.shape)
    limbs = cKDTree(polyline(0.001))
    far = {}
    for label, params in (("default", GuoParams()), ("wide", GuoParams(rho_min=6.0, rho_max=12.0))):
        g = grow(markers, np.ones(len(markers)), np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]), np.array([0.02]),
                 float(tips[0, 2]), PRIOR, params)
        far[label] = limbs.query(g.positions)[0].max()
    assert far["default"] < 0.07
    assert far["wide"] > 0.09


def test_two_roots_compete_and_growth_crosses_gaps(rng):
    # two stems, each with a crown cluster above it; the stems' markers stop at 0.6 m and resume at 1.2 m (a gap)
    markers, roots = [], np.array([[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    for x in (-1.0, 1.0):
        z = np.r_[np.arange(0.02, 0.6, 0.01), np.arange(1.2, 1.5, 0.01)]
        markers.append(np.c_[np.full_like(z, x), np.zeros_like(z), z])
        markers.append(np.array([x, 0, 1.8]) + rng.normal(0, 0.15, (300, 3)))
    markers = np.concatenate(markers)
    out = grow(markers, np.ones(len(markers)), roots, np.tile([0.0, 0, 1], (2, 1)), np.array([0.02, 0.02]), 2.0,
               PRIOR, GuoParams())
    assert out.markers_left < 0.05 * len(markers)
    root_of = np.arange(len(out.parents))
    for idx in levels(out.parents):
        c = idx[out.parents[idx] >= 0]
        root_of[c] = root_of[out.parents[c]]
    for r, x in zip(np.flatnonzero(out.parents < 0), (-1.0, 1.0)):
        mine = out.positions[root_of == r]
        assert mine[:, 2].max() > 1.7                 # crossed the gap and reached its crown
        assert np.all(np.sign(mine[:, 0]) == np.sign(x))  # and stayed on its side


def test_borchert_honda_bud_fate_by_hand():
    q = np.array([10.0, 0.0, 1.0, 4.0, 0.5])
    apical = np.array([True, False, False, False, False])
    # lit: 10, 1, 4, 0.5 -> mean 3.875; shares 2 q / 3.875 = 5.16, 0.52, 2.06, 0.26 metamers
    np.testing.assert_array_equal(growing_buds(q, apical, alpha=2.0, min_share=1.0), [True, False, False, True, False])
    apical[4] = True  # a lit apical bud grows whatever its share
    np.testing.assert_array_equal(growing_buds(q, apical, alpha=2.0, min_share=1.0), [True, False, False, True, True])
    np.testing.assert_array_equal(growing_buds(q, apical, alpha=2.0, min_share=0.0), q > 0)
    assert not growing_buds(np.zeros(3), np.zeros(3, bool), alpha=2.0, min_share=1.0).any()


def test_borchert_honda_thins_the_branching(rng):
    """A stem in a uniform crown of markers: without the bud-fate rule nearly every lateral bud that perceives a
    marker breaks; with it the weakly lit ones wait, and fewer branches grow into the same crown."""
    z = np.arange(0.02, 0.8, 0.01)
    crown = np.array([0.0, 0.0, 1.3]) + rng.uniform(-0.5, 0.5, (3000, 3))
    markers = np.concatenate([np.c_[np.zeros_like(z), np.zeros_like(z), z], crown])
    w = rng.uniform(0.2, 1.0, len(markers))
    args = (markers, w, np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]), np.array([0.02]), 1.8, PRIOR)
    tips = []
    for lv in (0.0, 1.0):
        out = grow(*args, GuoParams(lateral_vigour=lv))
        tips.append(int(np.sum(np.bincount(out.parents[out.parents >= 0], minlength=len(out.parents)) == 0)))
        assert out.positions[:, 2].max() > 1.6
    assert tips[1] < tips[0]
    # a share above bh_alpha's mean vigour: once the apical buds are unlit no lateral bud may grow, and growth stops
    out = grow(*args, GuoParams(lateral_vigour=10.0))
    assert out.history[-1].get("stopped") == "no bud grows"
    assert np.sum(out.lateral) == 0
