"""A small synthetic view capture with exact ground truth (analytic scene, no renderer), shared by the mvs tests."""

from __future__ import annotations

import numpy as np
import pytest

from reference_impl.mvs import synthetic


@pytest.fixture(scope="session")
def scene() -> synthetic.Scene:
    return synthetic.default_scene()


@pytest.fixture(scope="session")
def ring():
    """16 cameras at 128 x 128 px around the scene (22.5 deg apart)."""
    return synthetic.ring_cameras(16, width=128, height=128, radius=2.6)


@pytest.fixture(scope="session")
def views(scene, ring):
    """(image, depth, instance) of view 0 of ``ring`` and of its four nearest views, by view index."""
    return {i: synthetic.render(scene, ring[i], supersample=2) for i in (0, 1, 2, 14, 15)}


@pytest.fixture(scope="session")
def case(tmp_path_factory, scene, ring):
    """A case folder (views/ + plant/plant.json) of ``ring``."""
    case = tmp_path_factory.mktemp("mvs") / "case"
    synthetic.write_case(case, scene, ring, supersample=1)
    return case


def analytic_distance(scene: synthetic.Scene, points: np.ndarray, *, ground: bool = True) -> np.ndarray:
    """Exact distance from ``points`` (n, 3) to the scene's surfaces (independent of the engine)."""
    ds = [np.abs(np.linalg.norm(points - s[:3], axis=1) - s[3]) for s in scene.spheres]
    for d in scene.discs:
        c, n, r = d[:3], d[3:6], d[6]
        v = points - c
        h = v @ n
        rr = np.linalg.norm(v - h[:, None] * n, axis=1)
        ds.append(np.sqrt(h**2 + np.maximum(rr - r, 0) ** 2))
    if ground:
        ds.append(np.abs(points[:, 2]))
    return np.min(ds, axis=0)
