"""Sim(3) alignment and pycolmap SfM on the CPU."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from plantbench.errors import InputError
from reference_impl.mvs import synthetic
from reference_impl.mvs.sfm import run_sfm, umeyama


def test_umeyama_recovers_a_similarity(rng):
    src = rng.normal(size=(10, 3))
    r = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    dst = 2.5 * src @ r.T + np.array([1.0, -2.0, 0.5])
    s, rr, t = umeyama(src, dst)
    assert s == pytest.approx(2.5) and np.allclose(rr, r) and np.allclose(t, [1, -2, 0.5])


def test_umeyama_needs_three_points():
    with pytest.raises(InputError):
        umeyama(np.zeros((2, 3)), np.zeros((2, 3)))


@pytest.mark.slow
def test_sfm_registers_the_synthetic_views(tmp_path):
    cams = synthetic.ring_cameras(16, width=320, height=320, radius=2.4)
    synthetic.write_case(tmp_path / "c", synthetic.default_scene(), cams, supersample=1)
    names = [f"{i:04d}.png" for i in range(16)]
    res = run_sfm(tmp_path / "c" / "views" / "images", names, intrinsics="known", reference=cams, seed=0)
    assert len(res.registered) >= 14 and len(res.registered) + len(res.unregistered) == 16
    err = [np.linalg.norm(res.cameras[i].center - cams[i].center) for i in res.registered]
    assert np.median(err) < 0.02 * 2.4
    for i in res.registered:  # aligned rotations agree with the truth
        assert np.degrees(Rotation.from_matrix(res.cameras[i].R @ cams[i].R.T).magnitude()) < 2.0
