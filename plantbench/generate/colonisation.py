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


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 1e-15, n, 1.0)


def _perpendicular(d: np.ndarray) -> np.ndarray:
    """(n, 3) unit vectors perpendicular to unit vectors d (n, 3)."""
    a = np.where(np.abs(d[:, [0]]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    return _unit(np.cross(d, a))


def _limit_turn(prev: np.ndarray, new: np.ndarray, max_angle: float) -> np.ndarray:
    """Turn unit headings ``prev`` (n, 3) towards unit ``new`` (n, 3) by at most ``max_angle`` radians."""
    cosang = np.clip(np.sum(prev * new, axis=1), -1.0, 1.0)
    over = cosang < np.cos(max_angle)
    if not over.any():
        return new
    perp = new[over] - cosang[over, None] * prev[over]
    bad = np.linalg.norm(perp, axis=1) < 1e-9
    perp[bad] = _perpendicular(prev[over][bad])
    out = new.copy()
    out[over] = _unit(np.cos(max_angle) * prev[over] + np.sin(max_angle) * _unit(perp))
    return out


def _rotate(v: np.ndarray, axis: np.ndarray, angle: float | np.ndarray) -> np.ndarray:
    """Rodrigues rotation of v (n, 3) about unit axes (n, 3) by angle(s) in radians."""
    c = np.cos(angle)
    s = np.sin(angle)
    if np.ndim(c):
        c = c[:, None]
        s = s[:, None]
    return v * c + np.cross(axis, v) * s + axis * np.sum(axis * v, axis=1, keepdims=True) * (1 - c)


def assign_markers(markers: np.ndarray, bud_pos: np.ndarray, bud_dir: np.ndarray, *, radius: float,
                   cos_half_angle: float, neighbours: int = 8) -> np.ndarray:
    """Each marker's bud: the closest bud within ``radius`` whose perception cone holds the marker, else -1.

    markers : (m, 3) float; bud_pos : (b, 3) float; bud_dir : (b, 3) float unit cone axes
    Only the ``neighbours`` closest buds of each marker are examined (exact when that many cover the radius).
    returns : (m,) int
    """
    nb = len(bud_pos)
    out = np.full(len(markers), -1, np.int64)
    if nb == 0 or len(markers) == 0:
        return out
    kk = min(neighbours, nb)
    dist, ind = cKDTree(bud_pos).query(markers, k=kk, distance_upper_bound=radius)
    if kk == 1:
        dist, ind = dist[:, None], ind[:, None]
    rows = np.flatnonzero(np.isfinite(dist[:, 0]))  # markers with at least one bud in range
    dist, ind = dist[rows], ind[rows]
    valid = np.isfinite(dist) & (dist > 1e-12)
    safe = np.where(valid, ind, 0)
    vec = markers[rows, None, :] - bud_pos[safe]
    cosang = (vec * bud_dir[safe]).sum(axis=2) / np.where(valid, dist, 1.0)
    ok = valid & (cosang >= cos_half_angle)
    first = np.argmax(ok, axis=1)
    has = ok[np.arange(len(rows)), first]
    out[rows[has]] = safe[has, first[has]]
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
    unitv = _unit(markers[mi] - bud_pos[bi])
    q = (np.bincount(bi, minlength=nb) > 0).astype(np.float64)
    vdir = np.zeros((nb, 3))
    for c in range(3):
        vdir[:, c] = np.bincount(bi, weights=unitv[:, c], minlength=nb)
    return q, _unit(vdir)


class _Tree:
    """Growable node arrays."""

    def __init__(self, cap: int = 4096) -> None:
        self.n = 0
        self.pos = np.zeros((cap, 3))
        self.head = np.zeros((cap, 3))
        self.ref = np.zeros((cap, 3))
        self.lat_dir = np.zeros((cap, 3))
        self.parent = np.full(cap, -1, np.int64)
        self.main_child = np.full(cap, -1, np.int64)
        self.lat_child = np.full(cap, -1, np.int64)
        self.order = np.zeros(cap, np.int64)
        self.depth = np.zeros(cap, np.int64)
        self.lateral = np.zeros(cap, bool)
        self.lat_viable = np.zeros(cap, bool)
        self.alive = np.zeros(cap, bool)
        self.starve = np.zeros(cap, np.int64)

    def _grow(self, need: int) -> None:
        cap = len(self.parent)
        if need <= cap:
            return
        new = max(need, 2 * cap)
        for name in ("pos", "head", "ref", "lat_dir", "parent", "main_child", "lat_child", "order", "depth",
                     "lateral", "lat_viable", "alive", "starve"):
            old = getattr(self, name)
            fill = -1 if name in ("parent", "main_child", "lat_child") else 0
            arr = np.full((new,) + old.shape[1:], fill, old.dtype)
            arr[:cap] = old
            setattr(self, name, arr)

    def add(self, pos, head, ref, lat_dir, parent, order, depth, lateral, lat_viable) -> np.ndarray:
        k = len(pos)
        self._grow(self.n + k)
        idx = np.arange(self.n, self.n + k)
        self.pos[idx] = pos
        self.head[idx] = head
        self.ref[idx] = ref
        self.lat_dir[idx] = lat_dir
        self.parent[idx] = parent
        self.order[idx] = order
        self.depth[idx] = depth
        self.lateral[idx] = lateral
        self.lat_viable[idx] = lat_viable
        self.alive[idx] = True
        self.n += k
        return idx


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
    """
    p = params
    ell = p.internode_length
    r_occ = p.occupancy_radius * ell
    r_per = p.perception_radius * ell
    cos_half = np.cos(np.radians(p.perception_angle) / 2)
    psi = np.radians(p.branching_angle)
    phi = np.radians(p.roll_angle)
    up = np.array([0.0, 0.0, 1.0])
    lam = p.apical_control
    max_turn = np.radians(p.max_turn)

    tree = _Tree()
    k = len(root_positions)
    rdir = _unit(np.asarray(root_directions, dtype=np.float64))
    tree.add(np.asarray(root_positions, dtype=np.float64), rdir, _perpendicular(rdir), rdir, -1,
             np.zeros(k, np.int64), np.zeros(k, np.int64), np.zeros(k, bool), np.zeros(k, bool))
    markers = np.asarray(markers, dtype=np.float64)
    killed_upto = 0
    shoots = 0
    metamers = 0
    it = 0
    for cycle in range(1, p.max_iterations + 1):
        it = cycle
        n = tree.n
        # 1. occupancy: markers near the nodes added since the last cycle die
        if n > killed_upto and len(markers):
            d, _ = cKDTree(tree.pos[killed_upto:n]).query(markers, distance_upper_bound=r_occ)
            markers = markers[~np.isfinite(d)]
            killed_upto = n
        alive = tree.alive[:n]
        api = np.flatnonzero(alive & (tree.main_child[:n] < 0))
        lat = np.flatnonzero(alive & (tree.lat_child[:n] < 0) & tree.lat_viable[:n])
        bud_node = np.concatenate([api, lat])
        bud_dir = np.concatenate([tree.head[api], tree.lat_dir[lat]])
        bud_pos = tree.pos[bud_node]
        nb = len(bud_node)
        # 2. perception: each marker to the closest bud whose cone holds it
        q = np.zeros(nb)
        vdir = np.zeros((nb, 3))
        if len(markers) and nb:
            q, vdir = perceive(markers, bud_pos, bud_dir, radius=r_per, cos_half_angle=cos_half, neighbours=p.neighbours)
        # clear bole: stems below the crown grow straight on with light
        is_api = np.arange(nb) < len(api)
        bole = is_api & (tree.order[bud_node] == 0) & (bud_pos[:, 2] < p.bole_height) & (q == 0)
        q[bole] = 1.0
        vdir[bole] = bud_dir[bole]
        if not q.any():
            break
        # 3. Borchert-Honda allocation over the levels of the tree
        qa = np.zeros(n + 1)
        ql = np.zeros(n + 1)
        qa[bud_node[is_api]] = q[is_api]
        ql[bud_node[~is_api]] = q[~is_api]
        order_by_depth = np.argsort(tree.depth[:n], kind="stable")
        depths = tree.depth[:n][order_by_depth]
        bounds = np.flatnonzero(np.diff(depths)) + 1
        levels = np.split(order_by_depth, bounds)
        mc = np.where(tree.main_child[:n] >= 0, tree.main_child[:n], n)
        lc = np.where(tree.lat_child[:n] >= 0, tree.lat_child[:n], n)
        s = np.zeros(n + 1)
        sm = np.zeros(n + 1)
        sl = np.zeros(n + 1)
        cnt = np.zeros(n + 1, np.int64)
        al = np.append(alive, False)
        for idx in reversed(levels):
            sm[idx] = qa[idx] + s[mc[idx]]
            sl[idx] = ql[idx] + s[lc[idx]]
            s[idx] = np.where(al[idx], sm[idx] + sl[idx], 0.0)
            cnt[idx] = al[idx] + cnt[mc[idx]] + cnt[lc[idx]]
        # shedding bookkeeping for lateral branches
        latroots = np.flatnonzero(alive & tree.lateral[:n])
        dark = s[latroots] == 0
        tree.starve[latroots] = np.where(dark, tree.starve[latroots] + 1, 0)
        shed = np.zeros(n + 1, bool)
        shed[latroots] = dark & (tree.starve[latroots] >= p.shed_age) & (cnt[latroots] <= p.shed_max_internodes)
        vin = np.zeros(n + 1)
        va = np.zeros(n + 1)
        vl = np.zeros(n + 1)
        roots = np.flatnonzero(tree.parent[:n] < 0)
        vin[roots] = p.vigour * s[roots]
        for idx in levels:
            par = tree.parent[idx]
            shed[idx] |= np.where(par >= 0, shed[np.maximum(par, 0)], False)
            v = vin[idx]
            den = lam * sm[idx] + (1 - lam) * sl[idx]
            den = np.where(den > 0, den, 1.0)
            vm = v * lam * sm[idx] / den
            vlat = v * (1 - lam) * sl[idx] / den
            vin[mc[idx]] = vm
            vin[lc[idx]] = vlat
            va[idx] = vm
            vl[idx] = vlat
        vin[n] = 0.0
        dead = np.flatnonzero(shed[:n] & alive)
        tree.alive[dead] = False
        # 4. shoots
        vig = np.where(is_api, va[bud_node], vl[bud_node])
        nmet = np.minimum(np.floor(vig + 1e-9), p.max_shoot).astype(np.int64)
        nmet[~tree.alive[bud_node]] = 0
        nmet[q == 0] = 0
        # bud fate: a lit lateral bud with vigour breaks this cycle with probability bud_break, else stays dormant
        nmet[~is_api & (rng.random(nb) >= p.bud_break)] = 0
        grow = np.flatnonzero(nmet > 0)
        if len(grow) == 0:
            break
        shoots += len(grow)
        metamers += int(nmet[grow].sum())
        g_node = bud_node[grow]
        g_lat = ~is_api[grow]
        g_n = nmet[grow]
        g_v = vdir[grow]
        # the heading and roll reference each shoot starts from
        head = np.where(g_lat[:, None], tree.lat_dir[g_node], tree.head[g_node])
        ref_lat = np.cross(head, tree.head[g_node])
        bad = np.linalg.norm(ref_lat, axis=1) < 1e-9
        ref_lat[bad] = _perpendicular(head[bad])
        ref = np.where(g_lat[:, None], _unit(ref_lat), tree.ref[g_node])
        prev = g_node.copy()
        order = tree.order[g_node] + g_lat
        depth = tree.depth[g_node]
        for step in range(int(g_n.max())):
            act = np.flatnonzero(g_n > step)
            h = head[act] + p.direction_weight * g_v[act] + p.tropism * up
            h = h + p.noise * rng.normal(size=(len(act), 3))
            h = _limit_turn(head[act], _unit(h), max_turn)
            # the roll reference follows the heading, then rolls by phi
            r0 = ref[act] - np.sum(ref[act] * h, 1, keepdims=True) * h
            bad = np.linalg.norm(r0, axis=1) < 1e-9
            r0[bad] = _perpendicular(h[bad])
            r0 = _rotate(_unit(r0), h, phi)
            ldir = _unit(np.cos(psi) * h + np.sin(psi) * r0)
            pos = tree.pos[prev[act]] + ell * h
            viable = np.ones(len(act), bool)
            first = step == 0
            is_lat_node = g_lat[act] & first
            new = tree.add(pos, h, r0, ldir, prev[act], order[act], depth[act] + step + 1, is_lat_node, viable)
            if first:
                lat_first = g_lat[act]
                tree.lat_child[prev[act][lat_first]] = new[lat_first]
                tree.main_child[prev[act][~lat_first]] = new[~lat_first]
            else:
                tree.main_child[prev[act]] = new
            prev[act] = new
            head[act] = h
            ref[act] = r0
    n = tree.n
    keep = np.flatnonzero(tree.alive[:n])
    remap = np.full(n, -1, np.int64)
    remap[keep] = np.arange(len(keep))
    par = tree.parent[keep]
    parents = np.where(par >= 0, remap[np.maximum(par, 0)], -1)
    return GrowthResult(
        positions=tree.pos[keep].copy(),
        parents=parents,
        lateral=tree.lateral[keep].copy(),
        order=tree.order[keep].copy(),
        headings=tree.head[keep].copy(),
        iterations=it,
        growth_units=metamers / shoots if shoots else 0.0,
        markers_left=len(markers),
    )
