"""Self-organising tree growth by space colonisation (Palubicki et al. 2009) with Borchert-Honda allocation.

The plant is a set of metamers (nodes at internode ends); every node carries one lateral bud (rolled by phi from
the previous one, at psi from the axis: L-system 1 of Guo et al. 2018) and every axis ends in an apical bud. One growth
cycle:

1. markers inside any node's occupancy sphere (radius rho) are removed;
2. each remaining marker is given to the closest bud whose perception cone (opening theta, radius r) holds it;
   a bud with markers has light Q = 1 and a preferred direction V (normalised sum of unit vectors to them);
3. Borchert-Honda: Q is summed basipetally; the base receives v = alpha Q; at every node the resource is split
   between the axis (weight lambda) and the lateral (1 - lambda) in proportion to their Q;
4. a bud receiving v grows floor(v) metamers (at most ``max_shoot``), each turned towards
   default heading + xi V + eta z (tropism) (turning at most ``max_turn`` per internode), each with a new
   lateral bud; a lit lateral bud breaks in a given
   cycle with probability ``bud_break`` and otherwise stays dormant (Palubicki's bud fates);
5. small lateral branches that got no light for ``shed_age`` cycles are shed.

Before the stems reach the crown envelope their apical buds grow straight up (the clear bole), as in Palubicki's
examples, where the trunk grows until it perceives markers. Everything is vectorised over buds and markers
(``scipy.spatial.cKDTree``) and over tree levels (Borchert-Honda passes).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from plantbench.geometry.nodes import GrowableNodes
from plantbench.geometry.perception import assign_markers
from plantbench.geometry.vectors import levels_of, perpendicular, rotate, unit

__all__ = ["GrowthParams", "GrowthResult", "grow_space_colonisation", "assign_markers", "perceive"]


@dataclass(frozen=True)
class GrowthParams:
    """Growth constants in model units; see :class:`plantbench.generate.params.Growth` for their meaning."""

    internode_length: float
    """l, metres."""
    roll_angle: float
    """phi, degrees."""
    branching_angle: float
    """psi, degrees."""
    perception_angle: float = 90.0
    """theta, degrees (full opening)."""
    perception_radius: float = 5.0
    """r, internode lengths."""
    occupancy_radius: float = 2.0
    """rho, internode lengths."""
    apical_control: float = 0.55
    """lambda."""
    vigour: float = 2.0
    """alpha."""
    max_shoot: int = 4
    """Most metamers per bud per cycle."""
    direction_weight: float = 1.0
    """xi."""
    tropism: float = 0.1
    """eta (+z)."""
    noise: float = 0.1
    """Random deflection per internode, radians."""
    bud_break: float = 0.2
    """Probability per cycle that a lit lateral bud with vigour >= 1 breaks (else it stays dormant: bud fate)."""
    max_iterations: int = 40
    """Growth cycles."""
    shed_age: int = 3
    """Cycles without light before shedding."""
    shed_max_internodes: int = 4
    """Largest branch that can be shed."""
    max_turn: float = 20.0
    """Largest change of heading between successive internodes, degrees (no hairpins or spirals)."""
    bole_height: float = 0.0
    """Stems grow straight up (light forced) while below this height, metres."""
    neighbours: int = 8
    """Closest buds examined per marker (the cone test picks the closest one that sees it)."""


@dataclass(frozen=True)
class GrowthResult:
    """The grown skeleton before radii: parents precede children.

    positions : (n, 3) float; parents : (n,) int (-1 roots); lateral : (n,) bool (first node of a lateral shoot);
    order : (n,) int branch order; headings : (n, 3) float unit growth direction of the internode ending at the node.
    """

    positions: np.ndarray
    parents: np.ndarray
    lateral: np.ndarray
    order: np.ndarray
    headings: np.ndarray
    iterations: int
    growth_units: float
    """Mean metamers per shoot per cycle (rho of Guo et al. 2018, derived)."""
    markers_left: int


def _limit_turn(prev: np.ndarray, new: np.ndarray, max_angle: float) -> np.ndarray:
    """Turn unit headings ``prev`` (n, 3) towards unit ``new`` (n, 3) by at most ``max_angle`` radians."""
    cosang = np.clip(np.sum(prev * new, axis=1), -1.0, 1.0)
    over = cosang < np.cos(max_angle)
    if not over.any():
        return new
    perp = new[over] - cosang[over, None] * prev[over]
    bad = np.linalg.norm(perp, axis=1) < 1e-9
    perp[bad] = perpendicular(prev[over][bad])
    out = new.copy()
    out[over] = unit(np.cos(max_angle) * prev[over] + np.sin(max_angle) * unit(perp))
    return out


def perceive(markers: np.ndarray, bud_pos: np.ndarray, bud_dir: np.ndarray, *, radius: float,
             cos_half_angle: float, neighbours: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Light Q (b,) (1 where a bud has markers) and preferred directions V (b, 3) (normalised sum of unit vectors
    to its markers; zero without markers)."""
    nb = len(bud_pos)
    owner = assign_markers(markers, bud_pos, bud_dir, radius=radius, cos_half_angle=cos_half_angle,
                           neighbours=neighbours)
    mi = np.flatnonzero(owner >= 0)
    bi = owner[mi]
    unitv = unit(markers[mi] - bud_pos[bi])
    q = (np.bincount(bi, minlength=nb) > 0).astype(np.float64)
    vdir = np.zeros((nb, 3))
    for c in range(3):
        vdir[:, c] = np.bincount(bi, weights=unitv[:, c], minlength=nb)
    return q, unit(vdir)


_TREE_COLUMNS = {
    "pos": ((3,), np.float64, 0.0), "head": ((3,), np.float64, 0.0), "ref": ((3,), np.float64, 0.0),
    "lat_dir": ((3,), np.float64, 0.0), "parent": ((), np.int64, -1), "main_child": ((), np.int64, -1),
    "lat_child": ((), np.int64, -1), "order": ((), np.int64, 0), "depth": ((), np.int64, 0),
    "lateral": ((), bool, False), "lat_viable": ((), bool, False), "alive": ((), bool, False),
    "starve": ((), np.int64, 0),
}


class _Tree(GrowableNodes):
    """The growing plant's node arrays (:data:`_TREE_COLUMNS`)."""

    def __init__(self) -> None:
        super().__init__(_TREE_COLUMNS)

    def add(self, pos, head, ref, lat_dir, parent, order, depth, lateral, lat_viable) -> np.ndarray:
        return super().add(pos=pos, head=head, ref=ref, lat_dir=lat_dir, parent=parent, order=order, depth=depth,
                           lateral=lateral, lat_viable=lat_viable)


def _occupy(tree: _Tree, markers: np.ndarray, done: int, radius: float) -> np.ndarray:
    """Step 1: the markers left once those within ``radius`` of the nodes added since node ``done`` die."""
    n = tree.n
    if n > done and len(markers):
        d, _ = cKDTree(tree.pos[done:n]).query(markers, distance_upper_bound=radius)
        markers = markers[~np.isfinite(d)]
    return markers


def _buds(tree: _Tree) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The buds of the living nodes: node (b,) int, direction (b, 3) float and apical (b,) bool; first the apical
    buds (nodes without a main child), then the viable lateral buds that have not grown out."""
    n = tree.n
    alive = tree.alive[:n]
    api = np.flatnonzero(alive & (tree.main_child[:n] < 0))
    lat = np.flatnonzero(alive & (tree.lat_child[:n] < 0) & tree.lat_viable[:n])
    bud_node = np.concatenate([api, lat])
    bud_dir = np.concatenate([tree.head[api], tree.lat_dir[lat]])
    return bud_node, bud_dir, np.arange(len(bud_node)) < len(api)


def _light(tree: _Tree, markers: np.ndarray, bud_node: np.ndarray, bud_dir: np.ndarray, is_api: np.ndarray,
           p: GrowthParams) -> tuple[np.ndarray, np.ndarray]:
    """Step 2: light Q (b,) and preferred direction V (b, 3) of each bud (:func:`perceive`); a stem's apical bud
    below ``bole_height`` that perceives nothing is lit straight ahead (the clear bole)."""
    nb = len(bud_node)
    bud_pos = tree.pos[bud_node]
    q = np.zeros(nb)
    vdir = np.zeros((nb, 3))
    if len(markers) and nb:
        q, vdir = perceive(markers, bud_pos, bud_dir, radius=p.perception_radius * p.internode_length,
                           cos_half_angle=np.cos(np.radians(p.perception_angle) / 2), neighbours=p.neighbours)
    bole = is_api & (tree.order[bud_node] == 0) & (bud_pos[:, 2] < p.bole_height) & (q == 0)
    q[bole] = 1.0
    vdir[bole] = bud_dir[bole]
    return q, vdir


def _light_sums(tree: _Tree, levels: list[np.ndarray], mc: np.ndarray, lc: np.ndarray, bud_node: np.ndarray,
                is_api: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Step 3, basipetal: Q summed from the tips down.

    Returns, per node (index n: no node), the light of its subtree ``s`` (0 once dead), the light through its axis
    ``sm`` (its apical bud and main child) and through its lateral ``sl`` (its lateral bud and lateral child), and
    the living nodes of its subtree ``cnt``. ``mc``, ``lc`` : (n,) main and lateral child, n where there is none.
    """
    n = tree.n
    qa = np.zeros(n + 1)
    ql = np.zeros(n + 1)
    qa[bud_node[is_api]] = q[is_api]
    ql[bud_node[~is_api]] = q[~is_api]
    s = np.zeros(n + 1)
    sm = np.zeros(n + 1)
    sl = np.zeros(n + 1)
    cnt = np.zeros(n + 1, np.int64)
    al = np.append(tree.alive[:n], False)
    for idx in reversed(levels):
        sm[idx] = qa[idx] + s[mc[idx]]
        sl[idx] = ql[idx] + s[lc[idx]]
        s[idx] = np.where(al[idx], sm[idx] + sl[idx], 0.0)
        cnt[idx] = al[idx] + cnt[mc[idx]] + cnt[lc[idx]]
    return s, sm, sl, cnt


def _vigour(tree: _Tree, levels: list[np.ndarray], mc: np.ndarray, lc: np.ndarray, s: np.ndarray, sm: np.ndarray,
            sl: np.ndarray, p: GrowthParams) -> tuple[np.ndarray, np.ndarray]:
    """Step 3, acropetal: the base receives alpha Q; every node splits what it receives between its axis (weight
    lambda) and its lateral (1 - lambda) in proportion to their light. Returns the resource of each node's apical
    and lateral bud (n + 1,)."""
    n = tree.n
    lam = p.apical_control
    vin = np.zeros(n + 1)
    va = np.zeros(n + 1)
    vl = np.zeros(n + 1)
    roots = np.flatnonzero(tree.parent[:n] < 0)
    vin[roots] = p.vigour * s[roots]
    for idx in levels:
        v = vin[idx]
        den = lam * sm[idx] + (1 - lam) * sl[idx]
        den = np.where(den > 0, den, 1.0)
        vm = v * lam * sm[idx] / den
        vlat = v * (1 - lam) * sl[idx] / den
        vin[mc[idx]] = vm
        vin[lc[idx]] = vlat
        va[idx] = vm
        vl[idx] = vlat
    return va, vl


def _shed(tree: _Tree, levels: list[np.ndarray], s: np.ndarray, cnt: np.ndarray, p: GrowthParams) -> None:
    """Step 5: a lateral branch counts the cycles it stays dark; one dark for ``shed_age`` cycles with at most
    ``shed_max_internodes`` living nodes dies, with everything on it."""
    n = tree.n
    alive = tree.alive[:n]
    latroots = np.flatnonzero(alive & tree.lateral[:n])
    dark = s[latroots] == 0
    tree.starve[latroots] = np.where(dark, tree.starve[latroots] + 1, 0)
    shed = np.zeros(n + 1, bool)
    shed[latroots] = dark & (tree.starve[latroots] >= p.shed_age) & (cnt[latroots] <= p.shed_max_internodes)
    for idx in levels:
        par = tree.parent[idx]
        shed[idx] |= np.where(par >= 0, shed[np.maximum(par, 0)], False)
    tree.alive[np.flatnonzero(shed[:n] & alive)] = False


def _shoot_lengths(tree: _Tree, bud_node: np.ndarray, is_api: np.ndarray, q: np.ndarray, va: np.ndarray,
                   vl: np.ndarray, p: GrowthParams, rng: np.random.Generator) -> np.ndarray:
    """Step 4: metamers (b,) each bud grows this cycle, floor(v) capped at ``max_shoot`` for a living lit bud; bud
    fate: a lateral bud breaks with probability ``bud_break``, else it stays dormant."""
    vig = np.where(is_api, va[bud_node], vl[bud_node])
    nmet = np.minimum(np.floor(vig + 1e-9), p.max_shoot).astype(np.int64)
    nmet[~tree.alive[bud_node]] = 0
    nmet[q == 0] = 0
    nmet[~is_api & (rng.random(len(bud_node)) >= p.bud_break)] = 0
    return nmet


def _shoot_start(tree: _Tree, node: np.ndarray, lateral: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Heading (k, 3) and roll reference (k, 3) a shoot from the apical or ``lateral`` bud of ``node`` starts from:
    an axis goes on as it was; a lateral starts along its bud, referenced to the plane of the two axes."""
    head = np.where(lateral[:, None], tree.lat_dir[node], tree.head[node])
    ref_lat = np.cross(head, tree.head[node])
    bad = np.linalg.norm(ref_lat, axis=1) < 1e-9
    ref_lat[bad] = perpendicular(head[bad])
    ref = np.where(lateral[:, None], unit(ref_lat), tree.ref[node])
    return head, ref


def _roll(h: np.ndarray, ref: np.ndarray, psi: float, phi: float) -> tuple[np.ndarray, np.ndarray]:
    """Roll reference and lateral bud direction (k, 3) of new internodes with unit headings ``h``: the previous
    reference follows the heading, then rolls by ``phi``; the bud leaves at ``psi`` from ``h`` towards it."""
    r0 = ref - np.sum(ref * h, 1, keepdims=True) * h
    bad = np.linalg.norm(r0, axis=1) < 1e-9
    r0[bad] = perpendicular(h[bad])
    r0 = rotate(unit(r0), h, phi)
    return r0, unit(np.cos(psi) * h + np.sin(psi) * r0)


def _grow_shoots(tree: _Tree, node: np.ndarray, lateral: np.ndarray, count: np.ndarray, vdir: np.ndarray,
                 p: GrowthParams, rng: np.random.Generator) -> None:
    """Step 4: the apical or ``lateral`` bud of each ``node`` grows ``count`` metamers, each turned towards default
    heading + xi V + eta z plus noise (at most ``max_turn`` per internode) and carrying a new lateral bud."""
    up = np.array([0.0, 0.0, 1.0])
    psi = np.radians(p.branching_angle)
    phi = np.radians(p.roll_angle)
    max_turn = np.radians(p.max_turn)
    head, ref = _shoot_start(tree, node, lateral)
    prev = node.copy()
    order = tree.order[node] + lateral
    depth = tree.depth[node]
    for step in range(int(count.max())):
        act = np.flatnonzero(count > step)
        h = head[act] + p.direction_weight * vdir[act] + p.tropism * up
        h = h + p.noise * rng.normal(size=(len(act), 3))
        h = _limit_turn(head[act], unit(h), max_turn)
        r0, ldir = _roll(h, ref[act], psi, phi)
        pos = tree.pos[prev[act]] + p.internode_length * h
        viable = np.ones(len(act), bool)
        first = step == 0
        new = tree.add(pos, h, r0, ldir, prev[act], order[act], depth[act] + step + 1, lateral[act] & first, viable)
        if first:
            lat_first = lateral[act]
            tree.lat_child[prev[act][lat_first]] = new[lat_first]
            tree.main_child[prev[act][~lat_first]] = new[~lat_first]
        else:
            tree.main_child[prev[act]] = new
        prev[act] = new
        head[act] = h
        ref[act] = r0


def _result(tree: _Tree, iterations: int, metamers: int, shoots: int, markers_left: int) -> GrowthResult:
    """The living nodes, renumbered in order."""
    keep, parents = tree.alive_rows()
    return GrowthResult(
        positions=tree.pos[keep].copy(),
        parents=parents,
        lateral=tree.lateral[keep].copy(),
        order=tree.order[keep].copy(),
        headings=tree.head[keep].copy(),
        iterations=iterations,
        growth_units=metamers / shoots if shoots else 0.0,
        markers_left=markers_left,
    )


def grow_space_colonisation(
    markers: np.ndarray,
    root_positions: np.ndarray,
    root_directions: np.ndarray,
    params: GrowthParams,
    rng: np.random.Generator,
) -> GrowthResult:
    """Grow a forest of ``len(root_positions)`` stems competing for ``markers``.

    markers : (m, 3) float, attraction points (metres)
    root_positions : (k, 3) float; root_directions : (k, 3) float, initial headings

    Growth stops after ``max_iterations`` cycles, or earlier when no bud is lit or none grows.
    """
    p = params
    tree = _Tree()
    k = len(root_positions)
    rdir = unit(np.asarray(root_directions, dtype=np.float64))
    tree.add(np.asarray(root_positions, dtype=np.float64), rdir, perpendicular(rdir), rdir, -1,
             np.zeros(k, np.int64), np.zeros(k, np.int64), np.zeros(k, bool), np.zeros(k, bool))
    markers = np.asarray(markers, dtype=np.float64)
    killed_upto = 0
    shoots = 0
    metamers = 0
    it = 0
    for cycle in range(1, p.max_iterations + 1):
        it = cycle
        markers = _occupy(tree, markers, killed_upto, p.occupancy_radius * p.internode_length)
        killed_upto = tree.n
        bud_node, bud_dir, is_api = _buds(tree)
        q, vdir = _light(tree, markers, bud_node, bud_dir, is_api, p)
        if not q.any():
            break
        n = tree.n
        levels = levels_of(tree.depth[:n])
        mc = np.where(tree.main_child[:n] >= 0, tree.main_child[:n], n)
        lc = np.where(tree.lat_child[:n] >= 0, tree.lat_child[:n], n)
        s, sm, sl, cnt = _light_sums(tree, levels, mc, lc, bud_node, is_api, q)
        va, vl = _vigour(tree, levels, mc, lc, s, sm, sl, p)
        _shed(tree, levels, s, cnt, p)
        nmet = _shoot_lengths(tree, bud_node, is_api, q, va, vl, p, rng)
        grow = np.flatnonzero(nmet > 0)
        if len(grow) == 0:
            break
        shoots += len(grow)
        metamers += int(nmet[grow].sum())
        _grow_shoots(tree, bud_node[grow], ~is_api[grow], nmet[grow], vdir[grow], p, rng)
    return _result(tree, it, metamers, shoots, len(markers))
