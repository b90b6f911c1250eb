"""PLY files of the contract: skeletons, triangle meshes with per-face fields, labelled point clouds.

Binary little-endian, written through :func:`plantbench.io.atomic.atomic_write`. Reading accepts any PLY a
third-party tool is likely to write (ASCII or binary, ``vertex_indices`` or ``vertex_index``, polygons, which are
fan-triangulated) and raises :class:`~plantbench.errors.InputError` naming the file on anything else.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from plyfile import PlyData, PlyElement, PlyElementParseError

from plantbench.errors import InputError
from plantbench.io.atomic import atomic_write
from plantbench.plant import Skeleton, TriMesh

__all__ = ["write_skeleton", "read_skeleton", "write_mesh", "read_mesh", "write_points", "read_points"]

_TYPES = {"f": "f8", "i": "i4", "u": "u4", "b": "u1"}


def _vertex_element(columns: dict[str, np.ndarray], name: str = "vertex") -> PlyElement:
    n = len(next(iter(columns.values()))) if columns else 0
    dtype = []
    for key, col in columns.items():
        col = np.asarray(col)
        kind = col.dtype.kind
        if kind == "f":
            dtype.append((key, "f4" if col.dtype == np.float32 else "f8"))
        elif kind in "iu":
            dtype.append((key, {1: "u1", 2: "u2"}.get(col.dtype.itemsize, "i4") if kind == "u" else "i4"))
        elif kind == "b":
            dtype.append((key, "u1"))
        else:
            raise TypeError(f"column {key}: unsupported dtype {col.dtype}")
    rec = np.empty(n, dtype=dtype)
    for key, _ in dtype:
        rec[key] = columns[key]
    return PlyElement.describe(rec, name)


def _write(path: str | os.PathLike, elements: list[PlyElement], comments: list[str] | None = None) -> None:
    ply = PlyData(elements, text=False, byte_order="<", comments=comments or [])
    with atomic_write(path, "wb") as fh:
        ply.write(fh)


_TRIANGLES = {"face": {"vertex_indices": 3, "vertex_index": 3}}


def _read(path: str | os.PathLike) -> PlyData:
    """Parse a PLY file. Binary triangle lists take plyfile's fixed-length fast path (memory-mapped, ~1000x
    faster than per-row lists); files with other polygons fall back to the generic reader."""
    path = Path(path)
    if not path.is_file():
        raise InputError("file not found", path=path)
    try:
        try:
            return PlyData.read(str(path), known_list_len=_TRIANGLES)
        except PlyElementParseError:
            return PlyData.read(str(path))
    except Exception as exc:  # plyfile raises several types on corrupt input
        raise InputError(f"not a readable PLY file ({exc})", path=path) from exc


def _column(ply: PlyData, element: str, name: str, path, required: bool = True) -> np.ndarray | None:
    try:
        el = ply[element]
    except KeyError:
        if required:
            raise InputError(f"missing element '{element}'", path=path) from None
        return None
    names = [p.name for p in el.properties]
    if name not in names:
        if required:
            raise InputError(f"element '{element}' has no property '{name}' (has: {', '.join(names)})", path=path)
        return None
    return np.asarray(el[name])


def _xyz(ply: PlyData, path) -> np.ndarray:
    pts = np.stack([_column(ply, "vertex", k, path).astype(np.float64) for k in "xyz"], axis=1)
    if pts.size and not np.all(np.isfinite(pts)):
        raise InputError("vertex coordinates contain NaN or infinite values", path=path)
    return pts


# --------------------------------------------------------------------------------------------------- skeletons


def write_skeleton(path: str | os.PathLike, skeleton: Skeleton) -> None:
    """vertex: x y z radius order (double, double, double, double, int); edge: vertex1 vertex2 (parent -> child)."""
    p = skeleton.positions
    vert = _vertex_element(
        {"x": p[:, 0], "y": p[:, 1], "z": p[:, 2], "radius": skeleton.radii, "order": skeleton.order.astype(np.int32)}
    )
    e = skeleton.edges.astype(np.int32)
    edge = _vertex_element({"vertex1": e[:, 0], "vertex2": e[:, 1]}, "edge")
    _write(path, [vert, edge])


def read_skeleton(path: str | os.PathLike) -> Skeleton:
    """Read a skeleton PLY; edges must form a forest (each node at most one parent, no cycle)."""
    ply = _read(path)
    pos = _xyz(ply, path)
    n = len(pos)
    radius = _column(ply, "vertex", "radius", path, required=False)
    radius = np.full(n, np.nan) if radius is None else radius.astype(np.float64)
    order = _column(ply, "vertex", "order", path, required=False)
    parents = np.full(n, -1, np.int64)
    v1 = _column(ply, "edge", "vertex1", path, required=False)
    if v1 is not None:
        v2 = _column(ply, "edge", "vertex2", path).astype(np.int64)
        v1 = v1.astype(np.int64)
        if len(v1) and (min(v1.min(), v2.min()) < 0 or max(v1.max(), v2.max()) >= n):
            raise InputError("edge refers to a vertex that does not exist", path=path)
        if len(np.unique(v2)) != len(v2):
            raise InputError("a node has more than one parent edge (edges must run parent -> child)", path=path)
        parents[v2] = v1
    try:
        skel = Skeleton(pos, radius, parents, None if order is None else order.astype(np.int64))
    except InputError as exc:
        raise InputError(str(exc), path=path) from None
    if not skel.is_forest():
        raise InputError("edges contain a cycle", path=path)
    return skel


# ------------------------------------------------------------------------------------------------------ meshes


def write_mesh(
    path: str | os.PathLike,
    mesh: TriMesh,
    face_fields: dict[str, np.ndarray] | None = None,
    vertex_fields: dict[str, np.ndarray] | None = None,
) -> None:
    """Triangle mesh, float32 vertices, ``vertex_indices`` faces, optional extra per-face / per-vertex columns."""
    v = mesh.vertices.astype(np.float32)
    cols = {"x": v[:, 0], "y": v[:, 1], "z": v[:, 2], **(vertex_fields or {})}
    vert = _vertex_element(cols)
    fdtype = [("vertex_indices", "i4", (3,))]
    extra = face_fields or {}
    for key, col in extra.items():
        fdtype.append((key, "i4" if np.asarray(col).dtype.kind in "iub" else "f4"))
    rec = np.empty(len(mesh.faces), dtype=fdtype)
    rec["vertex_indices"] = mesh.faces.astype(np.int32)
    for key, col in extra.items():
        rec[key] = col
    face = PlyElement.describe(rec, "face", len_types={"vertex_indices": "u1"})
    _write_triangles(path, vert, face, rec)


def _write_triangles(path: str | os.PathLike, vert: PlyElement, face: PlyElement, rec: np.ndarray) -> None:
    """Write what ``_write(path, [vert, face])`` writes, byte for byte, without plyfile's per-row loop over list
    properties (every face has exactly three indices, so the face block is one packed numpy array)."""
    header = PlyData([vert, face], text=False, byte_order="<").header.encode("ascii") + b"\n"
    packed_dtype = [("n", "u1"), ("vertex_indices", "<i4", (3,))]
    packed_dtype += [(name, rec.dtype[name].newbyteorder("<")) for name in rec.dtype.names if name != "vertex_indices"]
    packed = np.empty(len(rec), dtype=packed_dtype)
    packed["n"] = 3
    for name in rec.dtype.names:
        packed[name] = rec[name]
    with atomic_write(path, "wb") as fh:
        fh.write(header)
        fh.write(vert.data.astype(vert.dtype("<"), copy=False).tobytes())
        fh.write(packed.tobytes())


def read_mesh(path: str | os.PathLike) -> tuple[TriMesh, dict[str, np.ndarray]]:
    """Return the triangle mesh and its extra per-face columns (polygons are fan-triangulated)."""
    ply = _read(path)
    verts = _xyz(ply, path)
    try:
        face_el = ply["face"]
    except KeyError:
        return TriMesh(verts, np.zeros((0, 3), np.int64)), {}
    names = [p.name for p in face_el.properties]
    key = next((k for k in ("vertex_indices", "vertex_index") if k in names), None)
    if key is None:
        raise InputError(f"face element has no vertex_indices property (has: {', '.join(names)})", path=path)
    raw = face_el[key]
    extras = {k: np.array(face_el[k]) for k in names if k != key}
    if len(raw) == 0:
        return TriMesh(verts, np.zeros((0, 3), np.int64)), {k: v[:0] for k, v in extras.items()}
    try:
        arr = np.stack(raw).astype(np.int64) if isinstance(raw, np.ndarray) and raw.dtype == object else np.asarray(raw)
    except ValueError:
        arr = None
    if arr is not None and arr.ndim == 2 and arr.shape[1] == 3:
        faces, src = arr.astype(np.int64), np.arange(len(arr))
    else:  # polygons of mixed size: fan triangulation
        tris, src_l = [], []
        for i, poly in enumerate(raw):
            poly = np.asarray(poly, np.int64)
            for j in range(1, len(poly) - 1):
                tris.append((poly[0], poly[j], poly[j + 1]))
                src_l.append(i)
        faces = np.asarray(tris, np.int64).reshape(-1, 3)
        src = np.asarray(src_l, np.int64)
    try:
        mesh = TriMesh(verts, faces)
    except InputError as exc:
        raise InputError(str(exc), path=path) from None
    return mesh, {k: v[src] for k, v in extras.items()}


# ------------------------------------------------------------------------------------------------------ points


def write_points(path: str | os.PathLike, points: np.ndarray, fields: dict[str, np.ndarray] | None = None) -> None:
    """Point cloud: float32 x y z plus extra columns (e.g. label, leaf_id, station, nx ny nz, red green blue)."""
    p = np.asarray(points, np.float32).reshape(-1, 3)
    _write(path, [_vertex_element({"x": p[:, 0], "y": p[:, 1], "z": p[:, 2], **(fields or {})})])


def read_points(path: str | os.PathLike) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Return (n, 3) float64 points and the other vertex columns."""
    ply = _read(path)
    pts = _xyz(ply, path)
    names = [p.name for p in ply["vertex"].properties if p.name not in "xyz"]
    return pts, {k: np.array(ply["vertex"][k]) for k in names}
