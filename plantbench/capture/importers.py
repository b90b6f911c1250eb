"""Real captures in: a laser scan file or a photo set with a COLMAP model becomes a case (docs/design.md).

A real capture arrives in its own frame: georeferenced coordinates (UTM eastings of 500 000 m), centimetres or
millimetres, Y up. The importers bring it to the case frame of docs/design.md (metres, right-handed, Z up, the
root at the origin on the ground plane z = 0) and record every step in ``CASE/case.json``::

    local = rotation @ (units_factor * source) - offset        (metres)
    source = rotation.T @ (local + offset) / units_factor

All of it in float64, before anything is stored as float32 (scan.ply holds float32 coordinates, fine in the local
frame: a 30 m tree keeps ~2 um; a UTM northing in float32 would keep 0.5 m). The origin rule, for scans and for the
sparse points of a COLMAP model alike: x, y of the offset are the centroid in x, y of the lowest 2 % of the points
(by z after the up-axis rotation, the stem base for a single tree), z of the offset is the 0.5th percentile of z
(the ground, robust to a few stray points below it).

Nothing is filtered silently: a NaN row, a file in the wrong units or a missing image is an
:class:`~plantbench.errors.InputError` naming the file. The case is built in a hidden folder next to ``CASE`` and
renamed into place at the end; an existing, non-empty ``CASE`` is refused.

Scans: ``.xyz`` / ``.txt`` / ``.csv`` (x y z first, extra columns ignored, ``#`` and ``//`` comment lines and one
header line skipped), ``.ply``, ``.las`` / ``.laz`` (laspy, the scaled coordinates), ``.pcd`` (Open3D).
Views: a COLMAP model (text or binary, read with pycolmap) and its images; pinhole cameras only (SIMPLE_RADIAL,
RADIAL, OPENCV and FULL_OPENCV are accepted when their distortion parameters are all zero; otherwise undistort the
images first with COLMAP's ``image_undistorter`` and import the undistorted model).
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Literal

import numpy as np
from pydantic import Field

from plantbench.errors import InputError
from plantbench.io.atomic import atomic_dir, atomic_write, write_json
from plantbench.schemas import Strict, load_json

__all__ = [
    "CASE_FORMAT", "UNITS", "UP_AXES", "MIN_POINTS", "CaseFrame", "CaseJson", "ImportResult",
    "read_scan_file", "units_factor", "up_rotation", "rotation_to_z", "ground_offset", "to_local", "to_source",
    "skeleton_to_frame",
    "import_scan", "export_scan", "read_colmap_model", "import_views", "read_case_json",
]

CASE_FORMAT = "plantbench.case/1"
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
"""Units a source file may be in, and their factor to metres."""

MIN_POINTS = 10
"""A scan with fewer points is refused: no method can make a plant of it."""

_UMASK = os.umask(0)
os.umask(_UMASK)

SCAN_SUFFIXES = (".xyz", ".txt", ".csv", ".xyz.gz", ".txt.gz", ".csv.gz", ".ply", ".las", ".laz", ".pcd")

_R = np.array
UP_AXES: dict[str, np.ndarray] = {
    "z": np.eye(3),
    "-z": _R([[1.0, 0, 0], [0, -1, 0], [0, 0, -1]]),  # 180 deg about x
    "y": _R([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]),  # (x, y, z) -> (x, -z, y): the usual Y-up to Z-up
    "-y": _R([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]),  # (x, y, z) -> (x, z, -y)
    "x": _R([[0.0, 1, 0], [0, 0, 1], [1, 0, 0]]),  # (x, y, z) -> (y, z, x)
    "-x": _R([[0.0, -1, 0], [0, 0, 1], [-1, 0, 0]]),  # (x, y, z) -> (-y, z, -x)
}
"""Proper rotations (det +1) taking the named source axis to +Z."""


# ------------------------------------------------------------------------------------------------- case.json


class CaseFrame(Strict):
    """How the case frame derives from the source: ``local = rotation @ (units_factor * source) - offset``."""

    units: str = Field(description="unit of the source coordinates: m, cm, mm, or 'model' for a COLMAP model")
    units_factor: float = Field(gt=0, description="source unit to metres (the --scale of a COLMAP model)")
    up: str = Field(description="the source axis that became +Z: z, -z, y, -y, x, -x, or 'auto' (estimated)")
    rotation: list[list[float]] = Field(description="3x3 proper rotation applied after the units factor")
    offset: list[float] = Field(description="(3,) metres, subtracted after the rotation: the root in the "
                                            "rotated metric frame")
    transform: str = ("local = rotation @ (units_factor * source) - offset; "
                      "source = rotation.T @ (local + offset) / units_factor")


class CaseSource(Strict):
    kind: Literal["scan", "views"]
    file: str = Field(description="source file (scan) or COLMAP model folder (views), as named on import")
    format: str
    sha256: str | None = Field(default=None, description="of the source file (scans)")
    points: int | None = Field(default=None, ge=0, description="points read (scan) or sparse points (views)")
    images: int | None = Field(default=None, ge=0, description="registered images imported (views)")


class CaseJson(Strict):
    """CASE/case.json of an imported real capture."""

    format: Literal["plantbench.case/1"] = CASE_FORMAT
    source: CaseSource
    frame: CaseFrame
    origin: str = Field(description="how the offset was chosen")
    height: float | None = Field(default=None, description="z extent of the imported points, metres")
    assumptions: list[str] = Field(default_factory=list, description="everything assumed rather than read")
    version: str = Field(description="plantbench version that imported it")


def read_case_json(case_dir: str | os.PathLike) -> CaseJson:
    """The import record of a case (InputError naming the file when missing or invalid)."""
    return load_json(Path(case_dir) / "case.json", CaseJson)


@dataclass(frozen=True)
class ImportResult:
    """What an import did, for the CLI to report."""

    case: Path
    record: CaseJson
    notes: list[str] = field(default_factory=list)


# ------------------------------------------------------------------------------------------------ the frame


def units_factor(units: str) -> float:
    """Factor from ``units`` (m, cm, mm) to metres."""
    try:
        return UNITS[units.strip().lower()]
    except KeyError:
        raise InputError(f"--units must be one of {', '.join(UNITS)}, got {units!r}") from None


def up_rotation(up: str) -> np.ndarray:
    """(3, 3) proper rotation taking the source axis ``up`` (z, -z, y, -y, x, -x; a leading + is allowed) to +Z."""
    key = up.strip().lower().lstrip("+")
    if key not in UP_AXES:
        raise InputError(f"--up must be one of {', '.join(UP_AXES)}, got {up!r}")
    return UP_AXES[key].copy()


def rotation_to_z(u: np.ndarray) -> np.ndarray:
    """(3, 3) the smallest proper rotation taking direction ``u`` (3,) to +Z (Rodrigues; 180 deg about x when ``u``
    points down)."""
    u = np.asarray(u, float)
    u = u / np.linalg.norm(u)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(u, z)
    s, c = np.linalg.norm(axis), float(u @ z)
    if s < 1e-12:
        return np.eye(3) if c > 0 else UP_AXES["-z"].copy()
    k = axis / s
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * kx + (1 - c) * (kx @ kx)


def ground_offset(points: np.ndarray, *, base_fraction: float = 0.02, ground_percentile: float = 0.5) -> np.ndarray:
    """The root of a metric, Z-up cloud: x, y the centroid of the lowest ``base_fraction`` of the points (by z),
    z the ``ground_percentile`` percentile of z.

    points : (n, 3) float, n >= 1; returns (3,) float
    """
    p = np.asarray(points, np.float64)
    k = max(1, int(np.ceil(base_fraction * len(p))))
    low = np.argpartition(p[:, 2], k - 1)[:k]
    return np.array([p[low, 0].mean(), p[low, 1].mean(), np.percentile(p[:, 2], ground_percentile)])


def to_local(points: np.ndarray, frame: CaseFrame) -> np.ndarray:
    """Source coordinates (n, 3) -> the case frame (n, 3), float64."""
    R = np.asarray(frame.rotation, float)
    return frame.units_factor * np.asarray(points, np.float64) @ R.T - np.asarray(frame.offset, float)


def to_source(points: np.ndarray, frame: CaseFrame) -> np.ndarray:
    """Case-frame coordinates (n, 3) -> the source frame (n, 3), float64."""
    R = np.asarray(frame.rotation, float)
    return (np.asarray(points, np.float64) + np.asarray(frame.offset, float)) @ R / frame.units_factor


def skeleton_to_frame(skeleton, frame: CaseFrame, *, to: Literal["local", "source"]):
    """``skeleton`` (a :class:`~plantbench.plant.Skeleton`) moved to the case frame ('local', from the source frame)
    or back to the source frame ('source'): positions by :func:`to_local` / :func:`to_source`, radii by the units
    factor."""
    from plantbench.plant import Skeleton

    if to == "local":
        pos, rad = to_local(skeleton.positions, frame), skeleton.radii * frame.units_factor
    elif to == "source":
        pos, rad = to_source(skeleton.positions, frame), skeleton.radii / frame.units_factor
    else:
        raise InputError(f"to must be 'local' or 'source', got {to!r}")
    return Skeleton(pos, rad, skeleton.parents, skeleton.order)


# ---------------------------------------------------------------------------------------------- scan reading


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


_SPLIT = re.compile(r"[,;\s]+")


def _first_rows(path: Path) -> tuple[int, list[str], str | None]:
    """Lines to skip (comments and at most one header line), the first data row's tokens and its delimiter."""
    import gzip

    header_seen = text_seen = False
    opener = gzip.open if path.suffix.lower() == ".gz" else open
    with opener(path, "rt", encoding="utf-8-sig", errors="replace") as fh:
        for lineno, line in enumerate(fh):
            s = line.strip()
            text_seen = text_seen or bool(s)
            if not s or s.startswith(("#", "//")):
                continue
            tokens = [t for t in _SPLIT.split(s) if t]
            numeric = [_is_number(t) for t in tokens[:3]]
            if all(numeric):
                delim = "," if "," in s else (";" if ";" in s else None)
                return lineno, tokens, delim
            if header_seen or any(numeric):  # one header line of names; a half-numeric row is an error
                raise InputError(f"line {lineno + 1} is not numeric: {s[:60]!r}", path=path)
            header_seen = True
    raise InputError("no numeric rows (only comments or a header)" if text_seen else "empty file", path=path)


def _read_text(path: Path) -> np.ndarray:
    skip, tokens, delim = _first_rows(path)
    if len(tokens) < 3:
        raise InputError(f"rows have {len(tokens)} column(s); need at least 3 (x y z) on line {skip + 1}", path=path)
    try:
        pts = np.loadtxt(path, delimiter=delim, comments=("#", "//"), skiprows=skip, usecols=(0, 1, 2),
                         dtype=np.float64, ndmin=2, encoding="utf-8-sig")
    except ValueError as exc:
        msg = str(exc)
        if "column index" in msg or "number of columns" in msg:
            raise InputError(f"a row has fewer than 3 columns (x y z) ({msg})", path=path) from None
        raise InputError(f"unreadable row ({msg})", path=path) from None
    return pts


def _read_ply(path: Path) -> np.ndarray:
    from plantbench.io.ply import read_points

    try:
        return read_points(path)[0]
    except InputError as exc:
        if "NaN" not in str(exc):
            raise
    from plyfile import PlyData  # read again without the check, so that the caller can count the NaN rows

    v = PlyData.read(str(path))["vertex"]
    return np.stack([np.asarray(v[k], np.float64) for k in "xyz"], axis=1)


def _read_las(path: Path) -> np.ndarray:
    import laspy

    try:
        las = laspy.read(str(path))
        return np.stack([np.asarray(las.x, np.float64), np.asarray(las.y, np.float64),
                         np.asarray(las.z, np.float64)], axis=1)
    except Exception as exc:  # noqa: BLE001 - laspy raises several types on corrupt input
        raise InputError(f"not a readable LAS/LAZ file ({type(exc).__name__}: {exc})", path=path) from None


def _read_pcd(path: Path) -> np.ndarray:
    import open3d as o3d

    try:
        cloud = o3d.io.read_point_cloud(str(path), format="pcd", remove_nan_points=False,
                                        remove_infinite_points=False)
    except Exception as exc:  # noqa: BLE001
        raise InputError(f"not a readable PCD file ({exc})", path=path) from None
    pts = np.asarray(cloud.points, np.float64)
    if not len(pts):
        raise InputError("no points read (empty or unreadable PCD file)", path=path)
    return pts


def read_scan_file(path: str | os.PathLike) -> np.ndarray:
    """Read a scan's coordinates, as stored (source units and axes).

    Returns
    -------
    points : (n, 3) float64, n >= :data:`MIN_POINTS`, all finite

    Raises InputError naming the file on: a missing or empty file, an unknown suffix, no numeric rows, fewer than 3
    columns, an unreadable LAS/LAZ/PLY/PCD, NaN or infinite coordinates (with the row count), fewer than
    :data:`MIN_POINTS` points.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("file not found", path=path)
    if path.stat().st_size == 0:
        raise InputError("empty file", path=path)
    suffix = path.suffix.lower()
    if suffix == ".gz" and Path(path.stem).suffix.lower() in (".xyz", ".txt", ".csv"):
        pts = _read_text(path)  # (gzip-compressed text: numpy and gzip.open read it as the plain file)
    elif suffix in (".xyz", ".txt", ".csv"):
        pts = _read_text(path)
    elif suffix == ".ply":
        pts = _read_ply(path)
    elif suffix in (".las", ".laz"):
        pts = _read_las(path)
    elif suffix == ".pcd":
        pts = _read_pcd(path)
    else:
        raise InputError(f"unknown scan format {suffix!r} (use one of {', '.join(SCAN_SUFFIXES)})", path=path)
    bad = ~np.isfinite(pts).all(axis=1)
    if bad.any():
        raise InputError(f"{int(bad.sum())} of {len(pts)} rows have NaN or infinite coordinates (first: point "
                         f"{int(np.argmax(bad))}); nothing is filtered silently: clean the file first", path=path)
    if len(pts) < MIN_POINTS:
        raise InputError(f"{len(pts)} point(s); a scan needs at least {MIN_POINTS}", path=path)
    return pts


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _open_mode(folder: Path) -> None:
    """Give a folder made by mkdtemp (0700) the mode mkdir would have given it."""
    os.chmod(folder, 0o777 & ~_UMASK)


def _check_target(case: Path) -> None:
    if case.exists() and (not case.is_dir() or any(case.iterdir())):
        raise InputError("exists and is not empty: choose a new case folder", path=case)


def _version() -> str:
    from plantbench import __version__

    return __version__


# ------------------------------------------------------------------------------------------------- scans


def _format(path: Path) -> str:
    """'xyz', 'las', ... ('xyz.gz' for a compressed text file)."""
    suffixes = [s.lower().lstrip(".") for s in path.suffixes]
    return ".".join(suffixes[-2:]) if suffixes[-1:] == ["gz"] and len(suffixes) > 1 else (suffixes[-1] if suffixes else "")


def import_scan(path: str | os.PathLike, case_dir: str | os.PathLike, *, units: str = "m", up: str = "z",
                max_height: float = 100.0) -> ImportResult:
    """Import a scan file as the case ``case_dir``: ``scan/scan.ply`` (x y z in the case frame, station 0),
    ``scan/stations.json`` (no station position: a file gives none) and ``case.json`` (the frame; see the module).

    Parameters
    ----------
    path : .xyz .txt .csv .ply .las .laz .pcd file
    case_dir : the case folder to create (absent or empty)
    units : unit of the file's coordinates, m, cm or mm
    up : the file's axis that points up (z, -z, y, -y, x, -x)
    max_height : refuse a cloud taller than this, metres, after units (a 3000 m tree means wrong units)
    """
    path, case = Path(path), Path(case_dir)
    _check_target(case)
    factor, R = units_factor(units), up_rotation(up)
    if not max_height > 0:
        raise InputError(f"--max-height must be > 0, got {max_height}")
    raw = read_scan_file(path)
    metric = factor * raw @ R.T  # float64 throughout: the offset is removed before any float32
    offset = ground_offset(metric)
    local = metric - offset
    height = float(local[:, 2].max() - local[:, 2].min())
    if height > max_height:
        raise InputError(f"a tree {height:.0f} m tall after --units {units} (more than --max-height {max_height:g} "
                         "m): wrong --units?", path=path)
    frame = CaseFrame(units=units.strip().lower(), units_factor=factor, up=up.strip().lower().lstrip("+"),
                      rotation=R.tolist(), offset=offset.tolist())
    record = CaseJson(
        source=CaseSource(kind="scan", file=path.name, format=_format(path), sha256=_sha256(path),
                          points=len(raw)),
        frame=frame, height=height,
        origin="x, y: centroid of the lowest 2 % of the points (by z after the up rotation); z: the 0.5th "
               "percentile of z (the ground)",
        assumptions=["one scanner station of unknown position (station 0 for every point)",
                     "no wood/leaf labels (a real scan has none)"],
        version=_version(),
    )
    from plantbench.io.ply import write_points

    with atomic_dir(case) as tmp:
        _open_mode(tmp)
        (tmp / "scan").mkdir()
        write_points(tmp / "scan" / "scan.ply", local, {"station": np.zeros(len(local), np.uint8)})
        write_json(tmp / "scan" / "stations.json", {
            "format": "plantbench.scan/1", "stations": [], "points": len(local), "source": path.name,
            "notes": "imported scan: station positions unknown; every point has station 0",
        })
        write_json(tmp / "case.json", record.model_dump(mode="json"))
    notes = [f"offset {offset[0]:.3f} {offset[1]:.3f} {offset[2]:.3f} m removed (case.json)"]
    return ImportResult(case, record, notes)


def export_scan(case_dir: str | os.PathLike, path: str | os.PathLike, *,
                frame: Literal["local", "source"] = "local") -> Path:
    """Write a case's scan coordinates as ``.xyz`` (text, 1 um) or ``.las`` / ``.laz`` (LAS 1.2, point format 0).

    ``frame`` 'local': the case frame (metres, as scan.ply); 'source': back in the imported file's frame (units,
    axes and georeferenced offset of ``case.json``). LAS coordinates are stored with scale 0.0001 m (expressed in
    the file's units) and offsets at the floor of the minimum, so a UTM-sized coordinate keeps 0.1 mm.
    """
    from plantbench.io.ply import read_points

    case, path = Path(case_dir), Path(path)
    pts = read_points(case / "scan" / "scan.ply")[0]
    unit = 1.0
    if frame == "source":
        cf = read_case_json(case).frame
        pts, unit = to_source(pts, cf), cf.units_factor
    elif frame != "local":
        raise InputError(f"frame must be 'local' or 'source', got {frame!r}")
    suffix = path.suffix.lower()
    if suffix in (".xyz", ".txt", ".csv"):
        sep = "," if suffix == ".csv" else " "
        decimals = max(0, int(np.ceil(-np.log10(1e-6 / unit))))
        with atomic_write(path, "w") as fh:
            np.savetxt(fh, pts, fmt=f"%.{decimals}f", delimiter=sep)
        return path
    if suffix not in (".las", ".laz"):
        raise InputError(f"export to .xyz, .txt, .csv, .las or .laz, not {suffix!r}", path=path)
    import laspy

    scale = 1e-4 / unit
    offsets = np.floor(pts.min(axis=0)) if len(pts) else np.zeros(3)
    if len(pts) and np.any((pts.max(axis=0) - offsets) / scale >= 2**31 - 1):
        raise InputError(f"the cloud spans more than {(2**31 - 1) * scale:.0f} units: too large for LAS at 0.1 mm",
                         path=path)
    header = laspy.LasHeader(point_format=0, version="1.2")
    header.scales, header.offsets = np.full(3, scale), offsets
    las = laspy.LasData(header)
    las.x, las.y, las.z = pts[:, 0], pts[:, 1], pts[:, 2]
    with atomic_write(path, "wb") as fh:
        las.write(fh, do_compress=suffix == ".laz")
    return path


# ------------------------------------------------------------------------------------------------- views


@dataclass(frozen=True)
class ColmapModel:
    """A COLMAP model's registered images as OpenCV cameras, in the model's own frame and units.

    cameras : per registered image (image-id order); names : their image names; points : (p, 3) sparse points
    """

    cameras: list
    names: list[str]
    points: np.ndarray


def _colmap_intrinsics(cam, image_name: str, model_dir: Path) -> np.ndarray:
    """OpenCV K of a pycolmap camera; InputError for a non-pinhole model or non-zero distortion."""
    model = cam.model.name
    if not cam.is_perspective_pinhole():
        raise InputError(f"camera {cam.camera_id} (image {image_name}) is a {model} camera; plantbench cameras are "
                         "pinhole: undistort the images (colmap image_undistorter) and import that model",
                         path=model_dir)
    extra = np.asarray(cam.params, float)[list(cam.extra_params_idxs())]
    if np.any(extra != 0):
        raise InputError(f"camera {cam.camera_id} (image {image_name}) is {model} with distortion "
                         f"{np.round(extra, 6).tolist()}; plantbench cameras are pinhole: undistort the images "
                         "(colmap image_undistorter) and import the undistorted model", path=model_dir)
    K = np.asarray(cam.calibration_matrix(), float).copy()
    K[0, 2] -= 0.5  # COLMAP puts pixel (u, v)'s centre at (u + 0.5, v + 0.5), OpenCV at (u, v)
    K[1, 2] -= 0.5
    return K


def read_colmap_model(model_dir: str | os.PathLike) -> ColmapModel:
    """Read a COLMAP model (text or binary) with pycolmap; registered images only, as OpenCV cameras."""
    import PIL.Image  # noqa: F401 - PIL before pycolmap: zlib clash (docs/design.md, Platform notes)
    import pycolmap

    from plantbench.cameras import Camera

    model_dir = Path(model_dir)
    if not model_dir.is_dir():
        raise InputError("COLMAP model folder not found", path=model_dir)
    have = {p.name for p in model_dir.iterdir()}
    if not ({"cameras.txt", "images.txt"} <= have or {"cameras.bin", "images.bin"} <= have):
        hint = " (COLMAP writes models to sparse/0: pass that folder)" if (model_dir / "0").is_dir() else ""
        raise InputError(f"not a COLMAP model: no cameras.txt + images.txt or cameras.bin + images.bin{hint}",
                         path=model_dir)
    try:
        rec = pycolmap.Reconstruction(str(model_dir))
    except Exception as exc:  # noqa: BLE001 - pycolmap raises ValueError / RuntimeError on bad input
        raise InputError(f"not a readable COLMAP model ({exc})", path=model_dir) from None
    cameras, names = [], []
    for image_id in sorted(rec.images.keys()):
        img = rec.images[image_id]
        if not img.has_pose:
            continue
        cam = img.camera
        K = _colmap_intrinsics(cam, img.name, model_dir)
        pose = img.cam_from_world() if callable(img.cam_from_world) else img.cam_from_world
        m = np.asarray(pose.matrix(), float)
        cameras.append(Camera(K, m[:, :3], m[:, 3], int(cam.width), int(cam.height)))
        names.append(str(img.name))
    if not cameras:
        raise InputError("the COLMAP model has no registered image", path=model_dir)
    pts = np.array([p.xyz for p in rec.points3D.values()], float).reshape(-1, 3)
    return ColmapModel(cameras, names, pts)


def _check_images(images_dir: Path, names: list[str], cameras: list) -> None:
    """Every image the model refers to exists, is readable and has its camera's size; InputError naming the first
    that is not."""
    from PIL import Image

    if not images_dir.is_dir():
        raise InputError("image folder not found", path=images_dir)
    for name in names:
        p = PurePosixPath(name.replace("\\", "/"))
        if p.is_absolute() or ".." in p.parts:
            raise InputError(f"image name {name!r} leaves the image folder", path=images_dir)
    missing = [n for n in names if not (images_dir / n).is_file()]
    if missing:
        raise InputError(f"image referenced by the COLMAP model is missing ({len(missing)} of {len(names)} missing)",
                         path=images_dir / missing[0])
    for name, cam in zip(names, cameras, strict=True):
        try:
            with Image.open(images_dir / name) as im:
                size = im.size
        except Exception as exc:  # noqa: BLE001 - PIL raises several types on corrupt input
            raise InputError(f"not a readable image ({exc})", path=images_dir / name) from None
        if size != (cam.width, cam.height):
            raise InputError(f"image is {size[0]}x{size[1]} but its COLMAP camera is {cam.width}x{cam.height} "
                             "(resized after reconstruction?)", path=images_dir / name)


def _views_frame(model: ColmapModel, scale: float, up: str) -> tuple[np.ndarray, np.ndarray, str, list[str]]:
    """(rotation, offset, origin rule, assumptions) taking the model's world to the case frame."""
    assumptions = []
    if up.strip().lower() == "auto":
        ups = np.array([-c.R[1] for c in model.cameras])  # OpenCV image y points down: a camera's up is -row 1 of R
        mean = ups.mean(axis=0)
        if np.linalg.norm(mean) < 0.5:
            raise InputError(f"cannot estimate up from {len(ups)} cameras (their up vectors disagree): pass --up")
        R = rotation_to_z(mean)
        assumptions.append("up estimated as the mean of the cameras' up vectors (cameras held upright)")
    else:
        R = up_rotation(up)
    if len(model.points) >= MIN_POINTS:
        offset = ground_offset(scale * model.points @ R.T)
        origin = ("x, y: centroid of the lowest 2 % of the sparse points (by z after the up rotation); z: the "
                  "0.5th percentile of their z (the ground)")
    else:
        centres = scale * np.array([c.center for c in model.cameras]) @ R.T
        offset = np.array([*centres[:, :2].mean(axis=0), centres[:, 2].min()])
        origin = "no sparse points: x, y the cameras' centroid, z the lowest camera's height"
        assumptions.append("the root is below the cameras' centroid and the ground at the lowest camera's height")
    return R, offset, origin, assumptions


def import_views(images_dir: str | os.PathLike, model_dir: str | os.PathLike, case_dir: str | os.PathLike, *,
                 scale: float | None = None, up: str = "auto") -> ImportResult:
    """Import a photo set with a COLMAP model as the case ``case_dir``: ``views/images/`` (copied, COLMAP's names),
    ``views/cameras.json`` (OpenCV K, R, t in the case frame), ``views/colmap/`` (cameras only) and
    ``views/transforms.json`` derived from them, and ``case.json``.

    The case frame: ``X = rotation @ (scale * X_model) - offset``; each camera becomes ``R' = R Q^T``,
    ``t' = R Q^T offset + scale t`` (its camera frame scaled with the world, so pixels are unchanged).

    Parameters
    ----------
    images_dir : folder holding the images under the names the model uses
    model_dir : COLMAP model folder (cameras, images, points3D; .txt or .bin)
    scale : metres per model unit (None: 1, recorded as assumed); a model from SfM has arbitrary units
    up : 'auto' (the mean of the cameras' up vectors) or the model axis that points up (z, -z, y, -y, x, -x)
    """
    from plantbench.cameras import Camera, write_cameras
    from plantbench.capture.formats import write_colmap_text, write_transforms

    images_dir, model_dir, case = Path(images_dir), Path(model_dir), Path(case_dir)
    _check_target(case)
    if scale is not None and not (np.isfinite(scale) and scale > 0):
        raise InputError(f"--scale must be a positive number, got {scale}")
    if up.strip().lower() != "auto":
        up_rotation(up)  # a bad --up fails before the model is read
    model = read_colmap_model(model_dir)
    _check_images(images_dir, model.names, model.cameras)
    s = 1.0 if scale is None else float(scale)
    R, offset, origin, assumptions = _views_frame(model, s, up)
    notes = []
    if scale is None:
        notes.append("scale assumed 1: the model's units (pass --scale, metres per model unit)")
        assumptions.insert(0, notes[0])
    cams = [Camera(c.K, c.R @ R.T, c.R @ R.T @ offset + s * c.t, c.width, c.height) for c in model.cameras]
    frame = CaseFrame(units="model", units_factor=s, up=up.strip().lower().lstrip("+"), rotation=R.tolist(),
                      offset=offset.tolist())
    record = CaseJson(source=CaseSource(kind="views", file=str(model_dir), format="colmap",
                                        points=len(model.points), images=len(cams)),
                      frame=frame, origin=origin, assumptions=assumptions, version=_version())
    with atomic_dir(case) as tmp:
        _open_mode(tmp)
        views = tmp / "views"
        for name in model.names:
            dest = views / "images" / name
            dest.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(images_dir / name, dest)
        write_cameras(views / "cameras.json", cams, model.names)
        write_colmap_text(views / "colmap", cams, model.names)
        write_transforms(views / "transforms.json", cams, model.names)
        write_json(tmp / "case.json", record.model_dump(mode="json"))
    notes.append(f"{len(cams)} registered views, {len(model.points)} sparse points; frame recorded in case.json")
    return ImportResult(case, record, notes)
