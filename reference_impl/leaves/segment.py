"""Candidate leaves from each view independently (Chaurasia and Beardsley 2017, section 4.1), vectorised
over superpixels.

1. SLIC superpixels (scikit-image) on colour (Lab) and depth, over the pixels that have a depth.
2. A RANSAC plane per superpixel (3-point hypotheses, inlier distance delta_plane, least-squares refit on the
   inliers), points far from the inliers' mean removed; superpixels with too few points or no valid plane dropped.
3. A graph on the remaining superpixels: edges between superpixels that share an image boundary, affinity Eq. 8 from
   the normal term and the 3D-distance term of Eq. 7 (sigma 0.2), thresholded at 0.85.
4. Connected components are the candidate leaves; their confidence is the fraction of their minimum-area
   enclosing ellipse they fill (section 4.1, "leaf confidence"), computed for all candidates at once in
   :func:`candidate_confidence`.

Eq. 7's 3D distance is the minimum distance between the points of two superpixels. On a dense multi-view stereo
cloud (the paper's input) two superpixels of one leaf touch, but a depth map samples one point per pixel, so two
adjacent pixels on one leaf are a pixel footprint apart (a few mm at our resolutions, comparable to delta_plane for
small leaves). The distance used here is the one that is zero for touching surfaces whatever the sampling: for each
pair of 4-adjacent pixels across the shared boundary, the mean distance of each point to the other superpixel's
plane, minimised over the boundary.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from plantbench.cameras import Camera

from .params import LeafParams

__all__ = ["ViewSegments", "backproject", "segment_view", "fit_planes", "superpixel_graph", "candidate_confidence"]


@dataclass
class ViewSegments:
    """The kept points of one view and their superpixel and candidate labels.

    points : (n, 3) float, world coordinates of the kept pixels (on a valid plane)
    pixel : (n,) int, flat pixel index (v * width + u)
    normal : (n, 3) float, unit normal of the point's superpixel plane, towards the camera
    area : (n,) float, surface area the pixel covers on that plane (m^2)
    candidate : (n,) int, candidate leaf of the point within this view (-1: none)
    superpixels : number of SLIC superpixels; skipped : superpixels dropped per reason
    """

    points: np.ndarray
    pixel: np.ndarray
    normal: np.ndarray
    area: np.ndarray
    candidate: np.ndarray
    superpixels: int = 0
    skipped: dict = field(default_factory=dict)


def backproject(depth: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """World points of the pixels with a finite positive depth.

    depth : (h, w) float, z-depth along the optical axis (inf or NaN: no depth)
    returns : points (n, 3) float and their flat pixel indices (n,) int (row-major)
    """
    d = np.asarray(depth, float)
    flat = np.flatnonzero(np.isfinite(d) & (d > 0))
    v, u = np.divmod(flat, d.shape[1])
    z = d.ravel()[flat]
    pix = np.stack([u * z, v * z, z], axis=1).astype(float)
    xc = pix @ np.linalg.inv(camera.K).T
    return (xc - camera.t) @ camera.R, flat


def _segment_starts(labels: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For labels sorted ascending: unique labels, segment starts and counts."""
    uniq, starts, counts = np.unique(labels, return_index=True, return_counts=True)
    return uniq, starts, counts


def _plane_ls(points: np.ndarray, seg: np.ndarray, weight: np.ndarray, nseg: int
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares plane per segment over weighted points: centroid (s, 3), unit normal (s, 3), weight sum (s,)."""
    c, vec, wsum = _segment_pca(points, seg, weight, nseg)
    return c, vec[:, :, 0], wsum


def _segment_pca(points: np.ndarray, seg: np.ndarray, weight: np.ndarray, nseg: int
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weighted PCA per segment: centroid (s, 3), principal axes as columns in increasing variance (s, 3, 3) and
    weight sum (s,)."""
    wsum = np.bincount(seg, weight, nseg)
    c = np.stack([np.bincount(seg, weight * points[:, k], nseg) for k in range(3)], 1) / np.maximum(wsum, 1e-12)[:, None]
    d = points - c[seg]
    cov = np.zeros((nseg, 3, 3))
    for i in range(3):
        for j in range(i, 3):
            cov[:, i, j] = cov[:, j, i] = np.bincount(seg, weight * d[:, i] * d[:, j], nseg)
    _, vec = np.linalg.eigh(cov + 1e-18 * np.eye(3))
    return c, vec, wsum


def fit_planes(points: np.ndarray, seg: np.ndarray, nseg: int, *, delta: float, params: LeafParams,
               rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """RANSAC plane per segment, all segments at once.

    points : (n, 3) float; seg : (n,) int in [0, nseg), the point's segment
    returns : keep (n,) bool (inlier of a valid plane and not far from its mean), centroid (nseg, 3),
        normal (nseg, 3), valid (nseg,) bool (enough points and a plane explaining min_inlier_fraction of them)
    """
    n = len(points)
    counts = np.bincount(seg, minlength=nseg)
    order = np.argsort(seg, kind="stable")
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    h = params.ransac_iterations
    pick = starts[:, None, None] + np.floor(rng.random((nseg, h, 3)) * counts[:, None, None]).astype(np.int64)
    pick = order[np.minimum(pick, n - 1)]
    p0, p1, p2 = points[pick[..., 0]], points[pick[..., 1]], points[pick[..., 2]]
    nrm = np.cross(p1 - p0, p2 - p0)
    ln = np.linalg.norm(nrm, axis=-1)
    ok = ln > 1e-12
    nrm = nrm / np.where(ok, ln, 1.0)[..., None]
    off = np.einsum("shk,shk->sh", nrm, p0)
    best = np.zeros(nseg, np.int64)
    score = np.full((nseg, h), -1, np.int64)
    chunk = max(1, 4_000_000 // max(h, 1))
    for a in range(0, n, chunk):  # inlier counts per hypothesis, (points x hypotheses) in chunks
        sl = slice(a, a + chunk)
        s = seg[sl]
        dist = np.abs(np.einsum("nk,nhk->nh", points[sl], nrm[s]) - off[s])
        inl = (dist < delta) & ok[s]
        for j in range(h):
            score[:, j] += np.bincount(s, inl[:, j], nseg).astype(np.int64)
    best = np.argmax(score, axis=1)
    bn, bo = nrm[np.arange(nseg), best], off[np.arange(nseg), best]
    inlier = np.abs(np.einsum("nk,nk->n", points, bn[seg]) - bo[seg]) < delta
    # least-squares refit on the inliers, then the final inliers of the refitted plane
    c, normal, _ = _plane_ls(points, seg, inlier.astype(float), nseg)
    dist = np.abs(np.einsum("nk,nk->n", points - c[seg], normal[seg]))
    inlier = dist < delta
    c, normal, _ = _plane_ls(points, seg, inlier.astype(float), nseg)
    # far from the inliers' mean: more than outlier_factor x the segment's median radius
    rad = np.linalg.norm(points - c[seg], axis=1)
    med = _segment_median(np.where(inlier, rad, np.inf), seg, nseg, inlier)
    keep = inlier & (rad <= params.outlier_factor * np.maximum(med[seg], 1e-9))
    nkeep = np.bincount(seg, keep, nseg)
    valid = (nkeep >= params.min_points) & (nkeep >= params.min_inlier_fraction * np.maximum(counts, 1))
    keep &= valid[seg]
    return keep, c, normal, valid


def _segment_median(values: np.ndarray, seg: np.ndarray, nseg: int, use: np.ndarray) -> np.ndarray:
    """Median of ``values[use]`` per segment (inf where a segment has none)."""
    idx = np.flatnonzero(use)
    out = np.full(nseg, np.inf)
    if not len(idx):
        return out
    o = idx[np.lexsort((values[idx], seg[idx]))]
    s = seg[o]
    uniq, starts, counts = _segment_starts(s)
    out[uniq] = values[o[starts + counts // 2]]
    return out


def superpixel_graph(label_img: np.ndarray, point_img: np.ndarray, centroid: np.ndarray, normal: np.ndarray, *,
                     delta: float, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """Edges between superpixels sharing an image boundary and their affinity (Eq. 7-8).

    label_img : (h, w) int, superpixel of each pixel (-1: none or dropped)
    point_img : (h, w, 3) float, the pixel's world point (only read where label_img >= 0)
    centroid, normal : (s, 3) float, each superpixel's plane
    returns : edges (e, 2) int (i < j) and affinity (e,) float
    """
    pairs_a, pairs_b = [], []
    h, w = label_img.shape
    flat = label_img.ravel()
    for di, dj in ((0, 1), (1, 0)):
        a = np.arange(h * w).reshape(h, w)[: h - di, : w - dj].ravel()
        b = a + di * w + dj
        sel = (flat[a] >= 0) & (flat[b] >= 0) & (flat[a] != flat[b])
        pairs_a.append(a[sel])
        pairs_b.append(b[sel])
    a, b = np.concatenate(pairs_a), np.concatenate(pairs_b)
    if not len(a):
        return np.zeros((0, 2), np.int64), np.zeros(0)
    pts = point_img.reshape(-1, 3)
    la, lb = flat[a], flat[b]
    gap_b = np.abs(np.einsum("nk,nk->n", pts[b] - centroid[la], normal[la]))
    gap_a = np.abs(np.einsum("nk,nk->n", pts[a] - centroid[lb], normal[lb]))
    gap = 0.5 * (gap_a + gap_b)
    i, j = np.minimum(la, lb), np.maximum(la, lb)
    key = i.astype(np.int64) * (int(flat.max()) + 1) + j
    order = np.lexsort((gap, key))
    key, gap, i, j = key[order], gap[order], i[order], j[order]
    first = np.concatenate([[True], key[1:] != key[:-1]])
    i, j, gmin = i[first], j[first], gap[first]  # minimum over the boundary (sorted by gap within a key)
    dn = 1.0 - np.abs(np.einsum("nk,nk->n", normal[i], normal[j]))
    dp = gmin / delta
    aff = np.exp(-(dn**2 + dp**2) / (2 * sigma**2))
    return np.stack([i, j], 1), aff


def segment_view(image: np.ndarray, depth: np.ndarray, camera: Camera, *, delta: float, leaf_length: float,
                 params: LeafParams, rng: np.random.Generator, exclude: np.ndarray | None = None) -> ViewSegments:
    """Candidate leaves of one view (section 4.1): superpixels, a plane per superpixel, the affinity graph's
    components.

    image : (h, w, 3) uint8 RGB; depth : (h, w) float z-depth (inf/NaN: none)
    delta : delta_plane, metres; leaf_length : expected leaf length, metres (sizes the superpixels)
    exclude : (h, w) bool, pixels to ignore (e.g. the ground), optional
    """
    hgt, wid = depth.shape
    pts_all, flat_all = backproject(depth, camera)
    fg = np.zeros(hgt * wid, bool)
    fg[flat_all] = True
    if exclude is not None:
        fg &= ~np.asarray(exclude, bool).ravel()
    if fg.sum() < params.min_points:
        return ViewSegments(np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0),
                            np.zeros(0, np.int64), 0, {})
    keep_pt = fg[flat_all]
    pts_all, flat_all = pts_all[keep_pt], flat_all[keep_pt]
    labels = _superpixels(image, depth, fg.reshape(hgt, wid), camera, delta=delta, leaf_length=leaf_length,
                          params=params)
    seg_of_px = labels.ravel()[flat_all] - 1
    ok = seg_of_px >= 0
    pts, flat, seg = pts_all[ok], flat_all[ok], seg_of_px[ok]
    nseg = int(labels.max())
    counts = np.bincount(seg, minlength=nseg)
    keep, centroid, normal, valid = fit_planes(pts, seg, nseg, delta=delta, params=params, rng=rng)
    present = counts > 0
    skipped = {"superpixel_few_points": int((present & (counts < params.min_points)).sum()),
               "superpixel_no_plane": int((present & (counts >= params.min_points) & ~valid).sum())}
    # normals towards the camera
    flip = np.einsum("sk,sk->s", normal, camera.center - centroid) < 0
    normal[flip] *= -1
    pts, flat, seg = pts[keep], flat[keep], seg[keep]
    cand_of_seg = _candidate_of_superpixel(pts, flat, seg, (hgt, wid), centroid, normal, valid, delta=delta,
                                           params=params)
    area = _pixel_area(pts, normal[seg], camera)
    return ViewSegments(pts, flat, normal[seg], area, cand_of_seg[seg], nseg, skipped)


def _superpixels(image: np.ndarray, depth: np.ndarray, fg: np.ndarray, camera: Camera, *, delta: float,
                 leaf_length: float, params: LeafParams) -> np.ndarray:
    """(h, w) int SLIC labels (1..) of the pixels of ``fg`` (0 elsewhere) on colour (Lab) and depth, sized for
    ``superpixels_per_leaf`` superpixels per leaf of ``leaf_length`` facing the camera at the median depth.

    SLIC runs on the bounding box of the pixels with depth, unmasked (scikit-image's masked mode seeds its centres by
    k-means over the mask, several times slower); pixels without depth get a depth feature beyond every surface,
    so superpixels do not cross into them, and are dropped afterwards. scikit-image rescales the feature image to
    [0, 1] (jointly over channels), so the compactness, meant in Lab units, is divided by the feature range.
    """
    from skimage.color import rgb2lab
    from skimage.segmentation import slic

    z = np.where(fg, np.nan_to_num(depth, nan=0.0, posinf=0.0), 0.0)
    zmed = float(np.median(z[fg]))
    fx, fy = camera.K[0, 0], camera.K[1, 1]
    leaf_px = 0.35 * leaf_length**2 * fx * fy / zmed**2  # projected area of a leaf facing the camera, pixels
    sp_area = max(params.min_superpixel_px, leaf_px / params.superpixels_per_leaf)
    rows, cols = np.flatnonzero(fg.any(1)), np.flatnonzero(fg.any(0))
    r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    lab = rgb2lab(np.asarray(image[r0:r1, c0:c1, :3], np.uint8))
    zf = params.depth_weight * (z[r0:r1, c0:c1] - zmed) / delta
    inside = fg[r0:r1, c0:c1]
    zf = np.where(inside, zf, zf[inside].max() + 100.0)
    feat = np.concatenate([lab, zf[..., None]], axis=2)
    frange = float(feat.max() - feat.min())
    nseg_target = max(1, int(round((r1 - r0) * (c1 - c0) / sp_area)))
    crop = slic(feat, n_segments=nseg_target, compactness=params.slic_compactness / max(frange, 1e-9),
                channel_axis=-1, convert2lab=False, start_label=1, enforce_connectivity=True)
    labels = np.zeros(fg.shape, np.int64)
    labels[r0:r1, c0:c1] = np.where(fg[r0:r1, c0:c1], crop, 0)
    return labels


def _candidate_of_superpixel(pts: np.ndarray, flat: np.ndarray, seg: np.ndarray, shape: tuple[int, int],
                             centroid: np.ndarray, normal: np.ndarray, valid: np.ndarray, *, delta: float,
                             params: LeafParams) -> np.ndarray:
    """(nseg,) candidate leaf of each superpixel (-1: none): the connected components of the graph of valid
    superpixels joined by an affinity above ``affinity_threshold``, renumbered 0..k-1.

    pts, flat, seg : the kept points, their flat pixel indices and superpixels; shape : the image's (h, w)
    centroid, normal : (nseg, 3) the superpixel planes; valid : (nseg,) bool, superpixels with a plane
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    hgt, wid = shape
    nseg = len(valid)
    label_img = np.full(hgt * wid, -1, np.int64)
    label_img[flat] = seg
    point_img = np.zeros((hgt * wid, 3))
    point_img[flat] = pts
    edges, aff = superpixel_graph(label_img.reshape(hgt, wid), point_img.reshape(hgt, wid, 3), centroid, normal,
                                  delta=delta, sigma=params.sigma)
    strong = edges[aff > params.affinity_threshold]
    graph = coo_matrix((np.ones(len(strong)), (strong[:, 0], strong[:, 1])), shape=(nseg, nseg))
    _, comp = connected_components(graph, directed=False)
    comp_valid = np.where(valid, comp, -1)
    _, cand_of_seg = np.unique(comp_valid, return_inverse=True)
    return cand_of_seg - (1 if (comp_valid < 0).any() else 0)


def _pixel_area(pts: np.ndarray, normal: np.ndarray, camera: Camera) -> np.ndarray:
    """(n,) surface area (m^2) each pixel's point covers on its plane (unit ``normal`` (n, 3)): the pixel footprint
    z^2 cos(alpha) / (fx fy cos(theta)), theta at least acos(0.2)."""
    fx, fy = camera.K[0, 0], camera.K[1, 1]
    ray = pts - camera.center
    rn = np.linalg.norm(ray, axis=1)
    zc = (pts @ camera.R.T + camera.t)[:, 2]
    cos_t = np.abs(np.einsum("nk,nk->n", ray, normal)) / rn
    return zc**2 * (zc / rn) / (fx * fy * np.maximum(cos_t, 0.2))


@dataclass
class Candidate:
    """One candidate leaf (a connected component of one view's superpixel graph) with its enclosing ellipse.

    view : view index; index : (k,) indices into the scene point arrays; area : surface area (m^2)
    centre : (3,) ellipse centre (world); frame : (3, 3) rows e1 (major axis), e2 (minor), e3 (plane normal)
    semi_axes : (a, b) metres; confidence : area / ellipse area, in [0, 1]
    """

    view: int
    index: np.ndarray
    area: float
    centre: np.ndarray
    frame: np.ndarray
    semi_axes: tuple[float, float]
    confidence: float


def candidate_confidence(points: np.ndarray, groups: list[np.ndarray], areas: np.ndarray, views: list[int]
                         ) -> list[Candidate | None]:
    """Confidence of each candidate: the fraction of its minimum-area enclosing ellipse (in its PCA plane) that its
    surface fills. None for degenerate candidates (collinear points: no ellipse).

    points : (n, 3) float scene points; groups : list of (k_i,) int indices into points
    areas : (len(groups),) float surface areas; views : the view of each group
    """
    from .ellipse import min_volume_ellipses

    if not groups:
        return []
    sizes = np.array([len(g) for g in groups])
    flat = np.concatenate(groups)
    seg = np.repeat(np.arange(len(groups)), sizes)
    cents, vec, _ = _segment_pca(points[flat], seg, np.ones(len(flat)), len(groups))  # all candidates at once
    e1, e2 = vec[:, :, 2], vec[:, :, 1]  # largest, middle variance
    frames = np.stack([e1, e2, np.cross(e1, e2)], axis=1)  # rows, right-handed
    local = np.einsum("nij,nj->ni", frames[seg, :2], points[flat] - cents[seg])
    flat2 = np.split(local, np.cumsum(sizes)[:-1])
    ells = min_volume_ellipses(flat2)
    out: list[Candidate | None] = []
    for g, f, c, e, a, v in zip(groups, frames, cents, ells, areas, views, strict=True):
        if e is None:
            out.append(None)
            continue
        ax, dirs = e.axes
        major = dirs[:, 0]
        e1 = major[0] * f[0] + major[1] * f[1]
        e2 = np.cross(f[2], e1)
        centre = c + e.centre[0] * f[0] + e.centre[1] * f[1]
        conf = float(min(1.0, a / e.area))
        out.append(Candidate(int(v), g, float(a), centre, np.stack([e1, e2, f[2]]), (float(ax[0]), float(ax[1])),
                             conf))
    return out
