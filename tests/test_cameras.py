import numpy as np
import pytest

from plantbench.cameras import look_at, read_cameras, write_cameras
from plantbench.errors import InputError


def test_project_and_rays_agree(rng):
    cam = look_at([6.0, -3.0, 2.0], [0.0, 0.0, 1.5], fov_x_deg=50, width=80, height=60)
    origin, dirs = cam.pixel_rays()
    idx = rng.integers(0, 80 * 60, 50)
    pts = origin + dirs[idx] * rng.uniform(1, 10, (50, 1))
    uv, z = cam.project(pts)
    v, u = np.divmod(idx, 80)
    assert np.allclose(uv, np.stack([u, v], 1), atol=1e-9)
    assert np.all(z > 0)


def test_look_at_axes():
    cam = look_at([5.0, 0.0, 1.0], [0.0, 0.0, 1.0], fov_x_deg=90, width=100, height=100)
    # a point above the target appears above the image centre (smaller v); +y world is to the image right
    uv, _ = cam.project(np.array([[0.0, 0.0, 2.0], [0.0, 1.0, 1.0]]))
    assert uv[0, 1] < 49.5 and np.isclose(uv[0, 0], 49.5)
    assert uv[1, 0] > 49.5 and np.isclose(uv[1, 1], 49.5)
    # horizontal fov 90 deg: a point at 45 deg lands on the image edge (x = -0.5 or width - 0.5)
    uv, _ = cam.project(np.array([[0.0, 5.0, 1.0]]))
    assert np.isclose(uv[0, 0], 99.5)


def test_cameras_json_roundtrip(tmp_path):
    cams = [look_at([5, 0, 1], [0, 0, 1], fov_x_deg=45, width=64, height=48),
            look_at([0, 5, 2], [0, 0, 1], fov_x_deg=45, width=64, height=48)]
    write_cameras(tmp_path / "cameras.json", cams, ["0000.png", "0001.png"])
    back, names = read_cameras(tmp_path / "cameras.json")
    assert names == ["0000.png", "0001.png"]
    for a, b in zip(cams, back):
        assert np.allclose(a.K, b.K) and np.allclose(a.R, b.R) and np.allclose(a.t, b.t)


def test_rejects_non_rotation():
    from plantbench.cameras import Camera

    with pytest.raises(InputError, match="rotation"):
        Camera(np.eye(3), np.diag([1.0, 1.0, -1.0]), np.zeros(3), 10, 10)
