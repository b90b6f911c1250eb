"""The ray caster: Mitsuba and open3d agree with each other and with an analytic case; reusing the render scene's
BVH gives the same answers as a caster of its own."""

from __future__ import annotations

import numpy as np
import pytest

from plantbench.backend import select_variant
from plantbench.capture.raycast import RayCaster
from tests.capture.plants import make_plant

llvm = pytest.mark.skipif(not select_variant().startswith("llvm"), reason="Mitsuba ray casting needs llvm_ad_rgb")


def test_open3d_hits_a_square_analytically(rng):
    v = np.array([[-1, -1, 2], [1, -1, 2], [1, 1, 2], [-1, 1, 2]], float)
    quad = (v, np.array([[0, 1, 2], [0, 2, 3]]))
    below = (v - [0, 0, 1.5], np.array([[0, 1, 2]]))  # half a square at z = 0.5: hit first where present
    c = RayCaster([quad, below], backend="open3d")
    o = np.c_[rng.uniform(-0.9, 0.9, (500, 2)), np.zeros(500)]
    t, prim = c.cast(o, np.tile([0.0, 0.0, 1.0], (500, 1)))
    in_tri = o[:, 0] >= o[:, 1]  # triangle (0, 1, 2) of the lower square covers x >= y
    assert np.allclose(t[in_tri], 0.5, atol=1e-6) and np.all(prim[in_tri] == 2)
    assert np.allclose(t[~in_tri], 2.0, atol=1e-6) and np.all(prim[~in_tri] <= 1)
    t, prim = c.cast(o, np.tile([0.0, 0.0, -1.0], (500, 1)))
    assert np.all(np.isinf(t)) and np.all(prim == -1)
    t, _ = c.cast(o, np.tile([0.0, 0.0, 1.0], (500, 1)), tmax=1.0)
    assert np.all(np.isinf(t[~in_tri]))


@llvm
def test_mitsuba_agrees_with_open3d_and_scene_reuse(rng):
    from plantbench.backend import load_mitsuba
    from plantbench.capture.scene import scene_dict
    from plantbench.capture.settings import CaptureOptions
    from plantbench.capture.views import ground_truth_caster, ground_truth_parts

    plant = make_plant(height=4.0)
    parts = [(v, f) for v, f, _ in ground_truth_parts(plant)]
    o = np.array([6.0, -2.0, 2.0])
    d = rng.normal(0, 1, (20000, 3)) * [0.3, 1, 0.5] + [-1, 0.3, 0]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t_o, p_o = RayCaster(parts, backend="open3d").cast(o, d)
    t_m, p_m = RayCaster(parts, backend="mitsuba").cast(o, d)
    mi = load_mitsuba()
    sd = scene_dict(plant, [], CaptureOptions(), np.random.default_rng(0), mi=mi)
    t_s, p_s = ground_truth_caster(plant, scene=mi.load_dict(sd), scene_dict=sd).cast(o, d)
    assert (p_o >= 0).mean() > 0.3 and len(np.unique(p_o)) > 50
    assert np.mean(p_o == p_m) > 0.999 and np.array_equal(p_m, p_s)
    both = (p_o >= 0) & (p_m >= 0)
    assert np.allclose(t_o[both], t_m[both], atol=1e-4) and np.allclose(t_m, t_s)
