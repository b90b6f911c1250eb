"""Camera formats derived from the canonical OpenCV cameras (docs/design.md, Conventions).

**COLMAP** (text model: cameras.txt, images.txt, points3D.txt). COLMAP's camera frame is OpenCV's (+X right, +Y
down, +Z forward) and images.txt stores the world-to-camera pose (quaternion QW QX QY QZ of R, Hamilton convention,
and t). COLMAP puts the centre of pixel (u, v) at (u + 0.5, v + 0.5), so the principal point is OpenCV's + 0.5 and
2D observations are OpenCV pixel coordinates + 0.5. Cameras are ``PINHOLE`` (fx fy cx cy); views with identical
intrinsics share one camera. points3D.txt holds ground-truth surface points seen in at least two views (visibility
from the exact depth and instance maps) with their tracks, so COLMAP tools that need a sparse model with tracks
(e.g. ``stereo_fusion``) accept it.

**transforms.json** (NeRF / nerfstudio): per frame the camera-to-world matrix in OpenGL axes (+X right, +Y up, +Z
backwards), i.e. ``c2w = [R^T | C] @ diag(1, -1, -1, 1)``; intrinsics ``fl_x fl_y cx cy w h`` with
``camera_model`` OPENCV and zero distortion. Pixel centres follow nerfstudio (which generates rays at pixel index
+ 0.5, as COLMAP does): cx, cy are OpenCV's + 0.5. ``camera_angle_x`` is added for the original NeRF loaders.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from plantbench.cameras import Camera
from plantbench.io.atomic import atomic_write, write_json
from plantbench.plant import check_shape

__all__ = ["rotation_to_quaternion", "colmap_intrinsics", "Tracks", "visible_tracks", "write_colmap_text",
           "transforms_json", "write_transforms", "OPENGL_FROM_OPENCV"]

OPENGL_FROM_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])
"""Right-multiplying an OpenCV camera-to-world matrix by this gives the OpenGL/NeRF one (flip y and z axes)."""


def rotation_to_quaternion(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z), w >= 0, of a rotation matrix (Shepperd's method).

    R : (3, 3) float; returns (4,) float
    """
    R = check_shape("rotation", R, (3, 3), "f")
    tr = np.trace(R)
    cands = np.array([tr, R[0, 0], R[1, 1], R[2, 2]])
    k = int(np.argmax(cands))
    if k == 0:
        s = 2.0 * np.sqrt(1.0 + tr)
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    else:
        i, j, m = k - 1, k % 3, (k + 1) % 3
        s = 2.0 * np.sqrt(1.0 + R[i, i] - R[j, j] - R[m, m])
        q = np.zeros(4)
        q[0] = (R[m, j] - R[j, m]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (R[j, i] + R[i, j]) / s
        q[1 + m] = (R[m, i] + R[i, m]) / s
    q = np.asarray(q, float)
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def colmap_intrinsics(camera: Camera) -> tuple[float, float, float, float]:
    """PINHOLE parameters (fx, fy, cx, cy) in COLMAP's pixel convention (centres at +0.5)."""
    K = camera.K
    return float(K[0, 0]), float(K[1, 1]), float(K[0, 2] + 0.5), float(K[1, 2] + 0.5)


@dataclass(frozen=True)
class Tracks:
    """Ground-truth 3D points and where each view sees them.

    points : (p, 3) float; colors : (p, 3) uint8
    obs_point : (k,) int, index into points; obs_image : (k,) int, view index; obs_uv : (k, 2) float, OpenCV pixels
    """

    points: np.ndarray
    colors: np.ndarray
    obs_point: np.ndarray
    obs_image: np.ndarray
    obs_uv: np.ndarray


def visible_tracks(points: np.ndarray, instance_of_point: np.ndarray, cameras: list[Camera],
                   depths: list[np.ndarray], instances: list[np.ndarray], images: list[np.ndarray] | None = None,
                   *, min_views: int = 2, rel_tol: float = 0.01) -> Tracks:
    """Which views see each point: it projects inside the image onto a pixel whose exact instance id is the
    point's and whose z-depth agrees within ``rel_tol``; points seen by fewer than ``min_views`` views are dropped.

    Parameters
    ----------
    points : (p, 3) float, surface samples; instance_of_point : (p,) int, their instance ids (1 wood, 2 + k leaf)
    depths, instances : per view (h, w) maps; images : per view (h, w, 3) uint8, for the point colours
    """
    pts = check_shape("track points", points, (-1, 3), "f")
    inst = check_shape("track instance ids", instance_of_point, (len(pts),), "i")
    seen_p, seen_i, seen_uv = [], [], []
    for k, (cam, depth, imap) in enumerate(zip(cameras, depths, instances, strict=True)):
        uv, z = cam.project(pts)
        pix = np.round(uv).astype(np.int64)
        ok = (z > 0) & (pix[:, 0] >= 0) & (pix[:, 0] < cam.width) & (pix[:, 1] >= 0) & (pix[:, 1] < cam.height)
        idx = np.flatnonzero(ok)
        u, v = pix[idx, 0], pix[idx, 1]
        vis = (imap[v, u] == inst[idx]) & (np.abs(depth[v, u] - z[idx]) <= rel_tol * z[idx])
        idx = idx[vis]
        seen_p.append(idx)
        seen_i.append(np.full(len(idx), k))
        seen_uv.append(uv[idx])
    obs_p = np.concatenate(seen_p) if seen_p else np.zeros(0, np.int64)
    obs_i = np.concatenate(seen_i) if seen_i else np.zeros(0, np.int64)
    obs_uv = np.concatenate(seen_uv) if seen_uv else np.zeros((0, 2))
    count = np.bincount(obs_p, minlength=len(pts))
    keep = count >= min_views
    new_id = np.cumsum(keep) - 1
    sel = keep[obs_p]
    obs_p, obs_i, obs_uv = new_id[obs_p[sel]], obs_i[sel], obs_uv[sel]
    colors = np.full((int(keep.sum()), 3), 128, np.uint8)
    if images is not None and len(obs_p):
        first = np.unique(obs_p, return_index=True)[1]  # first observation of each point (views in order)
        for k in np.unique(obs_i[first]):
            m = first[obs_i[first] == k]
            px = np.round(obs_uv[m]).astype(np.int64)
            colors[obs_p[m]] = images[k][px[:, 1], px[:, 0], :3]
    return Tracks(pts[keep], colors, obs_p, obs_i, obs_uv)


def write_colmap_text(folder: str | os.PathLike, cameras: list[Camera], names: list[str],
                      tracks: Tracks | None = None) -> Path:
    """Write a COLMAP text model (cameras.txt, images.txt, points3D.txt) into ``folder``.

    Image ids are 1 + view index; camera ids number the distinct intrinsics from 1; point ids are 1 + point index.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    intr = [(c.width, c.height, *colmap_intrinsics(c)) for c in cameras]
    cam_ids: dict[tuple, int] = {}
    for key in intr:
        cam_ids.setdefault(key, len(cam_ids) + 1)
    lines = ["# Camera list with one line of data per camera:", "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
             f"# Number of cameras: {len(cam_ids)}"]
    for (w, h, fx, fy, cx, cy), cid in cam_ids.items():  # plain floats: repr round-trips exactly
        lines.append(f"{cid} PINHOLE {w} {h} {fx!r} {fy!r} {cx!r} {cy!r}")
    _write_lines(folder / "cameras.txt", lines)

    tr = tracks or Tracks(np.zeros((0, 3)), np.zeros((0, 3), np.uint8), np.zeros(0, np.int64),
                          np.zeros(0, np.int64), np.zeros((0, 2)))
    order = np.lexsort((tr.obs_point, tr.obs_image))  # observations grouped by image
    obs_img, obs_pt, obs_uv = tr.obs_image[order], tr.obs_point[order], tr.obs_uv[order] + 0.5
    starts = np.searchsorted(obs_img, np.arange(len(cameras) + 1))
    point2d_idx = np.arange(len(obs_img)) - starts[obs_img]  # index of each observation within its image
    n_obs = len(obs_img)
    mean_track = n_obs / len(tr.points) if len(tr.points) else 0.0
    lines = ["# Image list with two lines of data per image:",
             "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
             "#   POINTS2D[] as (X, Y, POINT3D_ID)",
             f"# Number of images: {len(cameras)}, mean observations per image: {n_obs / max(len(cameras), 1)}"]
    for k, (cam, name, key) in enumerate(zip(cameras, names, intr, strict=True)):
        q = rotation_to_quaternion(cam.R)
        t = cam.t
        lines.append(" ".join([str(k + 1), *(repr(float(x)) for x in (*q, *t)), str(cam_ids[key]), name]))
        s, e = starts[k], starts[k + 1]
        lines.append(" ".join(f"{x!r} {y!r} {p + 1}" for (x, y), p in zip(obs_uv[s:e].tolist(), obs_pt[s:e].tolist())))
    _write_lines(folder / "images.txt", lines)

    lines = ["# 3D point list with one line of data per point:",
             "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)",
             f"# Number of points: {len(tr.points)}, mean track length: {mean_track}"]
    by_point = np.lexsort((obs_img, obs_pt))
    pstarts = np.searchsorted(obs_pt[by_point], np.arange(len(tr.points) + 1))
    for p in range(len(tr.points)):
        sel = by_point[pstarts[p]:pstarts[p + 1]]
        track = " ".join(f"{i + 1} {j}" for i, j in zip(obs_img[sel].tolist(), point2d_idx[sel].tolist()))
        x, y, z = tr.points[p].tolist()
        r, g, b = tr.colors[p].tolist()
        lines.append(f"{p + 1} {x!r} {y!r} {z!r} {r} {g} {b} 0 {track}")
    _write_lines(folder / "points3D.txt", lines)
    return folder


def _write_lines(path: Path, lines: list[str]) -> None:
    with atomic_write(path, "w") as fh:
        fh.write("\n".join(lines) + "\n")


def transforms_json(cameras: list[Camera], names: list[str]) -> dict:
    """The nerfstudio / NeRF ``transforms.json`` document (file paths relative to views/)."""
    def intr(c: Camera) -> dict:
        fx, fy, cx, cy = colmap_intrinsics(c)
        return {"fl_x": fx, "fl_y": fy, "cx": cx, "cy": cy, "w": c.width, "h": c.height}

    frames = []
    shared = intr(cameras[0]) if cameras else {}
    for cam, name in zip(cameras, names, strict=True):
        c2w = np.eye(4)
        c2w[:3, :3] = cam.R.T
        c2w[:3, 3] = cam.center
        frame = {"file_path": f"images/{name}", "transform_matrix": (c2w @ OPENGL_FROM_OPENCV).tolist()}
        if intr(cam) != shared:
            frame.update(intr(cam))
        frames.append(frame)
    doc = {"camera_model": "OPENCV", **shared, "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0, "frames": frames}
    if cameras:
        doc["camera_angle_x"] = float(2 * np.arctan(0.5 * cameras[0].width / cameras[0].K[0, 0]))
    return doc


def write_transforms(path: str | os.PathLike, cameras: list[Camera], names: list[str]) -> None:
    write_json(path, transforms_json(cameras, names))
