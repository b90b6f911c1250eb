"""The ``weber-penn`` family: recursive parametric stems (Weber and Penn 1995), a structurally different model from
space colonisation (no markers, no competition for space: every stem's length, angle, bend and children follow
from its parent's by the paper's formulas).

A stem of level n is ``curve_res`` straight segments. From one segment to the next the heading turns by
``curve / curve_res`` about the stem's curvature axis (or ``curve`` over the first half and ``curve_back`` over the
second: an S-curve), by a uniform random ``+-curve_v / curve_res`` about a random axis, and towards +z or -z by
``attraction_up``. At a segment end the stem may split into clones (``seg_splits``, fractional parts carried over;
``base_splits`` at the trunk's crown base), each deflected by ``split_angle`` and spread evenly around the axis,
radius divided by sqrt(clones) (pipe model). Children of level n+1 sit evenly along the stem above its base size,
rolled by ``rotate`` (spiral) or in alternate / opposite / whorl arrangement, at ``down_angle`` from the parent's
direction (a negative ``down_angle_v`` varies it along the parent). Their lengths and counts follow the paper:

- level 1: ``L = L_trunk (length +- length_v) ShapeRatio(shape, (L_trunk - offset) / (L_trunk (1 - base_size)))``;
  deeper: ``L = (length +- length_v) (L_parent - 0.7 offset)``;
- children of the trunk: ``branches``; of a level-1 stem: ``branches (0.2 + 0.8 (L / L_parent) / length_parent)``;
  deeper: ``branches (1 - 0.5 offset / L_parent)``;
- radii: trunk ``r0 = L0 ratio``, child ``r = r_parent (L / L_parent)^ratio_power`` capped at the parent's radius
  where it attaches, tapered along the stem (``taper``), flared at the trunk base (``flare``).

Leaves are one more level on the deepest stems: ``per_stem ShapeRatio(distribution, offset / L_parent)`` Bezier
leaves, evenly spaced above ``start``, in the species' phyllotaxis (:func:`.foliage.place_leaves`).

The skeleton has a node at every segment boundary, at every child's attachment and at every leaf (so children and
leaves hang from nodes); radii never increase from parent to child (a final pass takes the running minimum).
``scale`` in (0, 1] multiplies the tree size by scale^(1/3) and the children counts of each of the k branch levels
by scale^(1/k), so the number of stems (and leaves) shrinks roughly in proportion to ``scale``; leaf size is kept.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from plantbench.errors import InputError
from plantbench.generate.envelope import shape_ratio
from plantbench.generate.foliage import foliage_params, place_leaves
from plantbench.generate.params_wp import BranchLevel, StemLevel, WeberPennSpecies
from plantbench.geometry.tubes import node_frames, tube_mesh
from plantbench.geometry.vectors import depths, levels
from plantbench.plant import Plant, Skeleton

__all__ = ["shape_ratio", "taper_radius", "flare_factor", "WeberPennSkeleton", "grow_skeleton", "grow"]

_Z = (0.0, 0.0, 1.0)
Vec = tuple[float, float, float]  # headings and axes: plain floats (numpy is slow on 3-vectors, one at a time)
_PER_NODE = {"spiral": 1, "alternate": 1, "opposite": 2}


def taper_radius(z: np.ndarray, radius: float, taper: float, length: float) -> np.ndarray:
    """Weber and Penn's stem radius at fractions ``z`` (0 base, 1 tip) of a stem of base ``radius`` and ``length``.

    taper in [0, 1): linear to ``radius (1 - taper)`` at the tip; 1: a cone; (1, 2]: the cone of unit taper
    ``2 - taper`` with a spherical end (a hemisphere for 2). z : (n,) float; returns (n,) float >= 0.
    """
    z = np.clip(np.asarray(z, dtype=np.float64), 0.0, 1.0)
    unit = taper if taper < 1 else 2.0 - taper
    tz = radius * (1.0 - unit * z)
    if taper < 1:
        return tz
    z2 = (1.0 - z) * length  # distance to the tip
    rounded = np.sqrt(np.maximum(tz**2 - (z2 - tz) ** 2, 0.0))
    return np.where(z2 > tz, tz, rounded)


def flare_factor(z: np.ndarray, flare: float) -> np.ndarray:
    """Trunk flare: ``flare (100^y - 1) / 100 + 1`` with ``y = max(0, 1 - 8 z)``; z : (n,) float in [0, 1]."""
    y = np.maximum(0.0, 1.0 - 8.0 * np.asarray(z, dtype=np.float64))
    return flare * (100.0**y - 1.0) / 100.0 + 1.0


def _cross(a: Vec, b: Vec) -> Vec:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _dot(a: Vec, b: Vec) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _lin(ca: float, a: Vec, cb: float, b: Vec) -> Vec:
    """ca a + cb b"""
    return (ca * a[0] + cb * b[0], ca * a[1] + cb * b[1], ca * a[2] + cb * b[2])


def _norm(a: Vec) -> float:
    return math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


def _unit(v: Vec) -> Vec:
    n = _norm(v)
    return (v[0] / n, v[1] / n, v[2] / n) if n > 1e-15 else v


def _rotate(v: Vec, axis: Vec, angle: float) -> Vec:
    """Rodrigues rotation of v about the unit axis by angle (radians)."""
    c, s = math.cos(angle), math.sin(angle)
    kv = _cross(axis, v)
    d = _dot(axis, v) * (1.0 - c)
    return (v[0] * c + kv[0] * s + axis[0] * d, v[1] * c + kv[1] * s + axis[1] * d, v[2] * c + kv[2] * s + axis[2] * d)


@dataclass
class _Stem:
    level: int
    parent_node: int  # -1: the trunk (its root node is created with it)
    start: np.ndarray
    heading: Vec
    normal: Vec  # curvature axis, perpendicular to heading
    length: float
    radius: float  # base radius
    offset: float  # where it sits on its parent, metres
    parent_length: float


@dataclass
class _Path:
    """One run of segments of a stem: the stem itself from segment 0, or a clone from a split onwards."""

    seg: int
    pos: np.ndarray
    heading: Vec
    normal: Vec
    rfac: float
    err: float
    prev: int  # node the path's first node hangs from (-1 only for the trunk's root)
    lateral: bool  # its first node starts a new axis (a child or a clone)
    clone: bool


@dataclass(frozen=True)
class WeberPennSkeleton:
    """What the recursive growth produces before meshing.

    positions : (n, 3) float; radii : (n,) float; parents : (n,) int (-1 root); level : (n,) int (stem level);
    lateral : (n,) bool (first node of a child or clone axis); leaf_nodes : (k,) int increasing (leaf-bearing
    nodes); leaf_index : (k,) int (phyllotaxis step along the twig); leaf_factor : (k,) float (size profile).
    """

    positions: np.ndarray
    radii: np.ndarray
    parents: np.ndarray
    level: np.ndarray
    lateral: np.ndarray
    leaf_nodes: np.ndarray
    leaf_index: np.ndarray
    leaf_factor: np.ndarray
    stems: tuple[int, ...]
    clones: int


class _Builder:
    """The skeleton as it grows: node arrays in chunks (one per run of nodes) and the leaf-bearing nodes."""

    def __init__(self) -> None:
        self.pos: list[np.ndarray] = []
        self.rad: list[np.ndarray] = []
        self.par: list[np.ndarray] = []
        self.lat: list[np.ndarray] = []
        self.lev: list[np.ndarray] = []
        self.n = 0
        self.leaf_nodes: list[np.ndarray] = []
        self.leaf_index: list[np.ndarray] = []
        self.leaf_factor: list[np.ndarray] = []

    def add(self, pos: np.ndarray, rad: np.ndarray, prev: int, lateral: bool, level: int) -> np.ndarray:
        """A chain of nodes, the first hanging from ``prev`` (and starting an axis if ``lateral``); returns their ids."""
        m = len(pos)
        ids = self.n + np.arange(m)
        par = ids - 1
        par[0] = prev
        lat = np.zeros(m, bool)
        lat[0] = lateral
        self.pos.append(pos)
        self.rad.append(rad)
        self.par.append(par)
        self.lat.append(lat)
        self.lev.append(np.full(m, level, np.int64))
        self.n += m
        return ids

    def add_leaves(self, nodes: np.ndarray, index: np.ndarray, factor: np.ndarray) -> None:
        """Leaves at ``nodes``: their phyllotaxis step along the twig and their size factor."""
        self.leaf_nodes.append(nodes)
        self.leaf_index.append(index)
        self.leaf_factor.append(factor)

    def skeleton(self, min_radius: float, stems: list[int], clones: int) -> WeberPennSkeleton:
        """The grown skeleton, radii at least ``min_radius`` and never thicker than the parent, leaves by node."""
        pos = np.concatenate(self.pos)
        parents = np.concatenate(self.par)
        radii = np.maximum(np.concatenate(self.rad), min_radius)
        for idx in levels(parents)[1:]:  # never thicker than the parent
            radii[idx] = np.minimum(radii[idx], radii[parents[idx]])
        ln = np.concatenate(self.leaf_nodes) if self.leaf_nodes else np.zeros(0, np.int64)
        li = np.concatenate(self.leaf_index) if self.leaf_index else np.zeros(0, np.int64)
        lfac = np.concatenate(self.leaf_factor) if self.leaf_factor else np.zeros(0)
        order = np.argsort(ln, kind="stable")
        return WeberPennSkeleton(pos, radii, parents, np.concatenate(self.lev), np.concatenate(self.lat), ln[order],
                                 li[order], lfac[order], tuple(stems), clones)


@dataclass(frozen=True)
class _Plan:
    """The layout of one stem, shared by all its clones: nodes at the segment ends and at every child's and leaf's
    offset (metres from the stem's base), each node's segment and radius, where children and leaves sit."""

    p: StemLevel
    child: BranchLevel | None  # the level of the stem's children (None on the deepest stems)
    per: int  # children per node
    base: float  # fraction of the stem (from its base) without children
    child_offs: np.ndarray
    leaf_offs: np.ndarray
    node_offs: np.ndarray
    node_seg: np.ndarray
    seg_lo: np.ndarray  # nodes seg_lo[i]:seg_hi[i] end on segment i
    seg_hi: np.ndarray
    child_at: np.ndarray  # node of each child
    leaf_at: np.ndarray  # node of each leaf
    node_r: np.ndarray
    split_seg: int  # segment after which the trunk splits into base_splits clones (-1: none)


def _count(x: float, rng: np.random.Generator) -> int:
    """Stochastic rounding: floor(x) plus one with probability frac(x) (unbiased counts)."""
    x = max(float(x), 0.0)
    return int(math.floor(x + rng.random()))


def _even_offsets(count: int, length: float, base: float, rng: np.random.Generator) -> np.ndarray:
    """``count`` offsets evenly spread over [base length, length], each jittered by up to a quarter gap."""
    if count <= 0:
        return np.zeros(0)
    k = np.arange(count) + 0.5 + rng.uniform(-0.25, 0.25, count)
    return np.sort(length * (base + (1.0 - base) * k / count))


def _level_params(spec: WeberPennSpecies, level: int) -> StemLevel:
    return spec.trunk if level == 0 else spec.branch_levels[level - 1]


def _segment_turn(path: _Path, i: int, p: StemLevel, rng: np.random.Generator) -> None:
    """Curvature, random bend and up-attraction applied to a path's heading at the start of segment i."""
    res = p.curve_res
    if p.curve_back == 0.0:
        ang = p.curve / res
    else:
        half = max(res / 2.0, 0.5)
        ang = (p.curve if i < math.ceil(res / 2.0) else p.curve_back) / half
    h, n = path.heading, path.normal
    if ang:
        h = _rotate(h, n, math.radians(ang))
    if p.curve_v:
        theta = rng.uniform(0.0, 2.0 * math.pi)
        axis = _lin(math.cos(theta), n, math.sin(theta), _cross(h, n))
        a = math.radians(rng.uniform(-1.0, 1.0) * p.curve_v / res)
        h, n = _rotate(h, axis, a), _rotate(n, axis, a)
    if p.attraction_up:
        target = _Z if p.attraction_up > 0 else (0.0, 0.0, -1.0)
        axis = _cross(h, target)
        s = _norm(axis)
        if s > 1e-9:
            axis = (axis[0] / s, axis[1] / s, axis[2] / s)
            gap = math.atan2(s, _dot(h, target))
            a = min(abs(p.attraction_up) / res, 1.0) * gap
            h, n = _rotate(h, axis, a), _rotate(n, axis, a)
    h = _unit(h)
    path.heading = h
    path.normal = _unit(_lin(1.0, n, -_dot(n, h), h))


def _child_side(arr: str, h: Vec, n: Vec, phi: float, group: int, jitter: float) -> Vec:
    """Unit vector perpendicular to h towards which a child leaves its parent."""
    if arr == "alternate":
        side = _cross(_Z, h)
        if _norm(side) < 1e-6:
            side = n
        side = _lin(1.0 if group % 2 == 0 else -1.0, _unit(side), 0.0, side)
        return _rotate(side, h, jitter)
    return _lin(math.cos(phi), n, math.sin(phi), _cross(h, n))


def _trunk(spec: WeberPennSpecies, rng: np.random.Generator, scale: float) -> _Stem:
    """The trunk: ``Scale +- ScaleV`` (times scale^(1/3)) by ``0Length +- 0LengthV``, radius ``L0 Ratio``, its
    curvature axis at a random azimuth."""
    t = spec.tree
    size = (t.scale + rng.uniform(-1.0, 1.0) * t.scale_v) * scale ** (1.0 / 3.0)
    size = max(size, 0.05)
    trunk_len = size * max(spec.trunk.length + rng.uniform(-1.0, 1.0) * spec.trunk.length_v, 0.05)
    azimuth = rng.uniform(0.0, 2.0 * math.pi)
    return _Stem(0, -1, np.zeros(3), _Z, (math.cos(azimuth), math.sin(azimuth), 0.0), trunk_len, trunk_len * t.ratio,
                 0.0, trunk_len)


def _child_offsets(spec: WeberPennSpecies, stem: _Stem, base: float, count_scale: float,
                   rng: np.random.Generator) -> tuple[BranchLevel | None, int, np.ndarray]:
    """The level of the stem's children (None on the deepest stems), children per node and the children's offsets
    along the stem: the paper's counts (module docstring) times ``count_scale``, evenly above ``base``."""
    branch_levels = spec.branch_levels
    level = stem.level
    if level >= len(branch_levels):
        return None, 1, np.zeros(0)
    child = branch_levels[level]
    L = stem.length
    if level == 0:
        n_child = child.branches
    elif level == 1:
        n_child = child.branches * (0.2 + 0.8 * (L / stem.parent_length) / branch_levels[0].length)
    else:
        n_child = child.branches * (1.0 - 0.5 * stem.offset / stem.parent_length)
    per = _PER_NODE.get(child.arrangement, child.whorl_count)
    return child, per, _even_offsets(_count(n_child * count_scale / per, rng), L, base, rng)


def _leaf_offsets(spec: WeberPennSpecies, stem: _Stem, rng: np.random.Generator) -> np.ndarray:
    """Offsets of the leaves (or leaf pairs, whorls) along a stem of the deepest level, evenly above ``start``:
    ``per_stem ShapeRatio(distribution, offset / L_parent)``; none on other stems."""
    lv = spec.leaves
    level = stem.level
    if level != len(spec.branch_levels) or lv.per_stem <= 0:
        return np.zeros(0)
    r = 1.0 if level == 0 else stem.offset / stem.parent_length
    n_leaf = lv.per_stem * float(shape_ratio(lv.distribution, np.array([r]))[0])
    leaf_per = {"spiral": 1, "opposite": 2, "whorl": lv.whorl_count}[lv.arrangement]
    return _even_offsets(_count(n_leaf / leaf_per, rng), stem.length, lv.start, rng)


def _plan(spec: WeberPennSpecies, stem: _Stem, count_scale: float, rng: np.random.Generator) -> _Plan:
    """Children and leaves of ``stem`` (the stem's random counts and offsets) and the node layout they give."""
    t = spec.tree
    level = stem.level
    p = _level_params(spec, level)
    L = stem.length
    res = p.curve_res
    sl = L / res
    base = t.base_size if level == 0 else p.base_size  # type: ignore[union-attr]
    child, per, child_offs = _child_offsets(spec, stem, base, count_scale, rng)
    leaf_offs = _leaf_offsets(spec, stem, rng)
    seg_ends = sl * np.arange(1, res + 1)
    seg_ends[-1] = L
    node_offs = np.unique(np.concatenate([child_offs, leaf_offs, seg_ends]))
    keep = np.ones(len(node_offs), bool)
    keep[1:] = np.diff(node_offs) > 1e-9 * L
    node_offs = node_offs[keep]
    node_seg = np.clip(np.searchsorted(seg_ends, node_offs - 1e-9 * L), 0, res - 1)
    seg_lo = np.searchsorted(node_seg, np.arange(res), "left")
    seg_hi = np.searchsorted(node_seg, np.arange(res), "right")
    child_at = np.clip(np.searchsorted(node_offs, child_offs - 1e-9 * L), 0, len(node_offs) - 1)
    leaf_at = np.clip(np.searchsorted(node_offs, leaf_offs - 1e-9 * L), 0, len(node_offs) - 1)
    z = node_offs / L
    node_r = taper_radius(z, stem.radius, p.taper, L)
    if level == 0:
        node_r = node_r * flare_factor(z, t.flare)
    split_seg = min(max(round(t.base_size * res) - 1, 0), res - 2) if (level == 0 and t.base_splits > 0) else -1
    return _Plan(p, child, per, base, child_offs, leaf_offs, node_offs, node_seg, seg_lo, seg_hi, child_at, leaf_at,
                 node_r, split_seg)


def _split_count(path: _Path, i: int, plan: _Plan, base_splits: int) -> int:
    """Clones at the end of segment i: ``base_splits`` where the trunk reaches its crown base, else ``seg_splits``
    with the fractional part carried along the path."""
    if i == plan.split_seg and not path.clone:
        return base_splits
    e = plan.p.seg_splits + path.err
    n_split = int(e)
    path.err = e - n_split
    return n_split


def _split(path: _Path, i: int, n_split: int, p: StemLevel, rng: np.random.Generator) -> list[_Path]:
    """Split ``path`` after segment i into ``n_split + 1`` stems spread evenly around its axis, each deflected by
    ``split_angle``, radius divided by sqrt(n_split + 1). The path goes on as the first; returns the others, to be
    pushed in this order (last first)."""
    k = n_split + 1
    ang = math.radians(max(0.0, p.split_angle + rng.uniform(-1.0, 1.0) * p.split_angle_v))
    phase = rng.uniform(0.0, 2.0 * math.pi)
    h, n0 = path.heading, path.normal
    heads = []
    for j in range(k):
        phi = phase + 2.0 * math.pi * j / k
        side = _lin(math.cos(phi), n0, math.sin(phi), _cross(h, n0))
        axis = _unit(_cross(h, side))
        heads.append((_unit(_rotate(h, axis, ang)), _unit(_rotate(n0, axis, ang))))
    rfac = path.rfac / math.sqrt(k)
    clones = [_Path(i + 1, path.pos.copy(), heads[j][0], heads[j][1], rfac, path.err, path.prev, True, True)
              for j in range(k - 1, 0, -1)]
    path.heading, path.normal = heads[0]
    path.rfac = rfac
    return clones


def _grow_path(spec: WeberPennSpecies, stem: _Stem, plan: _Plan, path: _Path, b: _Builder,
               rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, dict[int, tuple[Vec, Vec]], list[_Path]]:
    """Grow ``path`` segment by segment (:func:`_segment_turn`) to the stem's end, splitting off clones; a branch
    that would reach the ground stops there.

    Returns the id (-1: not grown on this path) and position of each of the plan's nodes, the heading and curvature
    axis of each grown segment, and the clones split off.
    """
    p = plan.p
    level = stem.level
    res = p.curve_res
    sl = stem.length / res
    clearance = spec.wood.ground_clearance
    node_ids = np.full(len(plan.node_offs), -1, np.int64)
    node_pts = np.zeros((len(plan.node_offs), 3))
    seg_frame: dict[int, tuple[Vec, Vec]] = {}
    clones: list[_Path] = []
    for i in range(path.seg, res):
        _segment_turn(path, i, p, rng)
        h = path.heading
        lo, hi = plan.seg_lo[i], plan.seg_hi[i]
        pts = path.pos + np.asarray(h) * (plan.node_offs[lo:hi, None] - i * sl)
        if (level > 0 and pts[-1, 2] < clearance) or pts[-1, 2] < 0.0:
            break  # the branch would reach the ground: it stops here
        ids = b.add(pts, plan.node_r[lo:hi] * path.rfac, path.prev, path.lateral, level)
        node_ids[lo:hi] = ids
        node_pts[lo:hi] = pts
        seg_frame[i] = (h, path.normal)
        path.pos = pts[-1]
        path.prev = int(ids[-1])
        path.lateral = False
        if i >= res - 1:
            break
        n_split = _split_count(path, i, plan, spec.tree.base_splits)
        if n_split > 0:
            clones += _split(path, i, n_split, p, rng)
    return node_ids, node_pts, seg_frame, clones


def _down_angle(child: BranchLevel, length: float, offset: float, base: float, rng: np.random.Generator) -> float:
    """A child's angle from its parent's direction, degrees: ``down_angle +- down_angle_v``, or for a negative
    ``down_angle_v`` ``down_angle + down_angle_v (1 - 2 ShapeRatio(conical, r))``, r = 1 at the parent's base."""
    if child.down_angle_v >= 0:
        return child.down_angle + rng.uniform(-1.0, 1.0) * child.down_angle_v
    rr = np.clip((length - offset) / max(length * (1.0 - base), 1e-9), 0.0, 1.0)
    return child.down_angle + child.down_angle_v * (1.0 - 2.0 * (0.2 + 0.8 * rr))


def _child_frame(h: Vec, side: Vec, down: float) -> tuple[Vec, Vec]:
    """Heading of a child leaving a parent of heading ``h`` at ``down`` degrees towards ``side``, and its curvature
    axis (perpendicular to the plane of the two headings)."""
    d = math.radians(down)
    hc = _unit(_lin(math.cos(d), h, math.sin(d), side))
    axis = _cross(h, side)
    if _norm(axis) < 1e-9:
        axis = side
    return hc, _unit(_lin(1.0, axis, -_dot(axis, hc), hc))


def _child_length(spec: WeberPennSpecies, child: BranchLevel, stem: _Stem, offset: float,
                  rng: np.random.Generator) -> float:
    """A child's length at ``offset`` on ``stem`` (module docstring: ShapeRatio on the trunk, else the parent's
    length left beyond it)."""
    t = spec.tree
    L = stem.length
    lf = child.length + rng.uniform(-1.0, 1.0) * child.length_v
    if stem.level == 0:
        rr = (L - offset) / max(L * (1.0 - t.base_size), 1e-9)
        return L * lf * float(shape_ratio(t.shape, np.array([rr]))[0])
    return lf * (L - 0.7 * offset)


def _spawn_children(spec: WeberPennSpecies, stem: _Stem, plan: _Plan, rfac: float, node_ids: np.ndarray,
                    node_pts: np.ndarray, seg_frame: dict[int, tuple[Vec, Vec]], queue: list[_Stem],
                    rng: np.random.Generator) -> None:
    """Queue the children at the grown nodes of one path of ``stem`` (radius factor ``rfac``), rolled by ``rotate``
    in the level's arrangement; children shorter than a millimetre are dropped."""
    child = plan.child
    assert child is not None
    L = stem.length
    per = plan.per
    phi = rng.uniform(0.0, 2.0 * math.pi)
    for g in np.flatnonzero(node_ids[plan.child_at] >= 0):
        at = plan.child_at[g]
        node = int(node_ids[at])
        o = float(plan.child_offs[g])
        h, n = seg_frame[int(plan.node_seg[at])]
        r_node = float(plan.node_r[at] * rfac)
        if child.arrangement == "spiral" or g > 0:
            phi += math.radians(child.rotate + rng.uniform(-1.0, 1.0) * child.rotate_v)
        for j in range(per):
            if child.arrangement == "opposite":
                phj = phi + math.pi * j
            elif child.arrangement == "whorl":
                phj = phi + 2.0 * math.pi * j / per
            else:
                phj = phi
            jit = math.radians(rng.uniform(-1.0, 1.0) * child.rotate_v)
            side = _unit(_child_side(child.arrangement, h, n, phj, int(g), jit))
            hc, nc = _child_frame(h, side, _down_angle(child, L, o, plan.base, rng))
            lc = _child_length(spec, child, stem, o, rng)
            if lc <= 1e-3:
                continue
            rc = min(stem.radius * (lc / L) ** spec.tree.ratio_power, r_node)
            queue.append(_Stem(stem.level + 1, node, node_pts[at].copy(), hc, nc, lc, rc, o, L))


def _grow_stem(spec: WeberPennSpecies, stem: _Stem, count_scale: float, b: _Builder, queue: list[_Stem],
               rng: np.random.Generator) -> int:
    """Grow ``stem`` as a stack of paths (the stem, then its clones, each grown after the path it split from),
    record the leaves on each path and queue the children; returns the number of clones."""
    plan = _plan(spec, stem, count_scale, rng)
    prev = stem.parent_node
    if stem.level == 0:  # the root node
        prev = int(b.add(np.zeros((1, 3)), np.array([stem.radius * flare_factor(0.0, spec.tree.flare)]), -1, False,
                         0)[0])
    clones = 0
    stack = [_Path(0, stem.start.copy(), stem.heading, stem.normal, 1.0, 0.0, prev, stem.level > 0, False)]
    while stack:
        path = stack.pop()
        node_ids, node_pts, seg_frame, split = _grow_path(spec, stem, plan, path, b, rng)
        stack += split
        clones += len(split)
        if len(plan.leaf_offs):
            got = node_ids[plan.leaf_at]
            ok = got >= 0
            b.add_leaves(got[ok], np.arange(len(plan.leaf_offs))[ok],
                         shape_ratio(spec.leaves.size_profile, 1.0 - plan.leaf_offs[ok] / stem.length))
        if plan.child is not None and len(plan.child_offs):
            _spawn_children(spec, stem, plan, path.rfac, node_ids, node_pts, seg_frame, queue, rng)
    return clones


def grow_skeleton(spec: WeberPennSpecies, rng: np.random.Generator, *, scale: float = 1.0) -> WeberPennSkeleton:
    """The recursive stems of one plant (all random draws from ``rng``, in a fixed order): the trunk, then every
    stem in the order it was queued (breadth first), each queueing its children."""
    if not (0.0 < float(scale) <= 1.0):
        raise InputError(f"scale must be in (0, 1], got {scale}", field="scale")
    last = len(spec.branch_levels)  # level of the leaf-bearing stems
    count_scale = float(scale) ** (1.0 / max(last, 1))
    queue = [_trunk(spec, rng, float(scale))]
    b = _Builder()
    stems = [0] * (last + 1)
    clones = 0
    head = 0
    while head < len(queue):
        stem = queue[head]
        head += 1
        stems[stem.level] += 1
        clones += _grow_stem(spec, stem, count_scale, b, queue, rng)
    return b.skeleton(spec.wood.min_radius, stems, clones)


def grow(spec: WeberPennSpecies, rng: np.random.Generator, *, scale: float = 1.0) -> Plant:
    """Grow one plant of ``spec`` (all random draws from ``rng``)."""
    sk = grow_skeleton(spec, rng, scale=scale)
    pos = sk.positions.copy()
    pos[sk.parents < 0, 2] = 0.0
    skeleton = Skeleton(pos, sk.radii, sk.parents, sk.level)
    main = (sk.parents >= 0) & ~sk.lateral
    w = spec.wood
    branch_mesh = tube_mesh(pos, sk.parents, sk.radii, main, max_sides=w.max_sides, min_sides=w.min_sides,
                            edge_length=w.edge_length)
    tangent, normal, _, _ = node_frames(pos, sk.parents, main)
    foliage = place_leaves(pos, sk.parents, sk.radii, main, tangent, normal, levels(sk.parents),
                           foliage_params(spec), rng, nodes=sk.leaf_nodes, axis_index=sk.leaf_index,
                           length_factor=sk.leaf_factor)
    meta = {
        "derived": {
            "stems_per_level": list(sk.stems),
            "clones": int(sk.clones),
            "max_depth": int(depths(sk.parents).max()) if len(pos) else 0,
        },
        "scale": float(scale),
    }
    return Plant(skeleton, branch_mesh, foliage.mesh, foliage.face_ids, foliage.leaves, meta)
