"""Vectorised first-hit ray casting against one triangle mesh: Mitsuba (llvm) or open3d.

The exact ground-truth maps and the laser scan both need "which triangle does this ray hit first, and where". One
merged mesh with a per-face label array answers both without any shape bookkeeping: the primitive index of the
hit indexes the labels. Mitsuba's ``llvm_ad_rgb`` variant casts all rays in one vectorised call; in the
``scalar_rgb`` fallback Mitsuba would need a Python loop per ray, so open3d's ``RaycastingScene`` (Embree) is used
instead. Both cast the same float32 geometry and agree to ~1e-5 m (docs/design.md, Platform notes).
"""

from __future__ import annotations

import numpy as np

from plantbench.plant import check_shape

__all__ = ["RayCaster"]

_CHUNK = 1 << 22  # rays per call: bounds the memory of Dr.Jit / open3d buffers (~4M rays, ~150 MB)


class RayCaster:
    """First-hit ray caster over one or more triangle meshes, indexed as one: the face index it returns counts the
    faces of ``meshes[0]``, then ``meshes[1]``, and so on.

    Parameters
    ----------
    meshes : list of (vertices (n, 3) float, faces (m, 3) int)
    backend : 'auto' | 'mitsuba' | 'open3d'
        'auto' uses Mitsuba when the selected variant is llvm_ad_rgb, else open3d.
    scene, shapes : optional, Mitsuba backend only
        An already loaded Mitsuba scene and, per mesh, the ``mi.Mesh`` in it that holds that mesh (same faces in
        the same order; None for a mesh without faces). Casting then reuses the scene's acceleration structure
        (built once for rendering) instead of building another one; other shapes of the scene occlude but count
        as misses.
    """

    def __init__(self, meshes, backend: str = "auto", *, scene=None, shapes=None) -> None:
        parts = [(check_shape("ray caster vertices", v, (-1, 3), "f"), check_shape("ray caster faces", f, (-1, 3), "i"))
                 for v, f in meshes]
        counts = np.array([len(f) for _, f in parts], np.int64)
        self.offsets = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
        self.n_faces = int(counts.sum())
        if backend == "auto":
            from plantbench.backend import select_variant

            backend = "mitsuba" if select_variant().startswith("llvm") else "open3d"
        if backend not in ("mitsuba", "open3d"):
            raise ValueError(f"unknown ray casting backend {backend!r}")
        self.backend = backend
        if backend == "mitsuba":
            from plantbench.backend import load_mitsuba

            mi = load_mitsuba()
            if not mi.variant().startswith("llvm"):
                raise ValueError(f"Mitsuba ray casting needs an llvm variant (vectorised), not {mi.variant()}")
            import drjit as dr

            self._mi, self._dr = mi, dr
            if scene is None:
                shapes = [mitsuba_mesh(mi, f"part{k}", v, f) if len(f) else None for k, (v, f) in enumerate(parts)]
                scene = mi.load_dict({"type": "scene", **{f"part{k}": s for k, s in enumerate(shapes) if s is not None}})
            elif shapes is None or len(shapes) != len(parts):
                raise ValueError("RayCaster: give one Mitsuba shape (or None) per mesh")
            self._scene = scene
            # the hit's shape pointer, reinterpreted, is the shape's registry id: map it to the mesh's face offset
            reg = {int(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(s))[0]): k for k, s in enumerate(shapes)
                   if s is not None}
            size = max(reg, default=0) + 1
            for s in scene.shapes():
                size = max(size, int(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(s))[0]) + 1)
            self._lut = np.full(size, -1, np.int64)
            for rid, k in reg.items():
                self._lut[rid] = self.offsets[k]
        else:
            import open3d as o3d

            from plantbench.backend import open3d_threads

            self._o3d = o3d
            self._threads = open3d_threads()
            self._scene = o3d.t.geometry.RaycastingScene(nthreads=self._threads)
            v = np.concatenate([p[0] for p in parts]) if parts else np.zeros((0, 3))
            vo = np.concatenate([[0], np.cumsum([len(p[0]) for p in parts])[:-1]]) if parts else []
            f = np.concatenate([p[1] + o for p, o in zip(parts, vo)]) if parts else np.zeros((0, 3), int)
            self._scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(f.astype(np.uint32)))

    def cast(self, origins: np.ndarray, directions: np.ndarray, tmax: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
        """Cast rays; return the hit distance and face.

        Parameters
        ----------
        origins : (n, 3) or (3,) float
            Ray origins (one shared origin may be given as a (3,) array).
        directions : (n, 3) float
            Unit directions (``t`` is in units of their length).
        tmax : float
            Hits farther than this are misses.

        Returns
        -------
        t : (n,) float64, distance to the first hit, inf on a miss
        prim : (n,) int64, index of the hit face (over all meshes), -1 on a miss
        """
        d = np.asarray(directions, np.float32).reshape(-1, 3)
        o = np.asarray(origins, np.float32)
        if o.shape != (3,):
            o = np.broadcast_to(o, d.shape)
        t = np.full(len(d), np.inf)
        prim = np.full(len(d), -1, np.int64)
        for s in range(0, len(d), _CHUNK):
            sl = slice(s, s + _CHUNK)
            t[sl], prim[sl] = self._cast_chunk(o if o.ndim == 1 else o[sl], d[sl], tmax)
        miss = ~(t <= tmax)
        t[miss], prim[miss] = np.inf, -1
        return t, prim

    def _cast_chunk(self, o: np.ndarray, d: np.ndarray, tmax: float) -> tuple[np.ndarray, np.ndarray]:
        if self.backend == "mitsuba":
            mi, dr = self._mi, self._dr
            if o.ndim == 1:
                origin = mi.Point3f(*(float(x) for x in o))
            else:
                origin = mi.Point3f(*(mi.Float(np.ascontiguousarray(o[:, k])) for k in range(3)))
            ray = mi.Ray3f(origin, mi.Vector3f(*(mi.Float(np.ascontiguousarray(d[:, k])) for k in range(3))))
            if np.isfinite(tmax):
                ray.maxt = mi.Float(float(tmax))
            pi = self._scene.ray_intersect_preliminary(ray)
            shape = dr.reinterpret_array(mi.UInt32, pi.shape)
            dr.eval(pi.t, pi.prim_index, shape)  # one kernel for all three (else each .numpy() re-traces: ~3x)
            off = self._lut[shape.numpy()]
            prim = np.where(off >= 0, off + pi.prim_index.numpy(), -1)
            t = pi.t.numpy().astype(np.float64)
            t[prim < 0] = np.inf
            return t, prim
        rays = np.empty((len(d), 6), np.float32)
        rays[:, :3] = o
        rays[:, 3:] = d
        ans = self._scene.cast_rays(self._o3d.core.Tensor(rays), nthreads=self._threads)
        t = ans["t_hit"].numpy().astype(np.float64)
        prim = ans["primitive_ids"].numpy().astype(np.int64)
        miss = ~np.isfinite(t)
        prim[miss] = -1
        return t, prim


def mitsuba_mesh(mi, name: str, vertices: np.ndarray, faces: np.ndarray, texcoords: np.ndarray | None = None,
                 attributes: dict[str, np.ndarray] | None = None, bsdf=None):
    """A ``mi.Mesh`` from numpy arrays (works in scalar and llvm variants).

    vertices : (n, 3) float; faces : (m, 3) int; texcoords : (n, 2) float or None;
    attributes : name -> (n, k) float per-vertex attributes (e.g. ``vertex_color``), usable with the
    ``mesh_attribute`` texture; bsdf : a loaded BSDF or None.
    """
    mesh = mi.Mesh(name, vertex_count=len(vertices), face_count=len(faces), has_vertex_normals=False,
                   has_vertex_texcoords=texcoords is not None)
    params = mi.traverse(mesh)
    params["vertex_positions"] = type(params["vertex_positions"])(np.asarray(vertices, np.float32).ravel())
    params["faces"] = type(params["faces"])(np.asarray(faces, np.uint32).ravel())
    if texcoords is not None:
        params["vertex_texcoords"] = type(params["vertex_texcoords"])(np.asarray(texcoords, np.float32).ravel())
    params.update()
    for key, values in (attributes or {}).items():
        values = np.asarray(values, np.float32).reshape(len(vertices), -1)
        mesh.add_attribute(key, values.shape[1], type(params["vertex_positions"])(values.ravel()))
    if bsdf is not None:
        mesh.set_bsdf(bsdf)
    return mesh
