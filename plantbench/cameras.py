"""Canonical cameras: OpenCV pinhole (docs/design.md, Conventions).

A world point X maps to camera coordinates ``Xc = R X + t`` and to pixel ``(u, v) = (fx Xc/Zc + cx, fy Yc/Zc + cy)``
with pixel (u, v)'s centre at integer (u, v); camera +Z looks forward, +X right, +Y down. Every other camera format
(COLMAP, transforms.json, Mitsuba) is derived from this one in :mod:`plantbench.capture`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from plantbench.errors import InputError
from plantbench.io.atomic import write_json
from plantbench.plant import check_shape
from plantbench.schemas import CameraModel, CamerasJson, load_json

__all__ = ["Camera", "look_at", "read_cameras", "write_cameras"]


@dataclass(frozen=True)
class Camera:
    """One OpenCV pinhole camera.

    K : (3, 3) float, intrinsics
    R : (3, 3) float, world-to-camera rotation
    t : (3,) float, world-to-camera translation
    width, height : int, image size in pixels
    """

    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    width: int
    height: int

    def __post_init__(self) -> None:
        object.__setattr__(self, "K", check_shape("camera K", self.K, (3, 3), "f"))
        object.__setattr__(self, "R", check_shape("camera R", self.R, (3, 3), "f"))
        object.__setattr__(self, "t", check_shape("camera t", self.t, (3,), "f"))
        if not np.allclose(self.R @ self.R.T, np.eye(3), atol=1e-6) or np.linalg.det(self.R) <= 0:
            raise InputError("camera R is not a rotation matrix")

    @property
    def center(self) -> np.ndarray:
        """(3,) camera centre in world coordinates, -R^T t."""
        return -self.R.T @ self.t

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project world points.

        Parameters
        ----------
        points : (n, 3) float

        Returns
        -------
        uv : (n, 2) float, pixel coordinates (OpenCV: pixel centres at integers)
        z : (n,) float, depth along the optical axis (negative behind the camera)
        """
        xc = np.asarray(points, float) @ self.R.T + self.t
        z = xc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uvw = xc @ self.K.T
            uv = uvw[:, :2] / uvw[:, 2:3]
        return uv, z

    def pixel_rays(self) -> tuple[np.ndarray, np.ndarray]:
        """Rays through every pixel centre, row-major (v, u).

        Returns
        -------
        origin : (3,) float, the camera centre
        directions : (height * width, 3) float, unit directions in world coordinates; the ray through pixel
            (u, v) is at index ``v * width + u``. Its z-depth is ``t_hit * (R @ d)[2]``.
        """
        u, v = np.meshgrid(np.arange(self.width, dtype=float), np.arange(self.height, dtype=float))
        pix = np.stack([u.ravel(), v.ravel(), np.ones(u.size)], axis=1)
        d_cam = pix @ np.linalg.inv(self.K).T
        d = d_cam @ self.R  # R^T d_cam, row-wise
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return self.center, d

    def to_model(self, index: int, image: str) -> CameraModel:
        return CameraModel(
            id=index, image=image, width=self.width, height=self.height,
            K=self.K.tolist(), R=self.R.tolist(), t=self.t.tolist(),
        )


def look_at(eye, target, up=(0.0, 0.0, 1.0), *, fov_x_deg: float, width: int, height: int) -> Camera:
    """An OpenCV camera at ``eye`` looking at ``target`` with horizontal field of view ``fov_x_deg``.

    The principal point is the image centre ((width - 1) / 2, (height - 1) / 2) in OpenCV's pixel-centre convention.
    """
    eye, target, up = (np.asarray(a, float) for a in (eye, target, up))
    z = target - eye
    if np.linalg.norm(z) == 0:
        raise InputError("look_at: eye and target coincide")
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:
        raise InputError("look_at: view direction is parallel to the up vector")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)  # image down
    R = np.stack([x, y, z])
    f = 0.5 * width / np.tan(np.radians(fov_x_deg) / 2)
    K = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1]])
    return Camera(K, R, -R @ eye, width, height)


def write_cameras(path: str | os.PathLike, cameras: list[Camera], images: list[str]) -> None:
    doc = CamerasJson(cameras=[c.to_model(i, name) for i, (c, name) in enumerate(zip(cameras, images, strict=True))])
    write_json(path, doc.model_dump(mode="json"))


def read_cameras(path: str | os.PathLike) -> tuple[list[Camera], list[str]]:
    """Cameras and image file names from a cameras.json."""
    doc = load_json(path, CamerasJson)
    cams, names = [], []
    for m in doc.cameras:
        try:
            cams.append(Camera(np.array(m.K), np.array(m.R), np.array(m.t), m.width, m.height))
        except InputError as exc:
            raise InputError(str(exc), path=Path(path), field=f"cameras.{m.id}") from None
        names.append(m.image)
    return cams, names
