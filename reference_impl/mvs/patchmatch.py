"""Per-view depth and normal maps on the CPU: a ZNCC plane sweep, then slanted-plane PatchMatch, in Dr.Jit LLVM.

Guo et al. 2018, section 4 (depth initialisation, Eq. 1-2): each reference pixel gets a plane (depth d, normal n) whose
homography ``H = K_j (R_rel + t_rel n^T / rho) K_i^-1`` maps its support window into every source view, scored
by photo-consistency. We do it in two stages:

1. **Plane sweep** (initialisation): ``hypotheses`` fronto-parallel planes uniform in inverse depth over the view's
   depth range. Per plane and source, the source image is warped by the plane's homography (bilinear texture
   lookups), the ZNCC over a ``sweep_window``^2 box is computed with separable box sums, the per-source costs
   ``1 - ZNCC`` are aggregated as the mean of the ``top_k`` best (occlusion-robust), and the winner takes all,
   refined by a parabola through the neighbouring planes' costs.
2. **PatchMatch refinement** with slanted planes (Bleyer et al. 2011, Galliani et al. 2015 red-black scheme):
   every pixel tries its four neighbours' planes (propagation), two random perturbations of its own plane and a
   random normal (a random depth at the fine level of coarse to fine); normals start from the sweep's depth-map
   gradient;
   the cost is a bilateral-weighted ZNCC over a (2r+1)^2 window whose samples are mapped through the pixel's own
   plane by its homography (computed once per pixel and source; the window's weights once per pixel set).
3. **Coarse to fine** (the default for views of >= 512 px, ``coarse_scale``, ``coarse_min_size``): the sweep and
   the first ``coarse_iterations`` of PatchMatch run on the images downsampled by ``coarse_scale``; each
   full-resolution pixel then starts from the plane of the coarse pixel it lies in and PatchMatch refines at full
   resolution, where the fresh random candidate is a random depth instead of a random normal (surfaces smaller
   than a coarse pixel are in no coarse plane). Both levels evaluate the checkerboard half of the window (Gipuma).
   Measured in ``docs/tuning/mvs.md``.
4. **Options of ACMM** (Xu and Tao 2019), off by default: the adaptive checkerboard propagation (``propagation``:
   each pixel takes the lowest-cost plane of each of 8 regions reaching 23 pixels, :func:`propagation_regions`, so
   planes cross weakly textured surfaces) and the geometric-consistency pass (:func:`refine_geometric`: once every
   view has its depth, more iterations whose cost adds the reprojection error through the sources' depth maps).

The graph-cut global optimisation of the seed (Eq. 4) is replaced by this local PatchMatch plus the multi-view
consistency filter of :mod:`.filtering` (see the module notes there). All pixels are processed at once as Dr.Jit
arrays (kernels compiled once and cached; the per-plane/per-iteration values are opaque so they are reused).
The images are read through :class:`_Packed` (one 64-bit gather per bilinear lookup): gathers dominate the cost
kernels on the CPU.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from plantbench.cameras import Camera
from plantbench.errors import InputError

from .params import DepthParams

__all__ = ["DepthMap", "estimate_depth", "to_gray", "sweep_depths", "propagation_regions", "refine_geometric"]


@dataclass(frozen=True)
class DepthMap:
    """One view's estimate.

    depth : (h, w) float32, z-depth in the view's camera frame; NaN where no depth was kept
    normal : (h, w, 3) float32, unit normal in world coordinates (facing the camera); NaN where no depth
    cost : (h, w) float32, final matching cost (1 - ZNCC, mean of the best sources), 2 where unmatched
    planes : the raw planes of every pixel, kept or not: (h, w) float32 depth and (h, w, 3) float32 camera-frame
        normal (what the geometric-consistency pass starts from and checks against); None for the sweep alone
    background : (h, w) bool, pixels that matched well beyond the scene (:attr:`DepthParams.background_span`): the
        view sees past the scene there, which the free-space test counts against any point in front; None when the
        search stops at the scene
    """

    depth: np.ndarray
    normal: np.ndarray
    cost: np.ndarray
    planes: tuple[np.ndarray, np.ndarray] | None = None
    background: np.ndarray | None = None


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
    from plantbench.backend import load_drjit

    return load_drjit()


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


@dataclass(frozen=True)
class _Packed:
    """An (h, w) image stored for one-gather bilinear lookups: word ``x + y w`` holds the 2 x 2 block of pixels
    (x, y), (x + 1, y), (x, y + 1), (x + 1, y + 1) as four 16-bit fields of one 64-bit integer.

    A bilinear lookup then costs one 64-bit gather instead of four 32-bit ones. On this project's CPUs (AVX2, AMD,
    where LLVM lowers a gather to one scalar load per lane) a PatchMatch cost kernel went from 70 to 36 ms per
    131k pixels. Each field holds a 15-bit level ``q`` (below 2^15, so the conversions to float can be the one-
    instruction signed ones); the value is ``offset + scale q``, which resolves 1/32767 of the image's range (an
    8-bit image loses nothing)."""

    words: object  # drjit.llvm.UInt64, h * w (the last row and column are padding)
    width: int
    height: int
    offset: float
    scale: float

    @staticmethod
    def pack(jl, image: np.ndarray) -> _Packed:
        img = np.asarray(image, np.float64)
        lo, hi = float(img.min()), float(img.max())
        scale = (hi - lo) / 32767.0 if hi > lo else 1.0
        q = np.rint((img - lo) / scale).astype(np.uint64)
        h, w = q.shape
        words = np.zeros((h, w), np.uint64)
        words[:-1, :-1] = q[:-1, :-1] | (q[:-1, 1:] << 16) | (q[1:, :-1] << 32) | (q[1:, 1:] << 48)
        return _Packed(jl.UInt64(words.ravel()), w, h, lo, scale)


def _bilinear_packed(dr, jl, img: _Packed, u, v):
    """Bilinear value at pixel coordinates (u, v) (border clamped) of a :class:`_Packed` image, in its 15-bit levels
    (``img.offset + img.scale * result`` is the image value). No in-image mask and no finiteness guard: the integer
    corner is clamped after the conversion, so a NaN or infinite coordinate still reads inside the image (the value
    is then NaN and the caller rejects it)."""
    w, h = img.width, img.height
    uc = dr.clip(u, 0.0, float(w - 1))
    vc = dr.clip(v, 0.0, float(h - 1))
    x0 = dr.clip(jl.Int32(uc), 0, w - 2)
    y0 = dr.clip(jl.Int32(vc), 0, h - 2)
    fx = uc - jl.Float(x0)
    fy = vc - jl.Float(y0)
    word = dr.gather(jl.UInt64, img.words, jl.UInt32(x0 + y0 * w))
    # signed conversions (one instruction each on AVX2, the unsigned ones take several): levels are < 2^15
    top, bottom = jl.Int32(word & 0xFFFFFFFF), jl.Int32(word >> 32)
    a, b = jl.Float(top & 0xFFFF), jl.Float(top >> 16)
    c, d = jl.Float(bottom & 0xFFFF), jl.Float(bottom >> 16)
    t = dr.fma(fx, b - a, a)
    bt = dr.fma(fx, d - c, c)
    return dr.fma(fy, bt - t, t)


class _Mat:
    """A matrix indexable as m[i, j] that yields opaque Dr.Jit scalars (kernel inputs, not literals: the compiled
    kernels are reused across views)."""

    def __init__(self, m: np.ndarray, opaque) -> None:
        self.v = [[opaque(x) for x in row] for row in np.atleast_2d(np.asarray(m, float))]

    def __getitem__(self, ij: tuple[int, int]) -> float:
        return self.v[ij[0]][ij[1]]


class _Engine:
    """Dr.Jit state shared by the sweep and PatchMatch for one reference view."""

    def __init__(self, ref_gray, src_grays, ref_cam: Camera, src_cams: list[Camera], params: DepthParams,
                 checker: bool = False):
        dr, jl = _drjit()
        self.dr, self.jl, self.p = dr, jl, params
        self.checker = params.pm_checker or checker  # PatchMatch window: checkerboard samples only
        self.h, self.w = ref_gray.shape
        self.n = self.h * self.w
        self.ref_np = ref_gray
        self.ref = jl.Float(ref_gray.ravel())
        self.src_packed = [_Packed.pack(jl, g) for g in src_grays]
        self.src_scale = [self._opaque(s.scale) for s in self.src_packed]
        self.src_size = [(g.shape[1], g.shape[0]) for g in src_grays]
        self.src_np = src_grays
        self.ref_cam, self.src_cams = ref_cam, src_cams
        self.kinv = np.linalg.inv(ref_cam.K)
        self.rel = [_relative(ref_cam, c) for c in src_cams]
        # plain Python floats: numpy scalars times Dr.Jit arrays would turn into numpy arrays
        self.kinv_l = _Mat(self.kinv, self._opaque)
        # plane-induced homographies H_j = A_j + b_j c^T: A_j = K_j R_j K^-1, b_j = K_j t_j (see _plane_cost)
        self.hom_l = [(_Mat(c.K @ r @ self.kinv, self._opaque).v, _Mat(c.K @ t, self._opaque).v[0])
                      for c, (r, t) in zip(src_cams, self.rel)]
        self.geo = None  # set_geometry: the sources' depth maps for the geometric-consistency term

    def set_geometry(self, src_depths: list[np.ndarray] | None) -> None:
        """Add (or with None remove) the geometric-consistency term of :meth:`_plane_cost`: each source's (h', w')
        z-depth map (non-finite: no depth, the error's maximum) and the terms of the backward projection: a source
        pixel (u, v) with depth D maps to the reference pixel of ``D M_j (u, v, 1) - m_j`` with
        ``M_j = K R_j^T K_j^-1`` and ``m_j = K R_j^T t_j`` (R_j, t_j: reference to source)."""
        if src_depths is None:
            self.geo = None
            return
        jl = self.jl
        K = self.ref_cam.K
        self.geo = []
        for dep, cam, (r, t) in zip(src_depths, self.src_cams, self.rel, strict=True):
            d = np.where(np.isfinite(dep) & (dep > 0), dep, 0.0).astype(np.float32)
            m_mat = K @ r.T @ np.linalg.inv(cam.K)
            self.geo.append((jl.Float(d.ravel()), _Mat(m_mat, self._opaque).v, _Mat(K @ r.T @ t, self._opaque).v[0]))

    # ------------------------------------------------------------------------------------------ helpers
    def _opaque(self, value):
        return self.dr.opaque(self.jl.Float, float(value))

    # ------------------------------------------------------------------------------------------ plane sweep
    def _sweep_setup(self) -> None:
        """The sweep's normalised images (reference as floats, sources packed) and the per-source homography terms
        of the planes z = d: ``H = K_j (R_rel + t_rel e3^T / d) K_i^-1 = A_j + (1/d) B_j``."""
        if hasattr(self, "_ref_hat"):
            return
        p, jl = self.p, self.jl
        self._ref_hat = jl.Float(_normalised(self.ref_np, p.sweep_window, p.min_texture).ravel())
        self._src_hat = [_Packed.pack(jl, _normalised(g, p.sweep_window, p.min_texture)) for g in self.src_np]
        self._hat_scale = [self._opaque(s.scale) for s in self._src_hat]  # opaque: one compiled kernel for every view
        self._hat_offset = [self._opaque(s.offset) for s in self._src_hat]
        self._sweep_mats = []
        for j, cam in enumerate(self.src_cams):
            r_rel, t_rel = self.rel[j]
            self._sweep_mats.append((cam.K @ r_rel @ self.kinv,
                                     cam.K @ np.outer(t_rel, [0.0, 0.0, 1.0]) @ self.kinv))
        idx = self.dr.arange(jl.UInt32, self.n)
        self._xi, self._yi = jl.Int32(idx % self.w), jl.Int32(idx // self.w)
        self._x, self._y = jl.Float(self._xi), jl.Float(self._yi)
        self.dr.eval(self._xi, self._yi, self._x, self._y)

    # products of normalised values are clamped to +-_PROD_RANGE before quantisation (|z| <= sqrt(area - 1) bounds
    # them by 24 for a 5 x 5 window, but both factors beyond 2.8 sigma are rare)
    _PROD_RANGE = 8.0

    def sweep_costs(self, inv_depth: float) -> list:
        """Per-source costs ``1 - box_mean(R_hat * S_hat_warped)`` of the plane z = 1 / ``inv_depth`` (Dr.Jit arrays).

        The box sums run on packed words: each pixel's products with (up to) four sources are quantised to
        ``L = floor(65535 / area)`` levels and stored as four 16-bit fields of one 64-bit word, so that one 64-bit
        add sums four sources and the window's sum cannot overflow a field. A box pass then costs 2 r + 1 gathers
        per pixel for four sources instead of 4 (2 r + 1) (gathers dominate on the CPU). The quantisation step,
        2 x 8 / L = 0.006 for a 5 x 5 window, is averaged over the window: about 0.0004 on a source's ZNCC.
        """
        self._sweep_setup()
        dr, jl, p = self.dr, self.jl, self.p
        w, h = self.w, self.h
        xi, yi, x, y = self._xi, self._yi, self._x, self._y
        rad = p.sweep_window // 2
        area = p.sweep_window**2
        levels = 65535 // area
        rng_ = self._PROD_RANGE
        qscale = (levels - 1) / (2 * rng_)
        ns = len(self.src_cams)
        groups = [list(range(g, min(g + 4, ns))) for g in range(0, ns, 4)]
        words = []
        for group in groups:
            word = None
            for f, j in enumerate(group):
                hm = self._sweep_mats[j][0] + inv_depth * self._sweep_mats[j][1]
                hv = [self._opaque(v) for v in hm.ravel()]
                zz = hv[6] * x + hv[7] * y + hv[8]
                u = (hv[0] * x + hv[1] * y + hv[2]) / zz
                v = (hv[3] * x + hv[4] * y + hv[5]) / zz
                sw_, sh_ = self.src_size[j]
                inside = (zz > 0) & (u >= -0.5) & (u <= sw_ - 0.5) & (v >= -0.5) & (v <= sh_ - 0.5)
                val = dr.fma(_bilinear_packed(dr, jl, self._src_hat[j], u, v), self._hat_scale[j],
                             self._hat_offset[j])
                # outside the source: product -1 (ZNCC -1, the worst), so the box mean is pulled down
                prod = dr.clip(dr.select(inside, val * self._ref_hat, -1.0), -rng_, rng_)
                q = jl.UInt64(jl.Int32((prod + rng_) * qscale + 0.5))
                word = q if word is None else word | (q << (16 * f))
            words.append(word)
        dr.eval(words)
        hsum = []
        for word in words:
            acc = None
            for dx in range(-rad, rad + 1):
                g = dr.gather(jl.UInt64, word, jl.UInt32(dr.clip(xi + dx, 0, w - 1) + yi * w))
                acc = g if acc is None else acc + g
            hsum.append(acc)
        dr.eval(hsum)
        costs = []
        for word, group in zip(hsum, groups):
            acc = None
            for dy in range(-rad, rad + 1):
                g = dr.gather(jl.UInt64, word, jl.UInt32(xi + dr.clip(yi + dy, 0, h - 1) * w))
                acc = g if acc is None else acc + g
            for f, _ in enumerate(group):
                total = jl.Float(jl.Int32((acc >> (16 * f)) & 0xFFFF))
                mean = total * (1.0 / (qscale * area)) - rng_
                costs.append(1.0 - mean)
        return costs

    def initial_planes(self, depths: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """PatchMatch's start: the sweep's depth and cost, and camera-frame normals from the depth's gradient."""
        depth, cost = self.sweep(depths)
        return depth, cost, _normals_from_depth(np.where(cost < 1.0, depth, np.nan), self.ref_cam.K)

    def sweep(self, depths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Winner-take-all depth (sub-plane refined) and its cost over fronto-parallel planes.

        The cost is ZNCC computed on locally normalised images: each image is normalised once by its own
        ``sweep_window``^2 mean and standard deviation, and the per-plane cost is ``1 - box_mean(R_hat * S_hat_warped)``
        (one box filter per source and plane instead of three; exact ZNCC when the warped window's statistics equal
        the source window's, i.e. for near fronto-parallel warps, which is what the sweep tests); see
        :meth:`sweep_costs`.
        """
        dr, jl, p = self.dr, self.jl, self.p
        w, h, n = self.w, self.h, self.n
        inv = 1.0 / depths
        big = jl.Float(np.full(n, 4.0, np.float32))
        best_cost, best_k = jl.Float(big), dr.zeros(jl.Int32, n)
        c_before, c_after, prev = jl.Float(big), jl.Float(big), jl.Float(big)
        dr.eval(best_cost, best_k, c_before, c_after, prev)
        for k in range(len(depths)):
            agg = _top_k_mean(dr, self.sweep_costs(float(inv[k])), p.top_k)
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
    def _window(self, pidx):
        """What the plane cost needs of the reference window at pixels ``pidx`` (independent of the plane, so
        computed once per pixel set and reused by every candidate): the pixel coordinates, the normalised bilateral
        weights ``wn_k`` of the window samples, ``a_k = wn_k (r_k - mean_w(r))`` and the weighted variance of the
        reference window."""
        dr, jl, p = self.dr, self.jl, self.p
        w, h = self.w, self.h
        xi, yi = jl.Int32(pidx % w), jl.Int32(pidx // w)
        centre = dr.gather(jl.Float, self.ref, pidx)
        sc = 1.0 / (2 * p.bilateral_sigma_color**2)
        sp = 1.0 / (2 * p.bilateral_sigma_space**2)
        wts, refs = [], []
        for ox, oy in self._offsets():
            qx = dr.clip(xi + ox, 0, w - 1)
            qy = dr.clip(yi + oy, 0, h - 1)
            rv = dr.gather(jl.Float, self.ref, jl.UInt32(qx + qy * w))
            diff = rv - centre
            wts.append(dr.exp(-(diff * diff) * sc - float(ox * ox + oy * oy) * sp))
            refs.append(rv)
        sw = sum(wts[1:], wts[0])
        inv = 1.0 / sw
        wn = [wt * inv for wt in wts]
        mr = sum((a * b for a, b in zip(wn[1:], refs[1:])), wn[0] * refs[0])
        vr = dr.maximum(sum((a * b * b for a, b in zip(wn[1:], refs[1:])), wn[0] * refs[0] * refs[0]) - mr * mr, 0.0)
        an = [a * (b - mr) for a, b in zip(wn, refs)]
        x, y = jl.Float(xi), jl.Float(yi)
        dr.eval(x, y, wn, an, vr)
        return {"x": x, "y": y, "wn": wn, "an": an, "vr": vr}

    def _offsets(self) -> list[tuple[int, int]]:
        """Pixel offsets of the PatchMatch window samples (``pm_radius``, ``pm_step``; a checkerboard of them with
        ``pm_checker`` or in coarse to fine)."""
        r, step = self.p.pm_radius, self.p.pm_step
        return [(ox * step, oy * step) for oy in range(-r, r + 1) for ox in range(-r, r + 1)
                if not self.checker or (ox + oy) % 2 == 0]

    def _plane_cost(self, win, d, nx, ny, nz):
        """Bilateral-weighted ZNCC cost of plane (depth ``d`` at the pixel, camera-frame normal n) at the pixels of
        ``win`` (:meth:`_window`).

        The plane ``n . X = rho`` (``rho = d n . K^-1 p``) induces in source j the homography
        ``H_j = K_j (R_j + t_j n^T / rho) K^-1 = A_j + b_j c^T`` with ``A_j = K_j R_j K^-1``, ``b_j = K_j t_j`` and
        ``c = K^-T n / rho``; a window sample ``q = p + (ox, oy)`` maps to ``H_j q = H_j p + ox H_j e_1 + oy H_j e_2``,
        six multiply-adds per sample and source once ``H_j p`` and its two columns are known per pixel. (Within
        ``pm_radius`` of the image border the reference sample is the clamped pixel while the source sample follows
        the plane beyond it.)
        """
        dr, jl, p = self.dr, self.jl, self.p
        x, y = win["x"], win["y"]
        kinv = self.kinv_l
        # c = K^-T n / rho with rho = d (n . K^-1 p) = d (c' . p) for c' = K^-T n
        c0 = kinv[0, 0] * nx
        c1 = kinv[0, 1] * nx + kinv[1, 1] * ny
        c2 = kinv[0, 2] * nx + kinv[1, 2] * ny + nz
        rho = d * (c0 * x + c1 * y + c2)
        irho = 1.0 / rho
        c0, c1, c2 = c0 * irho, c1 * irho, c2 * irho
        cp = c0 * x + c1 * y + c2  # = 1 / d
        ns = len(self.src_cams)
        base, col0, col1 = [], [], []
        for j in range(ns):
            a, b = self.hom_l[j]
            base.append([a[i][0] * x + a[i][1] * y + a[i][2] + b[i] * cp for i in range(3)])
            col0.append([a[i][0] + b[i] * c0 for i in range(3)])
            col1.append([a[i][1] + b[i] * c1 for i in range(3)])
        ss = [0.0] * ns
        sss = [0.0] * ns
        srs = [0.0] * ns
        inside_all = [None] * ns
        geo_err = [None] * ns
        # one source at a time: its homography terms and sums
        for j in range(ns):
            for k, (ox, oy) in enumerate(self._offsets()):
                wn, an = win["wn"][k], win["an"][k]
                hx, hy, hz = (dr.fma(col1[j][i], float(oy), dr.fma(col0[j][i], float(ox), base[j][i]))
                              if (ox or oy) else base[j][i] for i in range(3))
                iz = 1.0 / hz
                val = _bilinear_packed(dr, jl, self.src_packed[j], hx * iz, hy * iz)
                if ox == 0 and oy == 0:
                    u, v = hx * iz, hy * iz
                    sw_, sh_ = self.src_size[j]
                    inside_all[j] = (hz > 0) & (u >= -0.5) & (u <= sw_ - 0.5) & (v >= -0.5) & (v <= sh_ - 0.5)
                    if self.geo is not None:
                        geo_err[j] = self._reprojection_error(j, u, v, x, y, inside_all[j])
                t = wn * val
                ss[j] = ss[j] + t
                sss[j] = dr.fma(t, val, sss[j])
                srs[j] = dr.fma(an, val, srs[j])
        vr = win["vr"]
        costs = []
        for j in range(ns):
            # the sums are in the packed image's 15-bit levels: the variance scales by scale^2, the covariance by
            # scale (sum_k an_k = 0, so the level offset drops out)
            sc = self.src_scale[j]
            vs = dr.maximum(sss[j] - ss[j] * ss[j], 0.0) * (sc * sc)
            zncc = srs[j] * sc / dr.sqrt(vr * vs + 1e-8)
            cost = dr.select(inside_all[j] & dr.isfinite(zncc), 1.0 - zncc, 2.0)
            if geo_err[j] is not None:
                cost = dr.fma(geo_err[j], float(p.geometric_weight), cost)
            costs.append(cost)
        return _top_k_mean(dr, costs, p.top_k)

    def _reprojection_error(self, j: int, u, v, x, y, inside):
        """ACMM's forward-backward reprojection error, truncated at ``geometric_max_px``: the pixel (``x``, ``y``)
        with its plane's point seen at (``u``, ``v``) in source j, that source's depth at the nearest pixel taken
        back into the reference view."""
        dr, jl = self.dr, self.jl
        dep, m, off = self.geo[j]
        sw_, sh_ = self.src_size[j]
        ui = dr.clip(jl.Int32(dr.round(u)), 0, sw_ - 1)
        vi = dr.clip(jl.Int32(dr.round(v)), 0, sh_ - 1)
        dd = dr.gather(jl.Float, dep, jl.UInt32(ui + vi * sw_))
        uf, vf = jl.Float(ui), jl.Float(vi)
        q = [dd * (m[i][0] * uf + m[i][1] * vf + m[i][2]) - off[i] for i in range(3)]
        ex, ey = q[0] / q[2] - x, q[1] / q[2] - y
        err = dr.sqrt(ex * ex + ey * ey)
        cap = float(self.p.geometric_max_px)
        return dr.select(inside & (dd > 0) & (q[2] > 0) & dr.isfinite(err), dr.minimum(err, cap), cap)

    def patchmatch(self, depth0: np.ndarray, normal0: np.ndarray, near: float, far: float, rng: np.random.Generator,
                   active: np.ndarray | None = None, iterations: int | None = None, random_depth: bool = False):
        """Red-black PatchMatch over the pixels of ``active`` ((h, w) bool, all when None); the others keep their
        initial plane and get cost 2 (they take no part: neither updated nor, having cost 2, a useful neighbour).
        ``iterations``: how many to run (iteration i perturbs by 0.5^i), ``pm_iterations`` by default.
        ``random_depth``: the fresh random candidate of every pixel and iteration is a depth drawn uniformly in inverse
        depth over the whole range with the pixel's normal (PatchMatch's random initialisation) instead of a random
        normal at its depth: how the fine level of coarse to fine finds surfaces smaller than a coarse pixel, which no
        coarse plane holds."""
        jl, p = self.jl, self.p
        w, h, n = self.w, self.h, self.n
        d = jl.Float(depth0.ravel().astype(np.float32))
        n0 = normal0.reshape(-1, 3).astype(np.float32)
        nx, ny, nz = jl.Float(n0[:, 0]), jl.Float(n0[:, 1]), jl.Float(n0[:, 2])
        act = np.ones(n, bool) if active is None else np.asarray(active, bool).ravel()
        yy, xx = np.divmod(np.arange(n), w)
        colours = [jl.UInt32(np.flatnonzero(act & ((xx + yy) % 2 == c)).astype(np.uint32)) for c in (0, 1)]
        windows = [self._window(pidx) for pidx in colours]
        cost = self._costs(colours, windows, (d, nx, ny, nz))  # the starting planes' costs
        planes = (d, nx, ny, nz, cost)
        for it in range(p.pm_iterations if iterations is None else iterations):
            for pidx, win in zip(colours, windows):
                self._half_sweep(planes, pidx, win, near, far, rng, 0.5**it, random_depth)
        out = [np.asarray(a, np.float32).reshape(h, w) for a in planes]
        return out[0], np.stack(out[1:4], axis=-1), out[4]

    def _costs(self, colours: list, windows: list, planes: tuple):
        """The cost (:meth:`_plane_cost`) of ``planes`` (Dr.Jit depth, normal x, y, z of every pixel) at the pixels
        of ``colours`` (index arrays, with their :meth:`_window` in ``windows``); 2 elsewhere."""
        dr, jl = self.dr, self.jl
        cost = dr.full(jl.Float, 2.0, self.n)
        for pidx, win in zip(colours, windows):
            dr.scatter(cost, self._plane_cost(win, *(dr.gather(jl.Float, a, pidx) for a in planes)), pidx)
        dr.eval(cost)
        return cost

    def photometric_cost(self, depth: np.ndarray, normal: np.ndarray) -> np.ndarray:
        """(h, w) float32 cost of the planes (``depth`` (h, w), camera-frame ``normal`` (h, w, 3)) without the
        geometric term."""
        jl = self.jl
        geo, self.geo = self.geo, None
        try:
            n0 = normal.reshape(-1, 3).astype(np.float32)
            planes = (jl.Float(depth.ravel().astype(np.float32)), *(jl.Float(n0[:, k]) for k in range(3)))
            colours = [jl.UInt32(np.arange(self.n, dtype=np.uint32))]
            cost = self._costs(colours, [self._window(c) for c in colours], planes)
        finally:
            self.geo = geo
        return np.asarray(cost, np.float32).reshape(self.h, self.w)

    def _half_sweep(self, planes: tuple, pidx, win, near: float, far: float, rng: np.random.Generator, scale: float,
                    random_depth: bool) -> None:
        """One colour of a red-black iteration: the pixels ``pidx`` try their neighbours' planes and random ones
        (perturbations by ``scale``) and keep the cheapest; ``planes`` (depth, normal x, y, z, cost) are updated in
        place."""
        dr, jl = self.dr, self.jl
        w = self.w
        kinv = self.kinv_l
        xi, yi = jl.Int32(pidx % w), jl.Int32(pidx // w)
        xf, yf = jl.Float(xi), jl.Float(yi)
        rx = kinv[0, 0] * xf + kinv[0, 1] * yf + kinv[0, 2]
        ry = kinv[1, 1] * yf + kinv[1, 2]
        rn = dr.sqrt(rx * rx + ry * ry + 1.0)
        cur = tuple(dr.gather(jl.Float, a, pidx) for a in planes)
        dr.eval(*cur, rx, ry, rn)
        cands = self._neighbour_planes(planes, xi, yi, rx, ry)
        cands += self._random_planes(cur, dr.width(pidx), near, far, rng, scale, random_depth)
        best = self._cheapest(win, cands, cur, (rx, ry, rn), near, far)
        for arr, val in zip(planes, best, strict=True):
            dr.scatter(arr, val, pidx)
        dr.eval(*planes)

    def _neighbour_planes(self, planes: tuple, xi, yi, rx, ry) -> list[tuple]:
        """Propagation: for each region of :func:`propagation_regions` the plane of its sample of lowest current cost,
        as (depth along the pixel's own ray (``rx``, ``ry``), normal x, y, z), for pixels (``xi``, ``yi``)."""
        dr, jl = self.dr, self.jl
        d, nx, ny, nz, cost = planes
        w, h = self.w, self.h
        kinv = self.kinv_l
        cands = []
        for region in propagation_regions(self.p.propagation):
            qi = best = None
            for ox, oy in region:
                si = jl.UInt32(dr.clip(xi + ox, 0, w - 1) + dr.clip(yi + oy, 0, h - 1) * w)
                if qi is None:
                    qi, best = si, dr.gather(jl.Float, cost, si)
                    continue
                c = dr.gather(jl.Float, cost, si)
                better = c < best
                qi, best = dr.select(better, si, qi), dr.select(better, c, best)
            qd, qnx, qny, qnz = (dr.gather(jl.Float, a, qi) for a in (d, nx, ny, nz))
            qxf, qyf = jl.Float(qi % w), jl.Float(qi // w)
            qrx = kinv[0, 0] * qxf + kinv[0, 1] * qyf + kinv[0, 2]
            qry = kinv[1, 1] * qyf + kinv[1, 2]
            rho = qd * (qnx * qrx + qny * qry + qnz)
            dd = rho / (qnx * rx + qny * ry + qnz)
            cands.append((dd, qnx, qny, qnz))
        return cands

    def _random_planes(self, cur: tuple, m: int, near: float, far: float, rng: np.random.Generator, scale: float,
                       random_depth: bool) -> list[tuple]:
        """Random search around the current planes ``cur`` of ``m`` pixels: two perturbations (inverse depth within
        +-scale * 2 % of the range, normal within +-scale * 0.6) and a fresh random depth or normal."""
        dr, jl = self.dr, self.jl
        cd, cnx, cny, cnz, _ = cur
        inv_span = 1.0 / near - 1.0 / far
        rnd = [jl.Float(r) for r in rng.uniform(-1.0, 1.0, (5, m)).astype(np.float32)]
        sc = self._opaque(scale)
        dq = rnd[0] * self._opaque(0.02 * scale * inv_span)
        pd = 1.0 / dr.maximum(1.0 / cd + dq, 1e-6)
        cands = [(pd, cnx + rnd[1] * (0.6 * sc), cny + rnd[2] * (0.6 * sc), cnz + rnd[3] * (0.6 * sc)),
                 (cd, cnx + rnd[4] * (0.3 * sc), cny - rnd[1] * (0.3 * sc), cnz)]
        if random_depth:  # a fresh random depth (uniform in inverse depth) with the current normal
            inv_d = rng.uniform(1.0 / far, 1.0 / near, m).astype(np.float32)
            cands.append((jl.Float(1.0 / inv_d), cnx, cny, cnz))
        else:  # a fresh random normal (uniform on the sphere, flipped to face the camera) at the current depth
            gz = rng.normal(size=(3, m)).astype(np.float32)
            cands.append((cd, jl.Float(gz[0]), jl.Float(gz[1]), jl.Float(gz[2])))
        return cands

    def _cheapest(self, win, cands: list[tuple], cur: tuple, rays: tuple, near: float, far: float) -> tuple:
        """The current planes ``cur`` (depth, normal x, y, z, cost) replaced by each candidate that is valid (normal
        facing the camera after flipping, depth inside (near, far)) and cheaper, in turn."""
        dr = self.dr
        near_o, far_o = self._opaque(near), self._opaque(far)
        rx, ry, rn = rays
        cd, cnx, cny, cnz, cc = cur
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
            ccost = self._plane_cost(win, dd, ex, ey, ez)
            dr.eval(ccost)
            better = ok & (ccost < cc)
            cd, cnx, cny, cnz = (dr.select(better, a, b) for a, b in ((dd, cd), (ex, cnx), (ey, cny), (ez, cnz)))
            cc = dr.select(better, ccost, cc)
            dr.eval(cd, cnx, cny, cnz, cc)
        return cd, cnx, cny, cnz, cc


def propagation_regions(kind: str) -> list[list[tuple[int, int]]]:
    """Pixel offsets (dx, dy) of PatchMatch's propagation regions; each region gives its lowest-cost sample's plane.

    'four': the 4 adjacent pixels, one per region. 'adaptive': the adaptive checkerboard sampling of ACMH (Xu and
    Tao 2019, Fig. 2): per direction a V-shaped near region of 7 samples (one step ahead, then 2 samples in each of
    the next 3 rows widening by one pixel) and a long strip of 11 samples (3, 5, ... 23 pixels ahead). Every offset
    has an odd coordinate sum: it lies on the other colour of the red-black checkerboard.
    """
    if kind == "four":
        return [[(-1, 0)], [(1, 0)], [(0, -1)], [(0, 1)]]
    if kind != "adaptive":
        raise InputError(f"propagation must be 'four' or 'adaptive', got {kind!r}")
    # the "up" regions (dy < 0), then rotated by 90 degrees three times: (dx, dy) -> (-dy, dx)
    near = [(0, -1)] + [(sx * i, -1 - i) for i in (1, 2, 3) for sx in (-1, 1)]
    strip = [(0, -3 - 2 * i) for i in range(11)]
    regions = []
    for region in (near, strip):
        r = region
        for _ in range(4):
            regions.append(r)
            r = [(-dy, dx) for dx, dy in r]
    return regions


def _scaled_camera(cam: Camera, factor: int) -> Camera:
    """The camera of the image downsampled by an integer ``factor`` (pixel centres at integers: u' = (u + 0.5) / f
    - 0.5)."""
    s = np.array([[1.0 / factor, 0.0, 0.5 / factor - 0.5], [0.0, 1.0 / factor, 0.5 / factor - 0.5], [0.0, 0.0, 1.0]])
    return Camera(s @ cam.K, cam.R, cam.t, cam.width // factor, cam.height // factor)


def _upsample_planes(depth: np.ndarray, normal: np.ndarray, cost: np.ndarray, coarse: Camera, fine: Camera,
                     factor: int):
    """Full-resolution depth, normal and cost maps from coarse ones: each fine pixel takes the plane (and cost) of the
    coarse pixel it lies in (nearest: no planes blended across an occlusion edge), the plane evaluated along its own
    ray."""
    h, w = fine.height, fine.width
    yi = np.minimum(np.arange(h) // factor, depth.shape[0] - 1)
    xi = np.minimum(np.arange(w) // factor, depth.shape[1] - 1)
    n_c = normal.astype(np.float64)
    # the plane n . X = rho of each coarse pixel, rho from its own ray (K^-1 upper triangular: no full products)
    kc = np.linalg.inv(coarse.K)
    hc, wc = depth.shape
    rx = kc[0, 0] * np.arange(wc)[None, :] + kc[0, 1] * np.arange(hc)[:, None] + kc[0, 2]
    ry = (kc[1, 1] * np.arange(hc) + kc[1, 2])[:, None]
    rho = depth * (n_c[..., 0] * rx + n_c[..., 1] * ry + n_c[..., 2])
    n = n_c[np.ix_(yi, xi)]
    rho, d_c = rho[np.ix_(yi, xi)], depth[np.ix_(yi, xi)]
    kf = np.linalg.inv(fine.K)
    fx = kf[0, 0] * np.arange(w, dtype=float)[None, :] + kf[0, 1] * np.arange(h, dtype=float)[:, None] + kf[0, 2]
    fy = (kf[1, 1] * np.arange(h, dtype=float) + kf[1, 2])[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        d = rho / (n[..., 0] * fx + n[..., 1] * fy + n[..., 2])
    d = np.where(np.isfinite(d) & (d > 0), d, d_c)
    return d.astype(np.float32), n.astype(np.float32), cost[np.ix_(yi, xi)]


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
    DepthMap (depth NaN where the final cost is above ``max_cost`` (``coarse_max_cost`` in coarse to fine) or the
    window is textureless)
    """
    p = (params or DepthParams()).for_view(ref_cam.width, ref_cam.height)
    _check_depth_inputs(src_images, src_cams, p)
    ref = to_gray(ref_image)
    if ref.shape != (ref_cam.height, ref_cam.width):
        raise InputError(f"reference image is {ref.shape[::-1]}, its camera says {(ref_cam.width, ref_cam.height)}")
    srcs = [to_gray(s) for s in src_images]
    keep_near, keep_far = float(depth_range[0]), float(depth_range[1])
    near, far, hypotheses = search_range(keep_near, keep_far, p)
    depths = sweep_depths(near, far, hypotheses)
    textured, coarse, max_cost = _level(ref, p)
    if coarse:
        depth, cost, normal_cam = _coarse_planes(ref, srcs, ref_cam, src_cams, depths, (near, far), p, rng=rng,
                                                 refine=refine)
    else:
        eng = _Engine(ref, srcs, ref_cam, src_cams, p)
        depth, cost, normal_cam = eng.initial_planes(depths)
    if refine and p.pm_iterations > 0:
        if coarse:
            eng = _Engine(ref, srcs, ref_cam, src_cams, p, checker=p.coarse_checker)
        # each level runs its own schedule of perturbation scales (0.5^i, i = 0, 1, ...)
        only_textured = p.pm_textured_only or (coarse and p.fine_textured_only)
        depth, normal_cam, cost = eng.patchmatch(depth.astype(np.float32), normal_cam, near, far, rng,
                                                 active=textured if only_textured else None,
                                                 random_depth=coarse and p.fine_random_depth)
    elif not refine:
        normal_cam = np.zeros(depth.shape + (3,), np.float32)
        normal_cam[..., 2] = -1.0
    keep = _kept(depth, cost, max_cost, textured, keep_near, keep_far)
    background = _background(depth, cost, max_cost, textured, keep_far) if far > keep_far else None
    return _depth_map(depth, normal_cam, cost, keep, ref_cam, planes=(depth, normal_cam) if refine else None,
                      background=background)


def refine_geometric(
    ref_image: np.ndarray,
    src_images: list[np.ndarray],
    ref_cam: Camera,
    src_cams: list[Camera],
    start: DepthMap,
    src_depths: list[np.ndarray],
    depth_range: tuple[float, float],
    params: DepthParams,
    *,
    rng: np.random.Generator,
) -> DepthMap:
    """ACMM's geometric-consistency pass (Xu and Tao 2019) for one view: ``params.geometric_iterations`` more
    PatchMatch iterations at full resolution from the view's photometric planes (``start.planes``), with each
    source's cost raised by its reprojection error through that source's raw depth map (``src_depths``, one per
    source: the planes' depths of the photometric pass). A pixel is kept on its photometric cost, as in
    :func:`estimate_depth`; the result's ``planes`` are the refined ones."""
    p = params.for_view(ref_cam.width, ref_cam.height)
    if start.planes is None:
        raise InputError("the geometric-consistency pass needs the photometric pass's planes (refine=True)")
    ref = to_gray(ref_image)
    srcs = [to_gray(s) for s in src_images]
    keep_near, keep_far = float(depth_range[0]), float(depth_range[1])
    near, far, _ = search_range(keep_near, keep_far, p)
    textured, coarse, max_cost = _level(ref, p)
    eng = _Engine(ref, srcs, ref_cam, src_cams, p, checker=coarse and p.coarse_checker)
    eng.set_geometry(src_depths)
    depth, normal_cam, _ = eng.patchmatch(start.planes[0].astype(np.float32), start.planes[1], near, far, rng,
                                          active=textured if p.pm_textured_only else None,
                                          iterations=p.geometric_iterations,
                                          random_depth=coarse and p.fine_random_depth)
    cost = eng.photometric_cost(depth, normal_cam)
    return _depth_map(depth, normal_cam, cost, _kept(depth, cost, max_cost, textured, keep_near, keep_far),
                      ref_cam, planes=(depth, normal_cam),
                      background=_background(depth, cost, max_cost, textured, keep_far) if far > keep_far else None)


def search_range(near: float, far: float, p: DepthParams) -> tuple[float, float, int]:
    """The depths searched for a scene between ``near`` and ``far`` (:attr:`DepthParams.background_span`): (near,
    the far end moved back by that fraction of the inverse-depth span, the plane count raised in proportion).
    ``p`` as :meth:`DepthParams.for_view` resolves it (an automatic span left unresolved searches no background)."""
    if not (p.background_span or 0.0) > 0:
        return near, far, p.hypotheses
    inv_far = 1.0 / far - p.background_span * (1.0 / near - 1.0 / far)
    inv_far = max(inv_far, 0.01 / far)  # (a finite far end: 100 x the scene's)
    span = (1.0 / near - inv_far) / (1.0 / near - 1.0 / far)
    return near, 1.0 / inv_far, int(np.ceil(p.hypotheses * span))


def _level(ref: np.ndarray, p: DepthParams) -> tuple[np.ndarray, bool, float]:
    """Of a reference view (grey): the pixels textured enough to keep a depth (window std >= ``min_texture``),
    whether coarse to fine runs on it, and the largest cost a kept pixel may have at the final level."""
    _, std = _box_stats(ref, p.sweep_window)
    coarse = p.coarse_scale > 1 and min(ref.shape) // p.coarse_scale >= p.coarse_min_size
    return std >= p.min_texture, coarse, p.coarse_max_cost if coarse else p.max_cost


def _kept(depth: np.ndarray, cost: np.ndarray, max_cost: float, textured: np.ndarray, near: float, far: float
          ) -> np.ndarray:
    """The pixels that keep their depth: cheap enough, textured, and inside (near, far)."""
    return (cost < max_cost) & textured & np.isfinite(depth) & (depth > near) & (depth < far)


def _background(depth: np.ndarray, cost: np.ndarray, max_cost: float, textured: np.ndarray, far: float
                ) -> np.ndarray:
    """The pixels that matched as well as a kept one but beyond the scene's far end: background seen past it."""
    return (cost < max_cost) & textured & np.isfinite(depth) & (depth >= far)


def _check_depth_inputs(src_images: list[np.ndarray], src_cams: list[Camera], p: DepthParams) -> None:
    """InputError unless there is a camera per source image (at least one) and the sweep window and coarse-to-fine
    settings are usable."""
    if not src_images:
        raise InputError("estimate_depth needs at least one source view")
    if len(src_images) != len(src_cams):
        raise InputError("estimate_depth: one camera per source image")
    if p.sweep_window % 2 != 1 or p.sweep_window < 3:
        raise InputError(f"sweep_window must be odd and >= 3, got {p.sweep_window}")
    if not (isinstance(p.coarse_scale, int) and p.coarse_scale >= 1):
        raise InputError(f"coarse_scale must be an integer >= 1, got {p.coarse_scale!r}")
    if not (isinstance(p.coarse_min_size, int) and p.coarse_min_size >= 1):
        raise InputError(f"coarse_min_size must be an integer >= 1, got {p.coarse_min_size!r}")
    propagation_regions(p.propagation)


def _coarse_planes(ref: np.ndarray, srcs: list[np.ndarray], ref_cam: Camera, src_cams: list[Camera],
                   depths: np.ndarray, depth_range: tuple[float, float], p: DepthParams, *, rng: np.random.Generator,
                   refine: bool):
    """The coarse level of coarse to fine: the sweep and the first ``coarse_iterations`` of PatchMatch on the images
    downsampled by ``coarse_scale`` (area averaging), the planes carried to full resolution (depth, cost, camera-
    frame normal), where PatchMatch refines them with random depths to find what the coarse level could not
    resolve."""
    import cv2

    f = p.coarse_scale
    near, far = depth_range
    small = [cv2.resize(g, (g.shape[1] // f, g.shape[0] // f), interpolation=cv2.INTER_AREA) for g in [ref, *srcs]]
    cam_s = _scaled_camera(ref_cam, f)
    eng_s = _Engine(small[0], small[1:], cam_s, [_scaled_camera(c, f) for c in src_cams], p, checker=p.coarse_checker)
    depth, cost, normal_cam = eng_s.initial_planes(depths)
    if refine and p.coarse_iterations > 0:
        depth, normal_cam, cost = eng_s.patchmatch(depth.astype(np.float32), normal_cam, near, far, rng,
                                                   iterations=p.coarse_iterations)
    depth, normal_cam, cost = _upsample_planes(depth, normal_cam, cost, cam_s, ref_cam, f)
    return depth, cost, normal_cam


def _depth_map(depth: np.ndarray, normal_cam: np.ndarray, cost: np.ndarray, keep: np.ndarray, ref_cam: Camera,
               planes: tuple[np.ndarray, np.ndarray] | None = None, background: np.ndarray | None = None) -> DepthMap:
    """The DepthMap of the kept pixels: NaN depth and normal elsewhere, normals turned into world coordinates."""
    depth = np.where(keep, depth, np.nan).astype(np.float32)
    normal = (normal_cam.reshape(-1, 3) @ ref_cam.R).reshape(normal_cam.shape)  # camera -> world: R^T n
    normal = np.where(keep[..., None], normal, np.nan).astype(np.float32)
    return DepthMap(depth, normal, np.where(np.isfinite(cost), cost, 2.0).astype(np.float32), planes, background)
