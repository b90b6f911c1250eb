"""The Bezier leaf of Chaurasia and Beardsley 2017 (ICCV, Eq. 1-6): 21 parameters, vectorised.

A leaf is described by four Bezier curves in a unit leaf frame whose base is at the origin and apex at
``(1, 0, 0)`` (plantbench's leaf convention, see :class:`plantbench.plant.Leaf`: the blade axis runs along +x,
the blade spans y, +z is the upper-side normal; the paper puts the length on y and the width on x, which is the
same model rotated by 90 degrees about z):

- the central axis ``A`` (midrib), a cubic with control points ``a0 = (0,0,0), a1, a2, a3 = (1,0,0)``;
  ``a1`` and ``a2`` are free in 3D (6 parameters; z bends the midrib out of the leaf plane);
- the silhouette ``S``, a quartic whose end points are the base and apex and whose three inner control points are
  ``s_i = A(v_i) + x_i n(v_i) + zs_i z`` (Eq. 3), with ``n`` the in-plane normal of the axis (Eq. 2) (9 parameters:
  ``v_i``, ``x_i``, ``zs_i``);
- two longitudinal quartics ``F`` and ``G`` at one and two thirds of the width (Eq. 4a, 4b),
  ``f_i = A(v_i) + x_i/3 n(v_i) + zf_i z`` and ``g_i = A(v_i) + 2 x_i/3 n(v_i) + zg_i z`` (6 parameters);
- the cross-section cubic ``C_v`` with control points ``A(v), F(v), G(v), S(v)`` (Eq. 5), evaluated at ``|u|``
  (Eq. 6). The half ``u < 0`` uses ``-x_i``.

Total 6 + 9 + 3 + 3 = 21 numbers (the paper's m = 4 axis control points, n = 5 for the other curves). The surface
point for ``(u, v) in [-1, 1] x [0, 1]`` is a polynomial in the parameters and (u, v) apart from the normalisation
of the axis normal, so every function here is a pure numpy function of the parameter vector (batched over leading
axes), suitable for least-squares fitting.

A leaf of length ``L`` is the unit leaf scaled uniformly by ``L`` (:func:`tessellate`'s ``length``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

import numpy as np

from plantbench.plant import TriMesh

__all__ = ["BezierLeaf", "PARAM_NAMES", "bezier", "bernstein", "axis_control", "axis_frame", "half_controls",
           "leaf_points", "leaf_grid", "silhouette_outline", "max_half_width", "tessellate", "tessellate_many",
           "tessellate_placed", "petiole_prisms", "PRISM_FACES"]


@dataclass(frozen=True)
class BezierLeaf:
    """The 21 parameters of one leaf in the unit leaf frame (base (0,0,0), apex (1,0,0), lengths in leaf lengths)."""

    axis1_x: float = 1 / 3
    """Axis control point a1, x (along the blade)."""
    axis1_y: float = 0.0
    """Axis control point a1, y (sideways skew: asymmetric leaves)."""
    axis1_z: float = 0.0
    """Axis control point a1, z (midrib bend out of the leaf plane)."""
    axis2_x: float = 2 / 3
    """Axis control point a2, x."""
    axis2_y: float = 0.0
    """Axis control point a2, y."""
    axis2_z: float = 0.0
    """Axis control point a2, z."""
    sil_v1: float = 0.15
    """Silhouette control point 1: position along the axis (Bezier parameter of A), Eq. 3's v_1."""
    sil_v2: float = 0.45
    """Silhouette control point 2: position along the axis."""
    sil_v3: float = 0.85
    """Silhouette control point 3: position along the axis."""
    sil_x1: float = 0.25
    """Silhouette control point 1: offset across the blade (half-width, leaf lengths), Eq. 3's x_s1."""
    sil_x2: float = 0.35
    """Silhouette control point 2: offset across the blade."""
    sil_x3: float = 0.15
    """Silhouette control point 3: offset across the blade."""
    sil_z1: float = 0.0
    """Silhouette control point 1: offset along the leaf normal (margin curl), Eq. 3's z_s1."""
    sil_z2: float = 0.0
    """Silhouette control point 2: offset along the normal."""
    sil_z3: float = 0.0
    """Silhouette control point 3: offset along the normal."""
    f_z1: float = 0.0
    """Longitudinal Bezier F (one third of the width), control point 1 offset along the normal, Eq. 4a."""
    f_z2: float = 0.0
    """F, control point 2 offset along the normal."""
    f_z3: float = 0.0
    """F, control point 3 offset along the normal."""
    g_z1: float = 0.0
    """Longitudinal Bezier G (two thirds of the width), control point 1 offset along the normal, Eq. 4b."""
    g_z2: float = 0.0
    """G, control point 2 offset along the normal."""
    g_z3: float = 0.0
    """G, control point 3 offset along the normal."""

    def vector(self) -> np.ndarray:
        """(21,) float, in :data:`PARAM_NAMES` order."""
        return np.array([getattr(self, n) for n in PARAM_NAMES], dtype=np.float64)

    @classmethod
    def from_vector(cls, omega: np.ndarray) -> BezierLeaf:
        omega = np.asarray(omega, dtype=np.float64).reshape(21)
        return cls(**{n: float(x) for n, x in zip(PARAM_NAMES, omega)})

    def to_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in asdict(self).items()}


PARAM_NAMES: tuple[str, ...] = tuple(f.name for f in fields(BezierLeaf))
assert len(PARAM_NAMES) == 21

_BINOM = {2: np.array([1.0, 2.0, 1.0]), 3: np.array([1.0, 3.0, 3.0, 1.0]), 4: np.array([1.0, 4.0, 6.0, 4.0, 1.0])}


def bernstein(t: np.ndarray, degree: int) -> np.ndarray:
    """(..., degree + 1) Bernstein basis at ``t`` (...)."""
    t = np.asarray(t, dtype=np.float64)
    s = 1.0 - t
    tp, sp = [np.ones_like(t)], [np.ones_like(t)]
    for _ in range(degree):  # powers by products: float ** int-array was the leaf fit's largest single cost
        tp.append(tp[-1] * t)
        sp.append(sp[-1] * s)
    return _BINOM[degree] * np.stack([tp[k] * sp[degree - k] for k in range(degree + 1)], axis=-1)


def _bernstein_deriv(t: np.ndarray, degree: int) -> np.ndarray:
    """(..., degree + 1) derivative of the Bernstein basis at ``t``."""
    lower = bernstein(t, degree - 1)
    pad = np.zeros(lower.shape[:-1] + (1,))
    return degree * (np.concatenate([pad, lower], -1) - np.concatenate([lower, pad], -1))


def bezier(control: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Points of Bezier curves (Eq. 1).

    control : (..., d + 1, 3) float, control points (d = 3 or 4)
    t : (m,) float in [0, 1]
    returns : (..., m, 3) float
    """
    control = np.asarray(control, dtype=np.float64)
    basis = bernstein(t, control.shape[-2] - 1)  # (m, d+1)
    return np.einsum("mk,...kc->...mc", basis, control)


def axis_control(omega: np.ndarray) -> np.ndarray:
    """(..., 4, 3) control points of the axis A."""
    lead = omega.shape[:-1]
    a0 = np.zeros(lead + (3,))
    a3 = np.broadcast_to(np.array([1.0, 0.0, 0.0]), lead + (3,))
    return np.stack([a0, omega[..., 0:3], omega[..., 3:6], a3], axis=-2)


def axis_frame(axis: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Axis points (..., m, 3) and in-plane unit normals (Eq. 2) at parameters t (..., m)."""
    basis = bernstein(t, 3)
    dbasis = _bernstein_deriv(t, 3)
    pts = np.einsum("...mk,...kc->...mc", basis, axis)
    tan = np.einsum("...mk,...kc->...mc", dbasis, axis)
    tx, ty = tan[..., 0], tan[..., 1]
    norm = np.sqrt(tx**2 + ty**2)
    norm = np.where(norm > 1e-12, norm, 1.0)
    normal = np.stack([-ty / norm, tx / norm, np.zeros_like(tx)], axis=-1)
    return pts, normal


def _longitudinal_controls(omega: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Axis control (..., 4, 3) and right-half silhouette, F and G control points (..., 5, 3) each (Eq. 3-4)."""
    axis, right, _ = half_controls(omega)
    return (axis, *right)


def half_controls(omega: np.ndarray) -> tuple[np.ndarray, tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
    """Axis control (..., 4, 3) and the silhouette, F and G control points (..., 5, 3) of the right and of the left
    half (which mirrors the sideways offsets of S, F and G) (Eq. 3-4), from one evaluation of the axis frame."""
    omega = np.asarray(omega, dtype=np.float64)
    axis = axis_control(omega)
    vbar = omega[..., 6:9]
    zs, zf, zg = omega[..., 12:15], omega[..., 15:18], omega[..., 18:21]
    pts, normal = axis_frame(axis, vbar)  # (..., 3, 3)
    zhat = np.array([0.0, 0.0, 1.0])
    base = axis[..., :1, :]
    apex = axis[..., 3:, :]

    def curve(frac: float, xs: np.ndarray, z: np.ndarray) -> np.ndarray:
        inner = pts + frac * xs[..., None] * normal + z[..., None] * zhat
        return np.concatenate([base, inner, apex], axis=-2)

    def half(xs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return curve(1.0, xs, zs), curve(1.0 / 3.0, xs, zf), curve(2.0 / 3.0, xs, zg)

    return axis, half(omega[..., 9:12]), half(-omega[..., 9:12])


def leaf_points(omega: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Surface points L_Omega(u, v) of the unit leaf (Eq. 6).

    omega : (..., 21) float, parameter vectors (:data:`PARAM_NAMES` order)
    u : (m,) float in [-1, 1], across the blade (0 the midrib, +-1 the margins; +1 is the +y side)
    v : (m,) float in [0, 1], along the blade (0 base, 1 apex)
    returns : (..., m, 3) float
    """
    u = np.asarray(u, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    omega = np.asarray(omega, dtype=np.float64)
    lead = omega.shape[:-1]
    out = np.empty(lead + (len(u), 3))
    axis, right, left = half_controls(omega)
    for sel, (sil, f, g) in ((u >= 0, right), (u < 0, left)):
        idx = np.flatnonzero(sel)
        if len(idx) == 0:
            continue
        b3 = bernstein(v[idx], 3)  # (q, 4)
        b4 = bernstein(v[idx], 4)  # (q, 5)
        a_v = np.matmul(b3, axis)  # (..., q, 3)
        bu = bernstein(np.abs(u[idx]), 3)  # (q, 4): cross-section weights of A, F, G, S
        out[..., idx, :] = (bu[:, 0:1] * a_v + bu[:, 1:2] * np.matmul(b4, f) + bu[:, 2:3] * np.matmul(b4, g)
                            + bu[:, 3:4] * np.matmul(b4, sil))
    return out


def silhouette_outline(omega: np.ndarray, n: int = 256) -> np.ndarray:
    """(..., n, 3) points of the right-half silhouette S(v), v from 0 to 1."""
    _, sil, _, _ = _longitudinal_controls(omega)
    return bezier(sil, np.linspace(0.0, 1.0, n))


def max_half_width(omega: np.ndarray, n: int = 129) -> np.ndarray:
    """(...,) largest distance of the right-half silhouette from the leaf's x axis (unit leaf), sampled."""
    return np.abs(silhouette_outline(omega, n)[..., 1]).max(axis=-1)


def leaf_grid(resolution: tuple[int, int] = (4, 8)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A triangulated (u, v) grid, shared by every leaf of a tessellation.

    resolution : (nu, nv), segments across each half of the blade and along it.
    Returns ``u (m,)``, ``v (m,)`` and ``faces (k, 3)``; the base and the apex are single vertices (the grid rows at
    v = 0 and v = 1 collapse there), and faces wind counter-clockwise seen from +z on a flat leaf.
    """
    nu, nv = int(resolution[0]), int(resolution[1])
    if nu < 1 or nv < 2:
        raise ValueError("leaf resolution must be at least (1, 2)")
    us = np.linspace(-1.0, 1.0, 2 * nu + 1)
    vs = np.linspace(0.0, 1.0, nv + 1)
    ncol = len(us)
    # vertex 0 = base, then interior rows, last = apex
    inner_rows = nv - 1
    u = np.concatenate([[0.0], np.tile(us, inner_rows), [0.0]])
    v = np.concatenate([[0.0], np.repeat(vs[1:-1], ncol), [1.0]])
    apex = 1 + inner_rows * ncol

    def vid(row: np.ndarray, col: np.ndarray) -> np.ndarray:
        return np.where(row == 0, 0, np.where(row == nv, apex, 1 + (row - 1) * ncol + col))

    r, c = np.meshgrid(np.arange(nv), np.arange(ncol - 1), indexing="ij")
    r, c = r.ravel(), c.ravel()
    v00, v01, v10, v11 = vid(r, c), vid(r, c + 1), vid(r + 1, c), vid(r + 1, c + 1)
    # (u, v) maps to (x ~ v, y ~ u): increasing u is +y, increasing v is +x; ccw from +z: (v00, v10, v11) etc.
    tris = np.concatenate([np.stack([v00, v01, v11], 1), np.stack([v00, v11, v10], 1)])
    keep = (tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2]) & (tris[:, 0] != tris[:, 2])
    tris = tris[keep]
    # orient: a flat default leaf must have +z normals
    return u, v, _orient_up(u, v, tris)


def _orient_up(u: np.ndarray, v: np.ndarray, tris: np.ndarray) -> np.ndarray:
    p = np.stack([v, u, np.zeros_like(u)], 1)  # flat, straight stand-in: x = v, y = u
    a, b, c = p[tris[:, 0]], p[tris[:, 1]], p[tris[:, 2]]
    nz = np.cross(b - a, c - a)[:, 2]
    flip = nz < 0
    tris = tris.copy()
    tris[flip] = tris[flip][:, [0, 2, 1]]
    return tris


def tessellate_many(omega: np.ndarray, lengths: np.ndarray, resolution: tuple[int, int] = (4, 8)
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Tessellate k leaves at once, each in its own (metric) leaf frame.

    omega : (k, 21) float; lengths : (k,) float, metres
    returns : vertices (k, m, 3) and the shared faces (f, 3) (index per leaf block)
    """
    u, v, faces = leaf_grid(resolution)
    pts = leaf_points(np.asarray(omega, dtype=np.float64), u, v)
    return pts * np.asarray(lengths, dtype=np.float64)[:, None, None], faces


def tessellate_placed(omega: np.ndarray, lengths: np.ndarray, rot: np.ndarray, base: np.ndarray,
                      resolution: tuple[int, int] = (4, 8)) -> tuple[np.ndarray, np.ndarray]:
    """Tessellate k leaves at once in world coordinates: leaf frame -> world by ``rot`` (k, 3, 3) (columns: the
    leaf's x, y, z axes) and ``base`` (k, 3).

    returns : vertices (k, m, 3) and faces (k * f, 3) indexing the flattened vertices, leaf by leaf
    """
    verts, tri = tessellate_many(omega, lengths, resolution)
    world = np.einsum("kij,kqj->kqi", rot, verts) + base[:, None, :]
    q = verts.shape[1]
    return world, (tri[None, :, :] + (np.arange(len(world)) * q)[:, None, None]).reshape(-1, 3)


def tessellate(leaf: BezierLeaf | np.ndarray, length: float = 1.0, resolution: tuple[int, int] = (4, 8)) -> TriMesh:
    """One leaf as a :class:`TriMesh` in its leaf frame, scaled to ``length`` metres."""
    omega = leaf.vector() if isinstance(leaf, BezierLeaf) else np.asarray(leaf, dtype=np.float64)
    verts, faces = tessellate_many(omega[None], np.array([length]), resolution)
    return TriMesh(verts[0], faces)


PRISM_FACES = np.array([[0, 1, 4], [1, 2, 5], [2, 0, 3], [0, 4, 3], [1, 5, 4], [2, 3, 5]])
"""The six side triangles of a triangular prism whose vertices are ring 0-2 at one end and 3-5 at the other."""


def petiole_prisms(start: np.ndarray, base: np.ndarray, radius: float) -> np.ndarray:
    """(m, 6, 3) vertices of triangular prisms of ``radius`` from ``start`` (m, 3) to ``base`` (m, 3), a petiole
    from the twig axis to each blade base; :data:`PRISM_FACES` index each prism's six vertices."""
    from plantbench.geometry.tubes import unit

    e = unit(base - start)
    e1 = unit(np.cross(e, np.where(np.abs(e[:, [2]]) < 0.9, np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]))))
    e2 = np.cross(e, e1)
    th = 2 * np.pi * np.arange(3) / 3
    ring = np.cos(th)[None, :, None] * e1[:, None, :] + np.sin(th)[None, :, None] * e2[:, None, :]
    return np.concatenate([start[:, None, :] + radius * ring, base[:, None, :] + radius * ring], axis=1)
