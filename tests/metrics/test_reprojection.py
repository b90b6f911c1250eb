"""Reprojection error: hand-counted masks, and ray-cast silhouettes against the analytic projection of a square."""

from __future__ import annotations

import numpy as np
import pytest

from plantbench.cameras import look_at
from plantbench.errors import InputError
from plantbench.metrics.reprojection import render_silhouettes, reprojection_error
from plantbench.plant import TriMesh


def test_error_equals_hand_count():
    gt = np.zeros((6, 8), bool)
    gt[1:4, 2:6] = True  # 12 pixels
    pred = np.zeros((6, 8), bool)
    pred[2:5, 3:7] = True  # 12 pixels, overlap rows 2-3 x cols 3-5 = 6
    # XOR = 12 + 12 - 2 * 6 = 12 -> 12 / 12 = 1.0; IoU = 6 / 18
    empty_gt = np.zeros((6, 8), bool)
    res = reprojection_error([gt, gt, empty_gt], [pred, gt, pred])
    assert res.per_view_error[0] == 1.0 and res.per_view_error[1] == 0.0 and np.isnan(res.per_view_error[2])
    assert res.error == 0.5  # the view with an empty reference is left out
    assert res.per_view_iou.tolist() == [6 / 18, 1.0, 0.0]
    over = np.ones((6, 8), bool)  # 48 pixels: XOR = 36 -> 3.0, above 1
    assert reprojection_error([gt], [over]).error == 3.0
    assert reprojection_error([empty_gt], [empty_gt]).error is None
    assert reprojection_error([empty_gt], [empty_gt]).iou == 1.0


def test_bad_input():
    m = np.zeros((4, 4), bool)
    with pytest.raises(InputError, match="2 reference masks but 1"):
        reprojection_error([m, m], [m])
    with pytest.raises(InputError, match="shapes"):
        reprojection_error([m], [np.zeros((4, 5), bool)])
    with pytest.raises(InputError, match="no views"):
        reprojection_error([], [])


def test_silhouette_matches_projection_of_a_square():
    cam = look_at((0.0, -3.0, 0.5), (0.0, 0.0, 0.5), fov_x_deg=40, width=64, height=48)
    # a square in the plane y = 0, x in [-0.4, 0.4], z in [0.2, 0.9]
    v = np.array([[-0.4, 0, 0.2], [0.4, 0, 0.2], [0.4, 0, 0.9], [-0.4, 0, 0.9]])
    mesh = TriMesh(v, np.array([[0, 1, 2], [0, 2, 3]]))
    (sil,) = render_silhouettes(mesh, [cam])
    uv, _ = cam.project(v)
    u_lo, u_hi = uv[:, 0].min(), uv[:, 0].max()
    v_lo, v_hi = uv[:, 1].min(), uv[:, 1].max()
    uu, vv = np.meshgrid(np.arange(64), np.arange(48))
    want = (uu > u_lo) & (uu < u_hi) & (vv > v_lo) & (vv < v_hi)
    assert want.sum() > 100
    assert np.array_equal(sil, want)
    assert not render_silhouettes(TriMesh.empty(), [cam])[0].any()


@pytest.mark.parametrize(("size", "stride"), [((512, 384), 1), ((1024, 768), 2), ((1023, 1024), 2), ((2048, 1536), 4)])
def test_strided_camera_casts_through_the_views_own_pixels(size, stride):
    """A view larger than MAX_PX is scored on every s-th pixel: the strided camera projects a point to (u / s, v / s)
    of the full camera's pixel, its image is mask[::s, ::s]'s size, and its silhouette is the full silhouette at those
    pixels, exactly (a slanted triangle fan, so that edges cut pixels at every phase)."""
    from plantbench.metrics.reprojection import MAX_PX, strided

    w, h = size
    cam = look_at((0.3, -3.0, 0.8), (0.0, 0.0, 0.5), fov_x_deg=40, width=w, height=h)
    small, s = strided(cam)
    assert s == stride and max(small.width, small.height) <= MAX_PX
    assert (small.height, small.width) == np.zeros((h, w))[::s, ::s].shape
    pts = np.random.default_rng(0).uniform(-0.5, 0.5, (50, 3)) + [0, 0, 0.5]
    assert np.allclose(small.project(pts)[0] * s, cam.project(pts)[0], atol=1e-9)
    if s > 1 and w * h <= 1024 * 1024:
        ang = np.linspace(0, 2 * np.pi, 14)
        v = np.concatenate([[[0, 0, 0.5]], np.stack([0.45 * np.cos(ang), 0.2 * np.sin(3 * ang), 0.5 + 0.35 *
                                                     np.sin(ang)], 1)])
        mesh = TriMesh(v, np.array([[0, i, i + 1] for i in range(1, 14)]))
        (full,) = render_silhouettes(mesh, [cam])
        (part,) = render_silhouettes(mesh, [small])
        assert part.any() and np.array_equal(part, full[::s, ::s])
