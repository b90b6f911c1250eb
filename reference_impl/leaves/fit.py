"""Fitting the 21-parameter Bezier leaf to a segmented leaf point cloud (Chaurasia and Beardsley 2017,
section 5, Eq. 9-11).

1. Axis alignment: the cloud's principal axes (SVD) give the leaf plane (normal = least variance, oriented to the
   ``up`` side: the upper side of a leaf faces the sky).
2. Base and apex: the ends of the major axis of the minimum-area enclosing ellipse of the in-plane coordinates
   (section 5.1: the ellipse extrapolates occluded tips). Which end is the base is not observable from one cloud;
   both are fitted and the lower residual wins.
3. UV mapping by scanlines perpendicular to the current axis (section 5): a point within half the scanline spacing
   of scanline ``v_j`` gets ``v = v_j`` and ``u`` = its signed distance from the axis over the farthest point of the
   same scanline and side. (The paper normalises by "the maximum distance from the axis across all scanlines";
   with that global factor ``u = 1`` would be the widest half-width at every ``v`` and the fit could not follow a
   tapering silhouette, so the factor here is per scanline and side, the same ``x_{v,s}`` Eq. 10 uses.)
4. Occlusion weights (Eq. 10): ``w_v = x_{v,s} / (x_{v,s} + x_{v,e})`` per scanline and side, ``x_{v,e}`` the
   distance from the farthest sample to the enclosing ellipse along the scanline.
5. Weighted Levenberg-Marquardt (Eq. 11) from the axis as a straight line and the silhouette initialised to the
   enclosing ellipse, alternating with re-mapping until the weighted RMS residual stops changing (the paper: 4-15
   iterations). The default solver, :func:`lm_batch`, runs the LM steps of all of a plant's leaves as one
   vectorised computation; ``LeafParams(lm_backend="scipy")`` uses ``scipy.optimize.least_squares(method="lm")``
   (MINPACK) one leaf at a time, the same energy, an order of magnitude slower for hundreds of leaves.

The leaf model itself is :mod:`plantbench.geometry.leaf` (shared with the generator).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from plantbench.errors import InputError
from plantbench.geometry.leaf import (
    BezierLeaf,
    axis_control,
    axis_frame,
    bernstein,
    half_controls,
    leaf_points,
    max_half_width,
)
from plantbench.plant import check_shape

from .ellipse import Ellipse
from .params import LeafParams

__all__ = ["LeafFit", "LeafModel", "fit_leaf", "fit_leaves", "lm_batch", "linear_jacobian", "uv_mapping",
           "uv_mapping_batch", "model_weights", "initial_params", "leaf_frame"]


@dataclass(frozen=True)
class LeafFit:
    """A fitted leaf.

    omega : (21,) float, Bezier parameters (unit leaf, :data:`plantbench.geometry.leaf.PARAM_NAMES` order)
    transform : (4, 4) float, leaf frame (metres) to world; length, width : metres
    rms : weighted RMS residual of the last Levenberg-Marquardt solve, in leaf lengths
    iterations : alternations of UV mapping and Levenberg-Marquardt used
    """

    omega: np.ndarray
    transform: np.ndarray
    length: float
    width: float
    rms: float
    iterations: int
    reset: bool = False
    """True when the fitted blade came out wider than ``max_width_factor`` x the enclosing ellipse (the silhouette
    ran away where no points constrain it) and the leaf kept the ellipse-shaped start instead."""

    def surface(self, nu: int = 9, nv: int = 17) -> np.ndarray:
        """(nu * nv, 3) world points on the fitted surface, a (u, v) grid."""
        u, v = (a.ravel() for a in np.meshgrid(np.linspace(-1, 1, nu), np.linspace(0, 1, nv)))
        local = leaf_points(self.omega, u, v) * self.length
        return local @ self.transform[:3, :3].T + self.transform[:3, 3]


class LeafModel:
    """:func:`plantbench.geometry.leaf.leaf_points` at fixed (u, v), fast: the surface is a fixed linear combination
    of the control points of A, F, G and S (Eq. 5-6; both halves), so the (m, 34) weights are computed once and
    each evaluation is the control points (the model's own :func:`half_controls`) and one product.

    u, v : (m,) float, as in ``leaf_points``
    """

    def __init__(self, u: np.ndarray, v: np.ndarray) -> None:
        self.weights = model_weights(np.asarray(u, float), np.asarray(v, float))

    @staticmethod
    def controls(omega: np.ndarray) -> np.ndarray:
        """(..., 34, 3) control points: axis, right F, G, S, left F, G, S."""
        axis, (sr, fr, gr), (sl, fl, gl) = half_controls(omega)
        return np.concatenate([axis, fr, gr, sr, fl, gl, sl], axis=-2)

    def __call__(self, omega: np.ndarray) -> np.ndarray:
        """(..., m, 3) surface points for parameter vectors (..., 21)."""
        return np.matmul(self.weights, self.controls(omega))

    def jacobian(self, omega: np.ndarray, step: float = 1e-7) -> np.ndarray:
        """(m * 3, 21) forward-difference Jacobian of the flattened points, one batched evaluation."""
        omega = np.asarray(omega, float)
        pts = self(np.concatenate([omega[None], omega[None] + step * np.eye(21)]))
        return ((pts[1:] - pts[0]) / step).reshape(21, -1).T


def leaf_frame(points: np.ndarray, up=(0.0, 0.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """Centroid (3,) and principal axes (3, 3) (rows: largest variance, middle, normal; right-handed, the normal on
    ``up``'s side) of a leaf cloud (section 5, axis alignment)."""
    c = points.mean(0)
    _, _, vt = np.linalg.svd(points - c, full_matrices=False)
    e1, e2 = vt[0], vt[1]
    e3 = np.cross(e1, e2)
    if e3 @ np.asarray(up, float) < 0:
        e2, e3 = -e2, -e3
    return c, np.stack([e1, e2, e3])


def initial_params(half_width: float) -> np.ndarray:
    """Omega with a straight axis and a silhouette that follows an ellipse of semi-minor axis ``half_width`` (leaf
    lengths) along the unit axis: inner silhouette control points at v = 1/4, 1/2, 3/4, their offsets the least-squares
    fit of the quartic to the ellipse's half-width (section 5.1: Omega initialised to the enclosing ellipse)."""
    t = np.linspace(0.0, 1.0, 41)
    target = half_width * np.sqrt(np.clip(1 - (2 * t - 1) ** 2, 0, None))
    basis = bernstein(t, 4)[:, 1:4]
    xs, *_ = np.linalg.lstsq(basis, target, rcond=None)
    omega = BezierLeaf().vector()
    omega[0:6] = [1 / 3, 0, 0, 2 / 3, 0, 0]
    omega[6:9] = [0.25, 0.5, 0.75]
    omega[9:12] = xs
    omega[12:21] = 0.0
    return omega


def model_weights(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(..., 34) weights of the control points of :meth:`LeafModel.controls` for surface points at (u, v) (...):
    Eq. 5-6, the axis by the cubic cross-section weight of u, F, G and S of the point's half by the others."""
    b3, b4, bu = bernstein(v, 3), bernstein(v, 4), bernstein(np.abs(u), 3)
    w = np.zeros(u.shape + (34,))
    w[..., 0:4] = bu[..., 0:1] * b3
    right = (u >= 0)[..., None]
    for off, sel in ((4, right), (19, ~right)):
        for k in range(3):  # F, G, S
            w[..., off + 5 * k: off + 5 * k + 5] = np.where(sel, bu[..., k + 1: k + 2] * b4, 0.0)
    return w


def uv_mapping(omega: np.ndarray, points: np.ndarray, ellipse: Ellipse | None, scanlines: int
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """UV mapping P_A by scanlines (section 5) and the occlusion weights of Eq. 10, for one leaf
    (:func:`uv_mapping_batch`).

    omega : (21,) float; points : (n, 3) float, unit leaf frame
    ellipse : the enclosing ellipse in the unit leaf frame's xy plane (None: all weights 1)
    returns : index (m,) of the mapped points, u (m,), v (m,), w (m,) (each point's scanline-side weight)
    """
    pts = np.asarray(points, float)[None]
    ell = None if ellipse is None else (ellipse.centre[None], ellipse.A[None])
    ok, u, v, w = uv_mapping_batch(np.asarray(omega, float)[None], pts, np.ones(pts.shape[:2], bool), ell, scanlines)
    idx = np.flatnonzero(ok[0])
    return idx, u[0, idx], v[0, idx], w[0, idx]


def uv_mapping_batch(omega: np.ndarray, points: np.ndarray, valid: np.ndarray,
                     ellipses: tuple[np.ndarray, np.ndarray] | None, scanlines: int
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """UV mapping of many leaves at once (padded): a point within half the scanline spacing of scanline v_j gets
    v = v_j and u = its signed distance from the axis over the farthest point of the same scanline and side;
    Eq. 10's weight of that scanline side is x_s / (x_s + x_e), x_e the distance on to the enclosing ellipse.

    omega : (k, 21); points : (k, n, 3), unit leaf frames; valid : (k, n) bool (False: padding)
    ellipses : centres (k, 2) and matrices (k, 2, 2) of the enclosing ellipses (None: all weights 1)
    returns : mapped (k, n) bool, u, v, w (k, n) float (0 where not mapped)
    """
    from .ellipse import ray_extent

    k, n = valid.shape
    vj = np.linspace(0.0, 1.0, scanlines)
    apts, normal = axis_frame(axis_control(omega), np.broadcast_to(vj, (k, scanlines)))  # (k, s, 3)
    apts, normal = apts[..., :2], normal[..., :2]
    tangent = np.stack([normal[..., 1], -normal[..., 0]], -1)  # in-plane unit tangents
    half = 0.5 * np.linalg.norm(np.diff(apts, axis=1), axis=2)  # (k, s - 1)
    reach = np.minimum(np.concatenate([half[:, :1], half], 1), np.concatenate([half, half[:, -1:]], 1))
    rel = points[:, :, None, :2] - apts[:, None]  # (k, n, s, 2)
    along = np.einsum("knsc,ksc->kns", rel, tangent)
    j = np.argmin(np.abs(along), axis=2)  # (k, n)
    kk = np.arange(k)[:, None]
    ok = valid & (np.abs(np.take_along_axis(along, j[..., None], 2)[..., 0]) <= reach[kk, j] + 1e-12)
    d = np.einsum("knc,knc->kn", np.take_along_axis(rel, j[..., None, None], 2)[:, :, 0], normal[kk, j])
    side = (d >= 0).astype(np.int64)
    key = (kk * scanlines + j) * 2 + side  # (k, n), one slot per leaf, scanline and side
    far = np.zeros(k * 2 * scanlines)
    np.maximum.at(far, key[ok], np.abs(d[ok]))
    denom = far[key]
    u = np.where(ok & (denom > 0), d / np.where(denom > 0, denom, 1.0), 0.0)
    w = ok.astype(float)
    if ellipses is not None:
        keys = np.flatnonzero(far > 0)
        leaf, rest = np.divmod(keys, 2 * scanlines)
        sj, ss = rest // 2, rest % 2
        dirs = np.where(ss == 1, 1.0, -1.0)[:, None] * normal[leaf, sj]
        origin = apts[leaf, sj] + dirs * far[keys][:, None]
        xe = ray_extent(ellipses[0][leaf], ellipses[1][leaf], origin, dirs)
        wk = np.ones(k * 2 * scanlines)
        wk[keys] = far[keys] / (far[keys] + xe)
        w = np.where(ok, wk[key], 0.0)
    return ok, u, np.where(ok, vj[j], 0.0), w


NONLINEAR = 9
"""Parameters 0-8 (axis control points and the silhouette stations vbar) move the control points nonlinearly; 9-20
(sideways offsets xs and heights zs, zf, zg) linearly (Eq. 3-4): their derivatives are :func:`linear_jacobian`."""


def linear_jacobian(omega: np.ndarray) -> np.ndarray:
    """(k, 12, 34, 3) exact derivatives of :meth:`LeafModel.controls` with respect to omega[9:21] (Eq. 3-4: an
    inner control point i of S, F, G is ``A(vbar_i) + frac xs_i n(vbar_i) + z_i zhat`` with frac 1, 1/3, 2/3; the
    left half mirrors xs)."""
    omega = np.asarray(omega, float)
    _, normal = axis_frame(axis_control(omega), omega[:, 6:9])  # (k, 3, 3)
    jac = np.zeros((len(omega), 12, 34, 3))
    # control layout of LeafModel.controls: axis 0-3, right F 4-8, G 9-13, S 14-18, left F 19-23, G 24-28, S 29-33
    for first, frac, zgroup in ((4, 1 / 3, 1), (9, 2 / 3, 2), (14, 1.0, 0)):
        for side, sign in ((0, 1.0), (15, -1.0)):
            for i in range(3):
                jac[:, i, first + side + 1 + i] = sign * frac * normal[:, i]
                jac[:, 3 + 3 * zgroup + i, first + side + 1 + i, 2] = 1.0
    return jac


def lm_batch(omega: np.ndarray, weights: np.ndarray, target: np.ndarray, w: np.ndarray, iterations: int,
             damping: np.ndarray | None = None, step: float = 1e-7) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weighted Levenberg-Marquardt on many leaves at once (Eq. 11 with the UV mapping fixed).

    The surface points are ``P = W C(omega)`` with ``W`` fixed by the UV mapping (:class:`LeafModel`), so the
    weighted cost ``sum_i w_i |P_i - T_i|^2 = tr(C^T G C) - 2 tr(C^T H) + t0`` with ``G = W^T diag(w) W`` (34 x 34)
    and ``H = W^T diag(w) T`` computed once; the Gauss-Newton matrix ``J^T J = dC^T G dC`` needs only the
    derivatives of the 34 control points. Each step costs the same whatever the number of points.

    omega : (k, 21) float, start; weights : (k, m, 34) :class:`LeafModel` weights (padding rows zero)
    target : (k, m, 3) float, mapped points; w : (k, m) float, Eq. 10 weights (0: padding)
    iterations : LM steps (forward-difference derivatives of the control points, damped normal equations with
        Marquardt's diagonal scaling, a step kept when it lowers the cost, damping divided by 3 then, else x 4)
    returns : omega (k, 21), cost (k,) (weighted sum of squared distances), final damping (k,)
    """
    k = len(omega)
    omega = omega.copy()
    lam = np.full(k, 1e-3) if damping is None else damping.copy()
    eye = np.eye(21)
    ww = weights * w[..., None]
    gram = np.matmul(ww.transpose(0, 2, 1), weights)  # (k, 34, 34)
    h = np.matmul(ww.transpose(0, 2, 1), target)  # (k, 34, 3)
    t0 = np.einsum("km,kmc,kmc->k", w, target, target)

    def cost_of(ctrl):  # batched matmuls: einsum's generic loops were half of the fit's time
        return np.sum(ctrl * (np.matmul(gram, ctrl) - 2 * h), axis=(1, 2)) + t0

    ctrl = LeafModel.controls(omega)
    cost = cost_of(ctrl)
    offsets = np.concatenate([np.zeros((1, 21)), step * eye[:NONLINEAR]])[None]
    for _ in range(iterations):
        cb = LeafModel.controls(omega[:, None, :] + offsets)  # (k, 10, 34, 3)
        dc = np.concatenate([(cb[:, 1:] - cb[:, :1]) / step, linear_jacobian(omega)], axis=1)  # (k, 21, 34, 3)
        dct = dc.transpose(0, 1, 3, 2).reshape(k, 63, 34)  # rows: (parameter, coordinate)
        a = np.matmul(dct.reshape(k, 21, 102), np.matmul(dct, gram).reshape(k, 21, 102).transpose(0, 2, 1))
        r = (np.matmul(gram, ctrl) - h).transpose(0, 2, 1).reshape(k, 102, 1)
        g = np.matmul(dct.reshape(k, 21, 102), r)[..., 0]
        diag = np.maximum(np.diagonal(a, axis1=1, axis2=2), 1e-12)
        lhs = a + lam[:, None, None] * diag[:, None, :] * eye
        try:
            delta = -np.linalg.solve(lhs, g[..., None])[..., 0]
        except np.linalg.LinAlgError:
            delta = -np.stack([np.linalg.lstsq(m_, g_, rcond=None)[0] for m_, g_ in zip(lhs, g, strict=True)])
        trial = omega + delta
        c_trial = LeafModel.controls(trial)
        c_new = cost_of(c_trial)
        better = np.isfinite(c_new) & (c_new < cost)
        omega[better] = trial[better]
        ctrl[better] = c_trial[better]
        cost = np.where(better, c_new, cost)
        lam = np.where(better, lam / 3.0, np.minimum(lam * 4.0, 1e12))
    return omega, np.maximum(cost, 0.0), lam


@dataclass
class _Problem:
    """One leaf (one base/apex choice) being fitted, in its unit leaf frame."""

    pts: np.ndarray
    ellipse: Ellipse
    omega: np.ndarray
    base: np.ndarray
    m2: np.ndarray
    length: float
    leaf: int
    rms: float = np.inf
    iterations: int = 0
    done: bool = False


def _alternate(problems: list[_Problem], params: LeafParams, iterations: int) -> None:
    """Up to ``iterations`` alternations of UV mapping and weighted LM on every problem not yet converged."""
    for _ in range(iterations):
        active = [p for p in problems if not p.done]
        if not active:
            return
        for chunk in range(0, len(active), 512):
            _alternate_chunk(active[chunk: chunk + 512], params)


def _alternate_chunk(part: list[_Problem], params: LeafParams) -> None:
    """One UV mapping (all problems of ``part`` at once, padded) and one weighted LM solve of each."""
    n = max(len(p.pts) for p in part)
    pts = np.zeros((len(part), n, 3))
    valid = np.zeros((len(part), n), bool)
    for i, p in enumerate(part):
        pts[i, : len(p.pts)] = p.pts
        valid[i, : len(p.pts)] = True
    ellipses = None
    if params.occlusion_weights:
        ellipses = (np.stack([p.ellipse.centre for p in part]), np.stack([p.ellipse.A for p in part]))
    omega = np.stack([p.omega for p in part])
    ok, u, v, w = uv_mapping_batch(omega, pts, valid, ellipses, params.scanlines)
    mapped = ok.sum(1)
    for i in np.flatnonzero(mapped < 8):
        part[i].done = True
    keep = np.flatnonzero(mapped >= 8)
    if params.lm_backend == "scipy":
        for i in keep:
            idx = np.flatnonzero(ok[i])
            om, cost = _scipy_lm(omega[i], LeafModel(u[i, idx], v[i, idx]), pts[i, idx], np.sqrt(w[i, idx]),
                                 params.lm_evaluations)
            _update(part[i], om, cost, w[i].sum(), params)
        return
    om, cost, _ = lm_batch(omega[keep], model_weights(u[keep], v[keep]), pts[keep], w[keep], params.lm_evaluations)
    for j, i in enumerate(keep):
        _update(part[i], om[j], cost[j], w[i].sum(), params)


def _update(p: _Problem, omega: np.ndarray, cost: float, wsum: float, params: LeafParams) -> None:
    rms = float(np.sqrt(cost / max(wsum, 1e-12) / 3))
    p.omega = omega
    p.iterations += 1
    if abs(p.rms - rms) < params.fit_tolerance or p.iterations >= params.fit_iterations:
        p.done = True
    p.rms = rms


def _scipy_lm(omega: np.ndarray, model: LeafModel, target: np.ndarray, sw: np.ndarray, evaluations: int
              ) -> tuple[np.ndarray, float]:
    """One weighted LM solve with scipy's MINPACK (``least_squares(method="lm")``)."""
    from scipy.optimize import least_squares

    sw3 = np.repeat(sw, 3)[:, None]

    def fun(om):
        return (sw[:, None] * (model(om) - target)).ravel()

    def jac(om):
        return model.jacobian(om) * sw3

    res = least_squares(fun, omega, jac=jac, method="lm", max_nfev=max(evaluations, 2 * 22))
    return res.x, float(2 * res.cost)


def fit_leaves(clouds: list[np.ndarray], *, params: LeafParams = LeafParams(), rng: np.random.Generator,
               up=(0.0, 0.0, 1.0)) -> list[LeafFit | str]:
    """Fit the Bezier leaf to many leaf clouds at once (section 5); see :func:`fit_leaf`.

    returns : per cloud a :class:`LeafFit`, or the skip reason (``"few_points"``, ``"degenerate_ellipse"``,
        ``"fit_failed"``)
    """
    from .ellipse import min_volume_ellipses

    need = max(params.min_candidate_points, 8)
    out: list[LeafFit | str] = ["few_points"] * len(clouds)
    prepared = []
    for i, cloud in enumerate(clouds):
        pts = check_shape("leaf points", cloud, (-1, 3), "f")
        if len(pts) < need:
            continue
        if len(pts) > params.max_fit_points:
            pts = pts[np.sort(rng.choice(len(pts), params.max_fit_points, replace=False))]
        c, frame = leaf_frame(pts, up)
        prepared.append((i, c, frame, (pts - c) @ frame.T))
    ellipses = min_volume_ellipses([q[:, :2] for _, _, _, q in prepared])
    problems: list[_Problem] = []
    for (i, _, _, q), ell in zip(prepared, ellipses, strict=True):
        if ell is None or ell.semi_axes[1] <= 1e-9 * ell.semi_axes[0]:
            out[i] = "degenerate_ellipse"
            continue
        ends = ell.major_ends()
        b = ell.semi_axes[1]
        for base, apex in (ends, ends[::-1]):  # which end is the base: both, the better one goes on
            d = apex - base
            length = float(np.linalg.norm(d))
            d = d / length
            m2 = np.array([d, [-d[1], d[0]]])  # rows: leaf x, leaf y (y = z cross x)
            local = np.column_stack([(q[:, :2] - base) @ m2.T, q[:, 2]]) / length
            ell_unit = Ellipse(m2 @ (ell.centre - base) / length, length**2 * m2 @ ell.A @ m2.T)
            problems.append(_Problem(local, ell_unit, initial_params(b / length), base, m2, length, i))
    _alternate(problems, params, min(2, params.fit_iterations))
    best: dict[int, _Problem] = {}
    for p in problems:
        if p.leaf not in best or p.rms < best[p.leaf].rms:
            best[p.leaf] = p
    chosen = list(best.values())
    _alternate(chosen, params, params.fit_iterations)
    frames = {i: (c, frame) for i, c, frame, _ in prepared}
    ok = []
    for p in chosen:
        if np.all(np.isfinite(p.omega)) and np.isfinite(p.rms):
            ok.append(p)
        else:
            out[p.leaf] = "fit_failed"
    if not ok:
        return out
    b_unit = np.array([p.ellipse.semi_axes[1] for p in ok])
    omegas = np.stack([p.omega for p in ok])
    reset = ~(max_half_width(omegas) <= params.max_width_factor * b_unit)
    for i in np.flatnonzero(reset):
        omegas[i] = initial_params(b_unit[i])
    widths = 2 * max_half_width(omegas) * np.array([p.length for p in ok])
    for p, omega, width, r in zip(ok, omegas, widths, reset, strict=True):
        c, frame = frames[p.leaf]
        m3 = np.eye(3)
        m3[:2, :2] = p.m2
        tr = np.eye(4)
        tr[:3, :3] = frame.T @ m3.T
        tr[:3, 3] = c + frame.T @ np.array([p.base[0], p.base[1], 0.0])
        out[p.leaf] = (LeafFit(omega, tr, p.length, float(width), p.rms, p.iterations, bool(r)) if width > 0
                       else "fit_failed")
    return out


def fit_leaf(points: np.ndarray, *, params: LeafParams = LeafParams(), rng: np.random.Generator,
             up=(0.0, 0.0, 1.0)) -> LeafFit:
    """Fit the Bezier leaf to one leaf's points (section 5).

    points : (n, 3) float, world coordinates (n >= ``params.min_candidate_points``)
    rng : subsamples clouds larger than ``params.max_fit_points``
    up : the side the fitted upper surface (+z of the leaf frame) faces
    Raises InputError for too few points or a degenerate (collinear) cloud.
    """
    res = fit_leaves([points], params=params, rng=rng, up=up)[0]
    if isinstance(res, str):
        raise InputError(f"leaf fit skipped: {res.replace('_', ' ')}")
    return res
