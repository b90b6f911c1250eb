"""Per-view depth and normal maps on the CPU: a ZNCC plane sweep, then slanted-plane PatchMatch, in Dr.Jit LLVM.

Seed 000 section 4 (depth initialisation, Eq. 1-2): each reference pixel gets a plane (depth d, normal n) whose
homography ``H = K_j (R_rel + t_rel n^T / rho) K_i^-1`` maps its support window into every source view, scored
by photo-consistency. We do it in two stages:

1. **Plane sweep** (initialisation): ``hypotheses`` fronto-parallel planes uniform in inverse depth over the view's
   depth range. Per plane and source, the source image is warped by the plane's homography (bilinear texture
   lookups), the ZNCC over a ``sweep_window``^2 box is computed with separable box sums, the per-source costs
   ``1 - ZNCC`` are aggregated as the mean of the ``top_k`` best (occlusion-robust), and the winner takes all,
   refined by a parabola through the neighbouring planes' costs.
2. **PatchMatch refinement** with slanted planes (Bleyer et al. 2011, Galliani et al. 2015 red-black scheme):
   every pixel tries its four neighbours' planes (propagation), two random perturbations of its own plane and a
   random normal; normals start from the sweep's depth-map gradient;
   the cost is a bilateral-weighted ZNCC over a (2r+1)^2 window whose samples are mapped through the pixel's own
   plane (exact per-sample ray-plane intersection, equivalent to the homography).

The graph-cut global optimisation of the seed (Eq. 4) is replaced by this local PatchMatch plus the multi-view
consistency filter of :mod:`.filtering` (see the module notes there). All pixels are processed at once as Dr.Jit
arrays (kernels compiled once and cached; the per-plane/per-iteration values are opaque so they are reused).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from plantbench.cameras import Camera
from plantbench.errors import InputError

from .params import DepthParams

__all__ = ["DepthMap", "estimate_depth", "to_gray", "sweep_depths"]


@dataclass(frozen=True)
class DepthMap:
    """One view's estimate.

    depth : (h, w) float32, z-depth in the view's camera frame; NaN where no depth was kept
    normal : (h, w, 3) float32, unit normal in world coordinates (facing the camera); NaN where no depth
    cost : (h, w) float32, final matching cost (1 - ZNCC, mean of the best sources), 2 where unmatched
    """

    depth: np.ndarray
    normal: np.ndarray
    cost: np.ndarray


def to_gray(image: np.ndarray) -> np.ndarray:
    """(h, w, 3) uint8 or float RGB -> (h, w) float32 luminance in [0, 1] (Rec. 601 weights)."""
    img = np.asarray(image)
    scale = 255.0 if img.dtype == np.uint8 else 1.0
    img = img.astype(np.float32) / scale
    if img.ndim == 2:
        return img
    return (img[..., :3] @ np.array([0.299, 0.587, 0.114], np.float32)).astype(np.float32)


def sweep_depths(near: float, far: float, count: int) -> np.ndarray:
    """(count,) depths uniform in inverse depth from ``far`` to ``near`` (index 0 is the farthest)."""
    if not 0 < near < far:
        raise InputError(f"depth range must satisfy 0 < near < far, got near={near}, far={far}")
    return 1.0 / np.linspace(1.0 / far, 1.0 / near, count)


def _drjit():
    from plantbench.backend import apply_thread_budget, find_libllvm

    llvm = find_libllvm()
    if llvm:
        os.environ.setdefault("DRJIT_LIBLLVM_PATH", llvm)
    import drjit as dr
    import drjit.llvm as jl

    apply_thread_budget(dr)
    return dr, jl


def _relative(ref: Camera, src: Camera) -> tuple[np.ndarray, np.ndarray]:
    r_rel = src.R @ ref.R.T
    return r_rel, src.t - r_rel @ ref.t


def _sort_network(dr, values: list) -> list:
    """Ascending order of a short list of Dr.Jit arrays (odd-even transposition sort with min/max)."""
    v = list(values)
    n = len(v)
    for rnd in range(n):
        for i in range(rnd % 2, n - 1, 2):
            lo, hi = dr.minimum(v[i], v[i + 1]), dr.maximum(v[i], v[i + 1])
            v[i], v[i + 1] = lo, hi
    return v


def _top_k_mean(dr, costs: list, k: int):
    s = _sort_network(dr, costs)
    k = max(1, min(k, len(s)))
    acc = s[0]
    for c in s[1:k]:
        acc = acc + c
    return acc / k


def _box_stats(gray: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard deviation over a ``window``^2 box (border replicated), numpy."""
    from scipy.ndimage import uniform_filter

    g = gray.astype(np.float64)
    m = uniform_filter(g, window, mode="nearest")
    v = np.maximum(uniform_filter(g * g, window, mode="nearest") - m * m, 0.0)
    return m.astype(np.float32), np.sqrt(v).astype(np.float32)


def _normals_from_depth(depth: np.ndarray, K: np.ndarray, radius: int = 2) -> np.ndarray:
    """(h, w, 3) camera-frame unit normals facing the camera from a depth map: cross product of central differences
    (``radius`` pixels apart) of the back-projected points; fronto-parallel (0, 0, -1) where undefined."""
    h, w = depth.shape
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(K).T
    X = rays * np.asarray(depth, np.float64)[..., None]
    r = radius
    dx = np.full_like(X, np.nan)
    dy = np.full_like(X, np.nan)
    dx[:, r:-r] = X[:, 2 * r:] - X[:, : -2 * r]
    dy[r:-r] = X[2 * r:] - X[: -2 * r]
    nrm = np.cross(dx, dy)
    ln = np.linalg.norm(nrm, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        nrm = nrm / ln
    ok = np.all(np.isfinite(nrm), axis=-1)
    nrm[~ok] = (0.0, 0.0, -1.0)
    flip = np.einsum("hwc,hwc->hw", nrm, rays) > 0
    nrm[flip] *= -1
    return nrm.astype(np.float32)


def _normalised(gray: np.ndarray, window: int, min_std: float) -> np.ndarray:
    """(gray - local mean) / local std over a ``window``^2 box, float32; 0 where the std is below ``min_std``."""
    m, s = _box_stats(gray, window)
    out = np.where(s >= min_std, (gray - m) / np.maximum(s, min_std), 0.0)
    return out.astype(np.float32)


def _bilinear(dr, jl, image, w: int, h: int, u, v):
    """Bilinear value of a row-major (h, w) Dr.Jit image at pixel coordinates (u, v) (pixel centres at integers,
    border clamped, as OpenCV's remap with BORDER_REPLICATE) and the mask of (u, v) inside [-0.5, w - 0.5] x
    [-0.5, h - 0.5]. Four gathers and three lerps: about half the operations of ``Texture2f.eval``, which also
    handles wrap modes and channels we do not need."""
    inside = (u >= -0.5) & (u <= w - 0.5) & (v >= -0.5) & (v <= h - 0.5)
    ok = dr.isfinite(u) & dr.isfinite(v)  # a ray parallel to the plane gives inf/NaN: read pixel 0, never out of bounds
    uc = dr.select(ok, dr.clip(u, 0.0, float(w - 1)), 0.0)
    vc = dr.select(ok, dr.clip(v, 0.0, float(h - 1)), 0.0)
    x0 = dr.clip(jl.Int32(uc), 0, w - 2)
    y0 = dr.clip(jl.Int32(vc), 0, h - 2)
    fx = uc - jl.Float(x0)
    fy = vc - jl.Float(y0)
    i00 = jl.UInt32(x0 + y0 * w)
    a = dr.gather(jl.Float, image, i00)
    b = dr.gather(jl.Float, image, i00 + 1)
    c = dr.gather(jl.Float, image, i00 + w)
    d = dr.gather(jl.Float, image, i00 + w + 1)
    top = dr.fma(fx, b - a, a)
    bot = dr.fma(fx, d - c, c)
    return dr.fma(fy, bot - top, top), inside


class _Mat:
    """A matrix indexable as m[i, j] that yields opaque Dr.Jit scalars (kernel inputs, not literals: the compiled
    kernels are reused across views)."""

    def __init__(self, m: np.ndarray, opaque) -> None:
        self.v = [[opaque(x) for x in row] for row in np.atleast_2d(np.asarray(m, float))]

    def __getitem__(self, ij: tuple[int, int]) -> float:
        return self.v[ij[0]][ij[1]]


class _Engine:
    """Dr.Jit state shared by the sweep and PatchMatch for one reference view."""

    def __init__(self, ref_gray, src_grays, ref_cam: Camera, src_cams: list[Camera], params: DepthParams):
        dr, jl = _drjit()
        self.dr, self.jl, self.p = dr, jl, params
        self.h, self.w = ref_gray.shape
        self.n = self.h * self.w
        self.ref_np = ref_gray
        self.ref = jl.Float(ref_gray.ravel())
        self.src_flat = [jl.Float(g.astype(np.float32).ravel()) for g in src_grays]
        self.src_size = [(g.shape[1], g.shape[0]) for g in src_grays]
        self.src_np = src_grays
        self.ref_cam, self.src_cams = ref_cam, src_cams
        self.kinv = np.linalg.inv(ref_cam.K)
        self.rel = [_relative(ref_cam, c) for c in src_cams]
        # plain Python floats: numpy scalars times Dr.Jit arrays would turn into numpy arrays
        self.kinv_l = _Mat(self.kinv, self._opaque)
        self.rel_l = [(_Mat(r, self._opaque), _Mat(t, self._opaque).v[0]) for r, t in self.rel]
        self.src_k_l = [_Mat(c.K, self._opaque) for c in src_cams]

    # ------------------------------------------------------------------------------------------ helpers
    def _opaque(self, value):
        return self.dr.opaque(self.jl.Float, float(value))

    def _lookup(self, j, u, v):
        """Bilinear value of source j at pixel coordinates (u, v) (border clamped) and an in-image mask."""
        return _bilinear(self.dr, self.jl, self.src_flat[j], *self.src_size[j], u, v)

    # ------------------------------------------------------------------------------------------ plane sweep
    def sweep(self, depths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Winner-take-all depth (sub-plane refined) and its cost over fronto-parallel planes.

        The cost is ZNCC computed on locally normalised images: each image is normalised once by its own
        ``sweep_window``^2 mean and standard deviation, and the per-plane cost is ``1 - box_mean(R_hat * S_hat_warped)``
        (one box filter per source and plane instead of three; exact ZNCC when the warped window's statistics equal
        the source window's, i.e. for near fronto-parallel warps, which is what the sweep tests).
        """
        dr, jl, p = self.dr, self.jl, self.p
        w, h, n = self.w, self.h, self.n
        rad = p.sweep_window // 2
        area = float(p.sweep_window**2)
        idx = dr.arange(jl.UInt32, n)
        xi, yi = jl.Int32(idx % w), jl.Int32(idx // w)
        x, y = jl.Float(xi), jl.Float(yi)
        ref_hat = jl.Float(_normalised(self.ref_np, p.sweep_window, p.min_texture).ravel())
        src_hat = [jl.Float(_normalised(g, p.sweep_window, p.min_texture).ravel()) for g in self.src_np]
        inv = 1.0 / depths
        ns = len(self.src_cams)
        # homography of plane z = d: H = K_j (R_rel + t_rel e3^T / d) K_i^-1 = A_j + (1/d) B_j
        mats = []
        for j, cam in enumerate(self.src_cams):
            r_rel, t_rel = self.rel[j]
            a = cam.K @ r_rel @ self.kinv
            b = cam.K @ np.outer(t_rel, [0.0, 0.0, 1.0]) @ self.kinv
            mats.append((a, b))
        big = jl.Float(np.full(n, 4.0, np.float32))
        best_cost, best_k = jl.Float(big), dr.zeros(jl.Int32, n)
        c_before, c_after, prev = jl.Float(big), jl.Float(big), jl.Float(big)
        dr.eval(best_cost, best_k, c_before, c_after, prev)
        for k in range(len(depths)):
            q = float(inv[k])
            prods = []
            for j in range(ns):
                hm = mats[j][0] + q * mats[j][1]
                hv = [self._opaque(v) for v in hm.ravel()]
                zz = hv[6] * x + hv[7] * y + hv[8]
                u = (hv[0] * x + hv[1] * y + hv[2]) / zz
                v = (hv[3] * x + hv[4] * y + hv[5]) / zz
                val, inside = _bilinear(dr, jl, src_hat[j], *self.src_size[j], u, v)
                inside = inside & (zz > 0)
                # outside the source: product -1 (ZNCC -1, the worst), so the box mean is pulled down
                prods.append(dr.select(inside, val * ref_hat, -1.0))
            dr.eval(prods)
            hs = []
            for j in range(ns):
                acc = None
                for dx in range(-rad, rad + 1):
                    gv = dr.gather(jl.Float, prods[j], jl.UInt32(dr.clip(xi + dx, 0, w - 1) + yi * w))
                    acc = gv if acc is None else acc + gv
                hs.append(acc)
            dr.eval(hs)
            costs = []
            for j in range(ns):
                acc = None
                for dy in range(-rad, rad + 1):
                    gv = dr.gather(jl.Float, hs[j], jl.UInt32(xi + dr.clip(yi + dy, 0, h - 1) * w))
                    acc = gv if acc is None else acc + gv
                costs.append(1.0 - acc * (1.0 / area))
            agg = _top_k_mean(dr, costs, p.top_k)
            kk = dr.opaque(jl.Int32, k)
            better = agg < best_cost
            c_after = dr.select(better, 4.0, dr.select(kk == best_k + 1, agg, c_after))
            c_before = dr.select(better, prev, c_before)
            best_k = dr.select(better, kk, best_k)
            best_cost = dr.select(better, agg, best_cost)
            prev = agg
            dr.eval(best_cost, best_k, c_before, c_after, prev)
        bk = np.asarray(best_k, np.int64)
        bc, cb, ca = (np.asarray(a, np.float64) for a in (best_cost, c_before, c_after))
        denom = cb - 2 * bc + ca
        ok = (cb < 3.5) & (ca < 3.5) & (denom > 1e-9)
        off = np.where(ok, 0.5 * (cb - ca) / np.where(ok, denom, 1.0), 0.0)
        off = np.clip(off, -0.5, 0.5)
        kf = np.clip(bk + off, 0, len(depths) - 1)
        inv_interp = np.interp(kf, np.arange(len(depths)), inv)
        return (1.0 / inv_interp).reshape(h, w), bc.reshape(h, w)

    # ------------------------------------------------------------------------------------------ PatchMatch
    def _plane_cost(self, pidx, d, nx, ny, nz):
        """Bilateral-weighted ZNCC cost of plane (d at the pixel, camera-frame normal n) at pixels ``pidx``."""
        dr, jl, p = self.dr, self.jl, self.p
        w, h = self.w, self.h
        xi, yi = jl.Int32(pidx % w), jl.Int32(pidx // w)
        kinv = self.kinv_l
        # camera-frame ray (z = 1) of the centre pixel; rho = n . X_p
        xf, yf = jl.Float(xi), jl.Float(yi)
        rx = kinv[0, 0] * xf + kinv[0, 1] * yf + kinv[0, 2]
        ry = kinv[1, 1] * yf + kinv[1, 2]
        rho = d * (nx * rx + ny * ry + nz)
        centre = dr.gather(jl.Float, self.ref, pidx)
        ns = len(self.src_cams)
        sw = sr = srr = 0.0
        ss = [0.0] * ns
        sss = [0.0] * ns
        srs = [0.0] * ns
        inside_all = [None] * ns
        sc = 1.0 / (2 * p.bilateral_sigma_color**2)
        sp = 1.0 / (2 * p.bilateral_sigma_space**2)
        r, step = p.pm_radius, p.pm_step
        offsets = [(ox, oy) for oy in range(-r, r + 1) for ox in range(-r, r + 1)
                   if not p.pm_checker or (ox + oy) % 2 == 0]
        for ox, oy in offsets:
            qx = dr.clip(xi + ox * step, 0, w - 1)
            qy = dr.clip(yi + oy * step, 0, h - 1)
            rv = dr.gather(jl.Float, self.ref, jl.UInt32(qx + qy * w))
            diff = rv - centre
            wt = dr.exp(-(diff * diff) * sc - float((ox * step) ** 2 + (oy * step) ** 2) * sp)
            qxf, qyf = jl.Float(qx), jl.Float(qy)
            qrx = kinv[0, 0] * qxf + kinv[0, 1] * qyf + kinv[0, 2]
            qry = kinv[1, 1] * qyf + kinv[1, 2]
            dq = rho / (nx * qrx + ny * qry + nz)
            X = (qrx * dq, qry * dq, dq)
            sw = sw + wt
            sr = sr + wt * rv
            srr = srr + wt * rv * rv
            for j in range(ns):
                rm, tv = self.rel_l[j]
                km = self.src_k_l[j]
                cx = rm[0, 0] * X[0] + rm[0, 1] * X[1] + rm[0, 2] * X[2] + tv[0]
                cy = rm[1, 0] * X[0] + rm[1, 1] * X[1] + rm[1, 2] * X[2] + tv[1]
                cz = rm[2, 0] * X[0] + rm[2, 1] * X[1] + rm[2, 2] * X[2] + tv[2]
                u = (km[0, 0] * cx + km[0, 1] * cy) / cz + km[0, 2]
                v = km[1, 1] * cy / cz + km[1, 2]
                if ox == 0 and oy == 0:
                    val, inside = self._lookup(j, u, v)
                    inside_all[j] = inside & (cz > 0) & (dq > 0)
                else:
                    val, _ = self._lookup(j, u, v)
                ss[j] = ss[j] + wt * val
                sss[j] = sss[j] + wt * val * val
                srs[j] = srs[j] + wt * val * rv
        mr = sr / sw
        vr = dr.maximum(srr / sw - mr * mr, 0.0)
        costs = []
        for j in range(ns):
            ms = ss[j] / sw
            vs = dr.maximum(sss[j] / sw - ms * ms, 0.0)
            cov = srs[j] / sw - mr * ms
            zncc = cov / dr.sqrt(vr * vs + 1e-8)
            costs.append(dr.select(inside_all[j], 1.0 - zncc, 2.0))
        return _top_k_mean(dr, costs, p.top_k)

    def patchmatch(self, depth0: np.ndarray, normal0: np.ndarray, near: float, far: float, rng: np.random.Generator,
                   active: np.ndarray | None = None):
        """Red-black PatchMatch over the pixels of ``active`` ((h, w) bool, all when None); the others keep their
        initial plane and get cost 2 (they take no part: neither updated nor, having cost 2, a useful neighbour)."""
        dr, jl, p = self.dr, self.jl, self.p
        near_o, far_o = self._opaque(near), self._opaque(far)
        w, h, n = self.w, self.h, self.n
        d = jl.Float(depth0.ravel().astype(np.float32))
        n0 = normal0.reshape(-1, 3).astype(np.float32)
        nx, ny, nz = jl.Float(n0[:, 0]), jl.Float(n0[:, 1]), jl.Float(n0[:, 2])
        act = np.ones(n, bool) if active is None else np.asarray(active, bool).ravel()
        act_idx = jl.UInt32(np.flatnonzero(act).astype(np.uint32))
        cost = dr.full(jl.Float, 2.0, n)
        dr.scatter(cost, self._plane_cost(act_idx, dr.gather(jl.Float, d, act_idx), dr.gather(jl.Float, nx, act_idx),
                                          dr.gather(jl.Float, ny, act_idx), dr.gather(jl.Float, nz, act_idx)),
                   act_idx)
        dr.eval(cost)
        yy, xx = np.divmod(np.arange(n), w)
        colours = [jl.UInt32(np.flatnonzero(act & ((xx + yy) % 2 == c)).astype(np.uint32)) for c in (0, 1)]
        inv_span = 1.0 / near - 1.0 / far
        kinv = self.kinv_l
        for it in range(p.pm_iterations):
            scale = 0.5**it
            for c in (0, 1):
                pidx = colours[c]
                m = dr.width(pidx)
                xi, yi = jl.Int32(pidx % w), jl.Int32(pidx // w)
                xf, yf = jl.Float(xi), jl.Float(yi)
                rx = kinv[0, 0] * xf + kinv[0, 1] * yf + kinv[0, 2]
                ry = kinv[1, 1] * yf + kinv[1, 2]
                rn = dr.sqrt(rx * rx + ry * ry + 1.0)
                cd, cnx, cny, cnz, cc = (dr.gather(jl.Float, a, pidx) for a in (d, nx, ny, nz, cost))
                dr.eval(cd, cnx, cny, cnz, cc, rx, ry, rn)
                cands = []
                for ox, oy in ((-1, 0), (1, 0), (0, -1), (0, 1)):
                    qx = dr.clip(xi + ox, 0, w - 1)
                    qy = dr.clip(yi + oy, 0, h - 1)
                    qi = jl.UInt32(qx + qy * w)
                    qd, qnx, qny, qnz = (dr.gather(jl.Float, a, qi) for a in (d, nx, ny, nz))
                    qxf, qyf = jl.Float(qx), jl.Float(qy)
                    qrx = kinv[0, 0] * qxf + kinv[0, 1] * qyf + kinv[0, 2]
                    qry = kinv[1, 1] * qyf + kinv[1, 2]
                    rho = qd * (qnx * qrx + qny * qry + qnz)
                    dd = rho / (qnx * rx + qny * ry + qnz)
                    cands.append((dd, qnx, qny, qnz))
                # random perturbations: inverse depth within +-scale * 2 % of the range, normal within +-scale * 0.6
                rnd = [jl.Float(r) for r in rng.uniform(-1.0, 1.0, (5, m)).astype(np.float32)]
                sc = self._opaque(scale)
                dq = rnd[0] * self._opaque(0.02 * scale * inv_span)
                pd = 1.0 / dr.maximum(1.0 / cd + dq, 1e-6)
                cands.append((pd, cnx + rnd[1] * (0.6 * sc), cny + rnd[2] * (0.6 * sc), cnz + rnd[3] * (0.6 * sc)))
                cands.append((cd, cnx + rnd[4] * (0.3 * sc), cny - rnd[1] * (0.3 * sc), cnz))
                # a fresh random normal (uniform on the sphere, flipped to face the camera) at the current depth
                gz = rng.normal(size=(3, m)).astype(np.float32)
                cands.append((cd, jl.Float(gz[0]), jl.Float(gz[1]), jl.Float(gz[2])))
                for dd, ex, ey, ez in cands:
                    norm = dr.sqrt(ex * ex + ey * ey + ez * ez)
                    ex, ey, ez = ex / norm, ey / norm, ez / norm
                    facing = ex * rx + ey * ry + ez
                    # the normal must face the camera; flip it if not
                    sgn = dr.select(facing > 0, -1.0, 1.0)
                    ex, ey, ez = ex * sgn, ey * sgn, ez * sgn
                    ok = (dd > near_o) & (dd < far_o) & dr.isfinite(dd) & (dr.abs(facing) > 0.1 * rn)
                    dd = dr.select(ok, dd, cd)
                    dr.eval(dd, ex, ey, ez, ok)
                    ccost = self._plane_cost(pidx, dd, ex, ey, ez)
                    dr.eval(ccost)
                    better = ok & (ccost < cc)
                    cd, cnx, cny, cnz = (dr.select(better, a, b) for a, b in ((dd, cd), (ex, cnx), (ey, cny), (ez, cnz)))
                    cc = dr.select(better, ccost, cc)
                    dr.eval(cd, cnx, cny, cnz, cc)
                for arr, val in ((d, cd), (nx, cnx), (ny, cny), (nz, cnz), (cost, cc)):
                    dr.scatter(arr, val, pidx)
                dr.eval(d, nx, ny, nz, cost)
        out = [np.asarray(a, np.float32).reshape(h, w) for a in (d, nx, ny, nz, cost)]
        return out[0], np.stack(out[1:4], axis=-1), out[4]


def estimate_depth(
    ref_image: np.ndarray,
    src_images: list[np.ndarray],
    ref_cam: Camera,
    src_cams: list[Camera],
    depth_range: tuple[float, float],
    params: DepthParams | None = None,
    *,
    rng: np.random.Generator,
    refine: bool = True,
) -> DepthMap:
    """Depth and normal map of one reference view from its source views.

    Parameters
    ----------
    ref_image : (h, w, 3) uint8 or (h, w) float, the reference image
    src_images : list of (h', w', 3) uint8 or (h', w') float, the source (neighbour) images
    ref_cam, src_cams : the cameras of the reference and of each source
    depth_range : (near, far) z-depth bounds of the reference view, metres
    params : DepthParams
    rng : numpy Generator for the PatchMatch perturbations
    refine : run PatchMatch after the sweep (False returns the sweep's fronto-parallel result)

    Returns
    -------
    DepthMap (depth NaN where the final cost is above ``max_cost`` or the window is textureless)
    """
    p = params or DepthParams()
    if not src_images:
        raise InputError("estimate_depth needs at least one source view")
    if len(src_images) != len(src_cams):
        raise InputError("estimate_depth: one camera per source image")
    if p.sweep_window % 2 != 1 or p.sweep_window < 3:
        raise InputError(f"sweep_window must be odd and >= 3, got {p.sweep_window}")
    ref = to_gray(ref_image)
    if ref.shape != (ref_cam.height, ref_cam.width):
        raise InputError(f"reference image is {ref.shape[::-1]}, its camera says {(ref_cam.width, ref_cam.height)}")
    srcs = [to_gray(s) for s in src_images]
    near, far = float(depth_range[0]), float(depth_range[1])
    depths = sweep_depths(near, far, p.hypotheses)
    eng = _Engine(ref, srcs, ref_cam, src_cams, p)
    _, std = _box_stats(ref, p.sweep_window)
    textured = std >= p.min_texture
    depth, cost = eng.sweep(depths)
    normal_cam = np.zeros(depth.shape + (3,), np.float32)
    normal_cam[..., 2] = -1.0
    if refine and p.pm_iterations > 0:
        init = _normals_from_depth(np.where(cost < 1.0, depth, np.nan), ref_cam.K)
        depth, normal_cam, cost = eng.patchmatch(depth.astype(np.float32), init, near, far, rng,
                                                 active=textured if p.pm_textured_only else None)
    keep = (cost < p.max_cost) & textured & np.isfinite(depth) & (depth > near) & (depth < far)
    depth = np.where(keep, depth, np.nan).astype(np.float32)
    normal = (normal_cam.reshape(-1, 3) @ ref_cam.R).reshape(normal_cam.shape)  # camera -> world: R^T n
    normal = np.where(keep[..., None], normal, np.nan).astype(np.float32)
    return DepthMap(depth, normal, np.where(np.isfinite(cost), cost, 2.0).astype(np.float32))
