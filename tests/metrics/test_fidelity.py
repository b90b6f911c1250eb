"""The calibrated fidelity metrics against brute-force and hand computations: volume-weighted skeleton P/R/F1 at
height-relative tolerances, the GT-free skeleton support, strict leaf detection against the leaf spacing."""

from __future__ import annotations

import numpy as np
import pytest

from plantbench.errors import InputError
from plantbench.metrics.leaves import SPACING_FRACTION, leaf_detection, median_spacing
from plantbench.metrics.skeleton import (
    sample_skeleton,
    sample_weights,
    skeleton_coverage,
    skeleton_prf,
    skeleton_support,
)
from plantbench.plant import Skeleton

from .synth import random_tree

EMPTY = Skeleton(np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64))
ONE = Skeleton(np.zeros((1, 3)), np.full(1, 0.01), np.array([-1]))


def _naive_weighted(gt: Skeleton, pred: Skeleton, tau: float, step: float) -> tuple[float, float]:
    """Precision and recall by explicit loops over edges: each edge cut into ceil(len / step) equal pieces, a piece
    at its start point weighing pi r(start)^2 x piece length; distances by brute force over all samples."""
    def pieces(s: Skeleton):
        pts, w = [], []
        for c in range(len(s)):
            p = s.parents[c]
            if p < 0:
                continue
            a, b = s.positions[p], s.positions[c]
            n = max(1, int(np.ceil(np.linalg.norm(b - a) / step)))
            for i in range(n):
                f = i / n
                r = s.radii[p] + f * (s.radii[c] - s.radii[p])
                pts.append(a + f * (b - a))
                w.append(np.pi * r * r * np.linalg.norm(b - a) / n)
        return np.array(pts).reshape(-1, 3), np.array(w)

    def all_samples(s: Skeleton):
        pts, _ = pieces(s)
        return np.concatenate([pts, s.positions])

    pg, wg = pieces(gt)
    pp, wp = pieces(pred)
    sg, sp = all_samples(gt), all_samples(pred)
    d_p = np.array([np.min(np.linalg.norm(sg - x, axis=1)) for x in pp])
    d_g = np.array([np.min(np.linalg.norm(sp - x, axis=1)) for x in pg])
    return float(wp[d_p < tau].sum() / wp.sum()), float(wg[d_g < tau].sum() / wg.sum())


@pytest.mark.parametrize("shift", [0.0, 0.004, 0.02])
def test_volume_weighted_prf_brute_force(rng, shift):
    gt = random_tree(rng, 6, seg_len=0.04, trunk_segments=8)
    moved = gt.positions + rng.normal(0, shift, gt.positions.shape)
    pred = Skeleton(moved, gt.radii * rng.uniform(0.5, 1.5, len(gt)), gt.parents)
    height = float(gt.positions[:, 2].max())
    out = skeleton_prf(gt, pred, step=0.005, height=height)
    for f, lab in ((0.005, "0.5%"), (0.01, "1%"), (0.02, "2%")):
        p, r = _naive_weighted(gt, pred, f * height, 0.005)
        assert out[f"vprecision@{lab}"] == pytest.approx(p, abs=1e-9)
        assert out[f"vrecall@{lab}"] == pytest.approx(r, abs=1e-9)
        assert out[f"vf1@{lab}"] == pytest.approx(2 * p * r / (p + r) if p + r else 0.0, abs=1e-9)


def test_volume_weighted_by_hand():
    # GT: a 1 m trunk of radius 0.1 and a sqrt(2) m twig of radius 0.01 on the ground (height 1 m; 1 % = 1 cm). The
    # prediction has the trunk only: recall = 0.01 / (0.01 + 0.0001 sqrt 2) of the wood (pi cancels), precision 1.
    # Unweighted, recall would be 1 / (1 + sqrt 2).
    gt = Skeleton(np.array([[0, 0, 0], [0, 0, 1.0], [1.0, 0, 0.0], [0, 1.0, 0.0]]),
                  np.array([0.1, 0.1, 0.01, 0.01]), np.array([-1, 0, -1, 2]))
    pred = Skeleton(np.array([[0, 0, 0], [0, 0, 1.0]]), np.array([0.1, 0.1]), np.array([-1, 0]))
    out = skeleton_prf(gt, pred, step=0.01, height=1.0)
    assert out["vprecision@1%"] == pytest.approx(1.0)
    assert out["vrecall@1%"] == pytest.approx(0.01 / (0.01 + 0.0001 * np.sqrt(2)), abs=1e-9)
    assert skeleton_prf(gt, pred, step=0.01)["recall@1.0"] < 0.45


def test_volume_weighted_degenerate():
    gt = Skeleton(np.array([[0, 0, 0], [0, 0, 1.0]]), np.full(2, 0.05), np.array([-1, 0]))
    out = skeleton_prf(gt, EMPTY, height=1.0)  # documented: empty -> 0
    assert out["vprecision@1%"] == 0.0 and out["vrecall@1%"] == 0.0 and out["vf1@1%"] == 0.0
    out = skeleton_prf(gt, ONE, height=1.0)  # no length: precision and F1 0, recall the wood within 1 cm of the node
    assert out["vprecision@1%"] == 0.0 and out["vf1@1%"] == 0.0
    assert out["vrecall@1%"] == pytest.approx(0.01, abs=0.0011)
    assert "vf1@1%" not in skeleton_prf(gt, gt)  # without a height: the radius-relative keys only
    with pytest.raises(InputError, match="height"):
        skeleton_prf(gt, gt, height=0.0)


def test_sample_weights_sum_to_length_and_volume(rng):
    t = random_tree(rng, 5)
    e = t.edges
    lengths = np.linalg.norm(t.positions[e[:, 1]] - t.positions[e[:, 0]], axis=1)
    assert sample_weights(t, 0.003, volume=False).sum() == pytest.approx(lengths.sum())
    assert len(sample_weights(t, 0.003)) == len(sample_skeleton(t, 0.003)[0])
    # volume of frusta ~ the weights' sum for a fine step (linear radius): pi/3 h (r0^2 + r0 r1 + r1^2)
    r0, r1 = t.radii[e[:, 0]], t.radii[e[:, 1]]
    frusta = (np.pi / 3 * lengths * (r0 * r0 + r0 * r1 + r1 * r1)).sum()
    assert sample_weights(t, 0.0005).sum() == pytest.approx(frusta, rel=0.02)


def test_skeleton_support_brute_force(rng):
    t = random_tree(rng, 6)
    obs = t.positions[rng.random(len(t)) < 0.5] + rng.normal(0, 0.01, (1, 3))
    tol = 0.015
    got, loose = skeleton_support(t, obs, tolerances=(tol, 1.0), step=0.002)
    assert loose == pytest.approx(1.0)
    pts, _ = sample_skeleton(t, 0.002)
    w = sample_weights(t, 0.002, volume=False)
    d = np.array([np.min(np.linalg.norm(obs - x, axis=1)) for x in pts])
    assert got == pytest.approx(w[d <= tol].sum() / w.sum())
    # a branch through empty space counts against: the whole skeleton near the points scores 1
    assert skeleton_support(t, sample_skeleton(t, 0.002)[0], tolerances=(tol,)) == [pytest.approx(1.0)]
    assert skeleton_support(ONE, obs, tolerances=(tol,)) is None
    assert skeleton_support(EMPTY, obs, tolerances=(tol,)) is None
    assert skeleton_support(t, np.zeros((0, 3)), tolerances=(tol,)) is None
    with pytest.raises(InputError):
        skeleton_support(t, obs, tolerances=(0.0,))


def test_skeleton_coverage_cylinder_and_brute_force(rng):
    """Points on a cylinder's bark are covered, points a tolerance beyond it are not; on a random tree the share
    matches a brute-force loop over every sample (distance to the sample minus its radius)."""
    n = 21
    stem = Skeleton(np.stack([np.zeros(n), np.zeros(n), np.linspace(0, 2, n)], 1), np.full(n, 0.2),
                    np.arange(-1, n - 1))
    phi = rng.uniform(0, 2 * np.pi, 500)
    z = rng.uniform(0.1, 1.9, 500)
    bark = np.stack([0.2 * np.cos(phi), 0.2 * np.sin(phi), z], 1)
    assert skeleton_coverage(stem, bark, tolerance=0.01) == pytest.approx(1.0)
    assert skeleton_coverage(stem, bark * [1.1, 1.1, 1.0], tolerance=0.01) == pytest.approx(0.0)  # 2 cm out
    half = np.concatenate([bark[:250], bark[250:] * [1.1, 1.1, 1.0]])
    assert skeleton_coverage(stem, half, tolerance=0.01) == pytest.approx(0.5)
    t = random_tree(rng, 6)
    obs = t.positions + rng.normal(0, 0.02, t.positions.shape)  # about half within the tolerance of the bark
    tol = 0.015
    pts, radii = sample_skeleton(t, 0.002)
    naive = np.mean([np.min(np.linalg.norm(pts - p, axis=1) - radii) <= tol for p in obs])
    assert 0.1 < naive < 0.9
    assert skeleton_coverage(t, obs, tolerance=tol, step=0.002) == pytest.approx(naive)
    assert skeleton_coverage(EMPTY, obs, tolerance=tol) is None
    assert skeleton_coverage(t, np.zeros((0, 3)), tolerance=tol) is None
    with pytest.raises(InputError):
        skeleton_coverage(t, obs, tolerance=0.0)


def test_median_spacing_brute_force(rng):
    c = rng.random((40, 3))
    d = np.linalg.norm(c[:, None] - c[None], axis=2)
    np.fill_diagonal(d, np.inf)
    assert median_spacing(c) == pytest.approx(float(np.median(d.min(1))))
    assert median_spacing(c[:1]) is None and median_spacing(np.zeros((0, 3))) is None


def test_strict_detection_not_passed_by_a_shuffled_crown(rng):
    # leaves in clusters of 5 around 200 twig tips in a 1 m crown, as a crown holds them: the same leaves moved by
    # 0.2 x the spacing are found; a plausible crown of the same shape (clusters around other tips) mostly is not,
    # whereas the lenient radius of the paper's column (half a 6 cm leaf length) is passed by it far more often
    tips = rng.uniform(-0.5, 0.5, (200, 3))
    g = (tips[:, None] + rng.normal(0, 0.01, (200, 5, 3))).reshape(-1, 3)
    other = (rng.uniform(-0.5, 0.5, (200, 3))[:, None] + rng.normal(0, 0.01, (200, 5, 3))).reshape(-1, 3)
    s = median_spacing(g)
    radius = SPACING_FRACTION * s
    near = g + 0.2 * s * rng.normal(size=g.shape) / np.sqrt(3)
    assert leaf_detection(g, near, radius=radius)["f1"] > 0.9
    strict = leaf_detection(g, other, radius=radius)["f1"]
    lenient = leaf_detection(g, other, radius=0.03)["f1"]
    assert strict < 0.1 and lenient > 2 * strict
