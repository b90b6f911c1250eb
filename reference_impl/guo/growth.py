"""Point-cloud-guided growth (Guo et al. 2018, section 5.2, L-system 1; Guo et al. 2017, section 2.2).

L-system 1: a seed at each root becomes the apical bud A(p, v) of a stem, heading up. In a growth cycle a bud with
markers in its perception volume emits a shoot, a chain of n metamers: metamer i starts where metamer i - 1 ends
(p'_i = p'_{i-1} + v l), keeps the shoot's direction and rolls the phyllotaxy by phi (v'_i = R_phi(v'_{i-1}) turns
the lateral bud, not the main direction); each metamer ends in a lateral bud L at the branching angle psi
(v' = R_psi(v)); the apical bud closes the chain. A lateral bud becomes the apical bud of a new axis from the next
cycle on.

Space colonisation (Palubicki et al. 2009, with Guo et al. 2018's three adaptations):

- markers are the cloud's points (merged per half-internode voxel, see :class:`~reference_impl.guo.params.GuoParams`)
  plus, for an occluded crown, Poisson-disk samples of its convex hull; every marker carries its Eq. 8 weight;
- each bud has a perception cone (opening theta = 90 deg, radius d_i) and an occupancy sphere (kill distance
  d_k = 0.5 d_i); a marker inside several cones goes to the closest bud (roots compete for the same markers);
- d_i = rho_t l (Guo et al. 2018) or floor(rho_t) l (Guo et al. 2017) from the logistic model:
  H_t = H_max / (1 + (H_max / H_0 - 1) exp(-rho_0 t)) (Eq. 6) in internodes, H_max = K (K l = the plant's height),
  rho_t = dH_t/dt (Eq. 7), clamped to [rho_min, rho_max] (the defaults clamp it to 4: d_i = 4 l on every plant, the
  bottom of the range Guo et al. quote, because a wider cone aims shoots between neighbouring limbs;
  :class:`~reference_impl.guo.params.GuoParams`, docs/tuning/guo.md);
- growth direction Eq. 9: V_A = V_default + alpha V_opt + beta V_tropism, V_opt the weighted mean of the unit
  vectors from the bud to its markers (weights w_i of Eq. 8);
- the shoot has rho_t metamers (the growth units, Table 1), but stops at the weighted centroid of its markers (the
  growing distance of space colonisation, section 5.2), and at least one;
- bud fate (Palubicki's Borchert-Honda allocation, which Guo et al. 2018 inherit with the space colonisation): the
  resource alpha x (lit buds) is shared in proportion to each lit bud's perceived marker weight, and a lateral bud
  whose share is below one metamer stays dormant (``lateral_vigour``);
- gaps (our addition, for clouds with unreconstructed parts): when no bud perceives a marker while markers remain,
  the perception radius of that cycle doubles (at most ``max_widen`` times, up to the plant's size) until one does,
  and the shoot may then be as long as that radius, so a stem crosses an empty stretch of the cloud instead of
  stopping there.

Refinement on the fly (section 5.3, Fig. 12): after every cycle the radii follow Eq. 5 from the measured trunk
radius; a lateral branch thinner than the species' twig radius that has stopped growing for ``shed_age`` cycles
violates the allometric rule and is shed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from plantbench.geometry.nodes import GrowableNodes
from plantbench.geometry.perception import assign_markers as nearest_cone
from plantbench.geometry.vectors import levels_of, perpendicular, rotate, unit
from reference_impl.common.graph import subtree_sums
from reference_impl.guo.params import GuoParams, SpeciesPrior

__all__ = ["logistic_height", "growth_units", "influence_distance", "allometric_radii", "assign_markers",
           "growing_buds", "GrowthOutput", "grow"]


def logistic_height(t: float | np.ndarray, h_max: float, h0: float, rho0: float) -> np.ndarray:
    """Eq. 6: H_t = H_max / (1 + (H_max / H_0 - 1) exp(-rho_0 t))."""
    a = h_max / h0 - 1.0
    return h_max / (1.0 + a * np.exp(-rho0 * np.asarray(t, float)))


def growth_units(t: float | np.ndarray, h_max: float, h0: float, rho0: float) -> np.ndarray:
    """Eq. 7: rho_t = dH_t/dt = H_max rho_0 (H_max/H_0 - 1) e^(-rho_0 t) / (1 + (H_max/H_0 - 1) e^(-rho_0 t))^2."""
    a = h_max / h0 - 1.0
    e = np.exp(-rho0 * np.asarray(t, float))
    return h_max * rho0 * a * e / (1.0 + a * e) ** 2


def influence_distance(t: int, k_internodes: float, ell: float, params: GuoParams) -> tuple[float, float]:
    """(rho used, d_i) at cycle t: rho_t of Eq. 7 (its integer part with ``integer_rho``, Guo et al. 2017), clamped to
    [rho_min, rho_max]; d_i = rho l."""
    k = max(float(k_internodes), params.h0 + 1.0)
    rho = float(growth_units(t, k, params.h0, params.rho0))
    if params.integer_rho:
        rho = float(np.floor(rho))
    rho = float(np.clip(rho, params.rho_min, params.rho_max))
    return rho, rho * ell


def allometric_radii(positions: np.ndarray, parents: np.ndarray, root_radius: np.ndarray, gamma: float, *,
                     levels: list[np.ndarray], alive: np.ndarray | None = None) -> np.ndarray:
    """Eq. 5 applied root to tip: d_c = d_p (l_c / sum_j l_j)^gamma, l the branch length a node supports.

    The sum runs over the parent's children and the parent's own internode, so the ratios telescope and every node
    gets r = r_root (l / l_root)^gamma (the generator's taper along chains; at a junction this is Eq. 5 up to the
    one internode). root_radius : (n_roots,) in the order of the roots in ``parents``. Dead nodes (``alive``
    False) support nothing. Returns (n,) radii (not clamped).
    """
    n = len(parents)
    has = parents >= 0
    inc = np.zeros(n)
    inc[has] = np.linalg.norm(positions[has] - positions[parents[has]], axis=1)
    if alive is not None:
        inc = np.where(alive, inc, 0.0)
    sup = subtree_sums(inc, parents, levels)
    root_of = np.arange(n)
    for idx in levels:
        c = idx[parents[idx] >= 0]
        root_of[c] = root_of[parents[c]]
    roots = np.flatnonzero(parents < 0)
    rr = np.zeros(n)
    rr[roots] = root_radius
    tot = np.maximum(sup[root_of], 1e-12)
    return rr[root_of] * (np.maximum(sup, 0.0) / tot) ** gamma


def assign_markers(markers: np.ndarray, bud_pos: np.ndarray, bud_dir: np.ndarray, apical: np.ndarray, *,
                   radius: float, cos_half_angle: float, neighbours: int = 8) -> np.ndarray:
    """(m,) index of the bud each marker feeds, -1 for none: the closest bud within ``radius`` whose perception
    cone holds the marker; between buds at the same distance (the apical and the lateral bud of one node share
    its position) the apical bud wins (apical dominance) [S: Palubicki's rule leaves ties open].

    markers : (m, 3); bud_pos : (b, 3); bud_dir : (b, 3) unit cone axes; apical : (b,) bool. Only the
    ``neighbours`` closest buds of each marker are examined (:func:`plantbench.geometry.perception.assign_markers`,
    a lateral bud's distance lengthened by 1e-9 radius).
    """
    penalty = np.where(np.asarray(apical, bool), 0.0, 1e-9 * radius)
    return nearest_cone(markers, bud_pos, bud_dir, radius=radius, cos_half_angle=cos_half_angle,
                        neighbours=neighbours, penalty=penalty)


def growing_buds(q: np.ndarray, apical: np.ndarray, *, alpha: float, min_share: float) -> np.ndarray:
    """(b,) bool: the buds that grow this cycle (Borchert-Honda bud fate with lambda = 0.5).

    q : (b,) perceived marker weight of each bud (0: no marker, the bud is not lit); apical : (b,) bool.
    The resource ``alpha`` x (number of lit buds) is shared among the lit buds in proportion to q, so a bud's share
    is alpha q / mean(q over lit buds) metamers; a lit apical bud grows, a lit lateral bud grows when its share is
    at least ``min_share`` (0: every lit bud grows).
    """
    q = np.asarray(q, float)
    lit = q > 0
    if min_share <= 0 or not lit.any():
        return lit
    share = alpha * q / q[lit].mean()
    return lit & (np.asarray(apical, bool) | (share >= min_share))


@dataclass(frozen=True)
class GrowthOutput:
    """The grown skeleton (alive nodes only; parents precede children)."""

    positions: np.ndarray
    """(n, 3) float."""
    parents: np.ndarray
    """(n,) int, -1 at the roots."""
    lateral: np.ndarray
    """(n,) bool: first node of a lateral shoot."""
    radii: np.ndarray
    """(n,) float: Eq. 5 radii at the end of growth (clamped at half the twig radius)."""
    iterations: int
    shed_nodes: int
    markers_left: int
    history: list[dict]
    """Per cycle: t, rho, d_i, markers, buds with markers, new nodes, shed nodes."""


class _Nodes(GrowableNodes):
    """The growing skeleton's node arrays."""

    def __init__(self) -> None:
        super().__init__({
            "pos": ((3,), np.float64, 0.0), "head": ((3,), np.float64, 0.0), "ref": ((3,), np.float64, 0.0),
            "latdir": ((3,), np.float64, 0.0), "parent": ((), np.int64, -1), "has_main": ((), bool, False),
            "has_lat": ((), bool, False), "lateral": ((), bool, False), "birth": ((), np.int64, 0),
            "depth": ((), np.int64, 0), "alive": ((), bool, False), "lat_ok": ((), bool, False),
        })

    def alive_tree(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The alive nodes renumbered in order (parents still precede children): positions, parents, lateral flags
        and depths."""
        keep, parents = self.alive_rows()
        return self.pos[keep], parents, self.lateral[keep], self.depth[keep]


@dataclass(frozen=True)
class _Rules:
    """Constants of one growth run, from the species prior, the parameters and the plant's size."""

    ell: float
    """Internode length l, metres."""
    k_internodes: float
    """K: the plant's height in internodes (H_max of Eq. 6)."""
    psi: float
    """Branching angle, radians."""
    phi: float
    """Roll angle (phyllotaxy), radians."""
    cos_half: float
    """Cosine of half the perception cone's opening theta."""
    tropism: np.ndarray
    """(3,) V_tropism of Eq. 9."""
    widen_limit: float
    """Largest perception radius of a cycle that widens it (the plant's size), metres."""

    @classmethod
    def of(cls, markers: np.ndarray, height: float, prior: SpeciesPrior, params: GuoParams) -> _Rules:
        widen_limit = max(float(height), float(np.ptp(markers, axis=0).max()) if len(markers) else 0.0)
        return cls(ell=prior.internode_length, k_internodes=height / prior.internode_length,
                   psi=np.radians(prior.branching_angle), phi=np.radians(prior.roll_angle),
                   cos_half=float(np.cos(np.radians(params.perception_angle) / 2)),
                   tropism=np.asarray(params.tropism, float), widen_limit=widen_limit)


def _seed(root_positions: np.ndarray) -> _Nodes:
    """L-system 1's axiom: a node at each root whose apical bud heads up (roll reference across Z)."""
    k = len(root_positions)
    up = np.tile([0.0, 0.0, 1.0], (k, 1))
    nodes = _Nodes()
    nodes.add(pos=np.asarray(root_positions, float), head=up, ref=perpendicular(up), latdir=up, parent=np.full(k, -1),
              has_main=np.zeros(k, bool), has_lat=np.zeros(k, bool), lateral=np.zeros(k, bool),
              birth=np.zeros(k, np.int64), depth=np.zeros(k, np.int64), lat_ok=np.zeros(k, bool))
    return nodes


def _occupy(markers: np.ndarray, weights: np.ndarray, nodes: _Nodes, radii: np.ndarray, d_k: float,
            branch_radius: bool) -> tuple[np.ndarray, np.ndarray]:
    """Occupancy: the markers (and their weights) left after removing those within the kill distance ``d_k`` of an
    alive node, plus the node's radius (``radii``, per node) with ``branch_radius``."""
    if len(markers) == 0:
        return markers, weights
    alive_idx = np.flatnonzero(nodes.alive[: nodes.n])
    extra = radii[alive_idx] if branch_radius else np.zeros(len(alive_idx))
    kk = min(4, len(alive_idx))
    dist, j = cKDTree(nodes.pos[alive_idx]).query(markers, k=kk, distance_upper_bound=d_k + float(extra.max()))
    if kk == 1:
        dist, j = dist[:, None], j[:, None]
    ok = np.isfinite(dist)
    reach = d_k + extra[np.where(ok, j, 0)]
    dead = np.any(ok & (dist < reach), axis=1)
    return markers[~dead], weights[~dead]


def _buds(nodes: _Nodes, t: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The buds of cycle ``t``: the apical buds, then the lateral buds of the nodes made in earlier cycles. Returns
    each bud's node, whether it is apical and its direction."""
    n = nodes.n
    alive = nodes.alive[:n]
    api = np.flatnonzero(alive & ~nodes.has_main[:n])
    lat = np.flatnonzero(alive & ~nodes.has_lat[:n] & nodes.lat_ok[:n] & (nodes.birth[:n] < t))
    bud_node = np.concatenate([api, lat])
    is_api = np.arange(len(bud_node)) < len(api)
    return bud_node, is_api, np.concatenate([nodes.head[api], nodes.latdir[lat]])


def _perceive(markers: np.ndarray, bud_pos: np.ndarray, bud_dir: np.ndarray, is_api: np.ndarray, d_i: float,
              rules: _Rules, params: GuoParams) -> tuple[np.ndarray, float]:
    """Each marker's bud (:func:`assign_markers`, -1 for none) and the perception radius used: ``d_i``, doubled while
    no bud perceives a marker (a gap in the cloud: occluded or unreconstructed parts), at most ``max_widen`` times
    and up to the plant's size."""
    d_use = d_i
    for _ in range(params.max_widen + 1):
        owner = assign_markers(markers, bud_pos, bud_dir, is_api, radius=d_use, cos_half_angle=rules.cos_half,
                               neighbours=params.neighbours)
        if np.any(owner >= 0) or d_use >= rules.widen_limit:
            break
        d_use = min(2.0 * d_use, rules.widen_limit)
    return owner, d_use


def _shoots(markers: np.ndarray, weights: np.ndarray, owner: np.ndarray, bud_pos: np.ndarray, bud_dir: np.ndarray,
            is_api: np.ndarray, rho: float, d_use: float, rules: _Rules, params: GuoParams
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bud fate and Eq. 9 for buds fed by ``markers`` (``owner``: each marker's bud, weights Eq. 8).

    Returns the growing buds (:func:`growing_buds`), their shoots' unit directions and their numbers of metamers:
    rho_t (or enough to cross the widened radius ``d_use``), but no farther than the weighted centroid of the bud's
    markers, and at least one.
    """
    nb = len(bud_pos)
    vec = markers - bud_pos[owner]
    u = unit(vec)
    wsum = np.bincount(owner, weights=weights, minlength=nb)
    vopt = np.stack([np.bincount(owner, weights=weights * u[:, c], minlength=nb) for c in range(3)], 1)
    cen = np.stack([np.bincount(owner, weights=weights * vec[:, c], minlength=nb) for c in range(3)], 1)
    lit = np.flatnonzero(growing_buds(wsum, is_api, alpha=params.bh_alpha, min_share=params.lateral_vigour))
    vopt = vopt[lit] / wsum[lit, None]
    reach = np.linalg.norm(cen[lit] / wsum[lit, None], axis=1)
    v = unit(bud_dir[lit] + params.alpha * vopt + params.beta * rules.tropism)
    nmet = np.minimum(np.round(max(rho, d_use / rules.ell)), np.round(reach / rules.ell))
    return lit, v, np.clip(nmet, 1, None).astype(np.int64)


def _extend(nodes: _Nodes, bud_node: np.ndarray, lateral: np.ndarray, v: np.ndarray, nmet: np.ndarray, t: int,
            rules: _Rules) -> None:
    """L-system 1's production: from each growing bud (its node, ``lateral`` for a lateral bud) a shoot of ``nmet``
    metamers along ``v``, one internode each, the lateral bud of each rolled by phi about the shoot and set at the
    branching angle psi."""
    # roll reference of each shoot: an axis continues its own, a new lateral axis starts across its parent
    ref = np.where(lateral[:, None], np.cross(v, nodes.head[bud_node]), nodes.ref[bud_node])
    prev = bud_node.copy()
    depth = nodes.depth[bud_node]
    for step in range(int(nmet.max())):
        act = np.flatnonzero(nmet > step)
        h = v[act]
        r0 = ref[act] - np.sum(ref[act] * h, 1, keepdims=True) * h
        bad = np.linalg.norm(r0, axis=1) < 1e-9
        r0[bad] = perpendicular(h[bad])
        r0 = rotate(unit(r0), h, rules.phi)
        ldir = unit(np.cos(rules.psi) * h + np.sin(rules.psi) * r0)
        first = step == 0
        new = nodes.add(pos=nodes.pos[prev[act]] + rules.ell * h, head=h, ref=r0, latdir=ldir, parent=prev[act],
                        has_main=False, has_lat=False, lateral=lateral[act] & first,
                        birth=np.full(len(act), t, np.int64), depth=depth[act] + step + 1, lat_ok=True)
        if first:
            nodes.has_lat[prev[act][lateral[act]]] = True
            nodes.has_main[prev[act][~lateral[act]]] = True
        else:
            nodes.has_main[prev[act]] = True
        prev[act] = new
        ref[act] = r0


def _shed(nodes: _Nodes, radii: np.ndarray, levels: list[np.ndarray], t: int, shed_radius: float,
          shed_age: int) -> int:
    """Shed (mark dead) the lateral branches thinner than ``shed_radius`` at their base whose subtree has not grown
    for ``shed_age`` cycles; returns the number of nodes shed. A shed lateral's bud is spent: the parent does not
    regrow it."""
    n = nodes.n
    par = nodes.parent[:n]
    alive = nodes.alive[:n]
    newest = nodes.birth[:n].astype(np.int64).copy()  # the latest birth cycle in each node's subtree
    newest[~alive] = -1
    for idx in reversed(levels):
        c = idx[par[idx] >= 0]
        np.maximum.at(newest, par[c], newest[c])
    cut = alive & nodes.lateral[:n] & (radii < shed_radius) & (newest <= t - shed_age)
    if not cut.any():
        return 0
    gone = cut.copy()
    for idx in levels:
        c = idx[par[idx] >= 0]
        gone[c] |= gone[par[c]]
    gone &= alive
    nodes.alive[:n] &= ~gone
    return int(gone.sum())


def grow(markers: np.ndarray, weights: np.ndarray, root_positions: np.ndarray, root_axes: np.ndarray,
         root_radii: np.ndarray, height: float, prior: SpeciesPrior, params: GuoParams) -> GrowthOutput:
    """Grow one stem per root towards the markers.

    markers : (m, 3) float; weights : (m,) float > 0 (Eq. 8); root_positions, root_axes : (k, 3) (the axes are not
    used: every seed heads up, as in L-system 1); root_radii : (k,) trunk radii (Eq. 5 anchor); height : plant height
    (H_max = K l), metres.

    Each cycle t: d_i from Eq. 6-7 (:func:`influence_distance`); occupancy removes the markers within d_k of the
    nodes; every bud perceives its markers (the radius widened across gaps); the buds that bud fate lets grow emit
    their shoots (Eq. 9); then the radii follow Eq. 5 and thin branches that stopped growing are shed. Growth stops
    when no marker or no bud is left, when no bud perceives a marker or bud fate lets none grow, before the skeleton
    exceeds ``max_nodes`` or after ``max_iterations`` cycles.
    """
    rules = _Rules.of(markers, height, prior, params)
    shed_radius = params.shed_radius * prior.tip_radius
    nodes = _seed(root_positions)
    mk = np.asarray(markers, float)
    mw = np.asarray(weights, float)
    history: list[dict] = []
    shed_total = 0
    radii = np.asarray(root_radii, float).copy()
    t = 0
    for t in range(params.max_iterations):
        rho, d_i = influence_distance(t, rules.k_internodes, rules.ell, params)
        mk, mw = _occupy(mk, mw, nodes, radii, params.kill_factor * d_i, params.occupy_branch_radius)
        bud_node, is_api, bud_dir = _buds(nodes, t)
        entry = {"t": t, "rho": rho, "d_i": d_i, "markers": len(mk), "buds": len(bud_node)}
        if len(mk) == 0 or len(bud_node) == 0:
            history.append(entry | {"lit": 0, "new": 0, "shed": 0})
            break
        bud_pos = nodes.pos[bud_node]
        owner, d_use = _perceive(mk, bud_pos, bud_dir, is_api, d_i, rules, params)
        entry["d_used"] = d_use
        fed = np.flatnonzero(owner >= 0)
        if len(fed) == 0:
            history.append(entry | {"lit": 0, "new": 0, "shed": 0})
            break
        lit, v, nmet = _shoots(mk[fed], mw[fed], owner[fed], bud_pos, bud_dir, is_api, rho, d_use, rules, params)
        if len(lit) == 0:  # only lateral buds are lit, none with a share of a metamer (lateral_vigour > bh_alpha)
            history.append(entry | {"lit": 0, "new": 0, "shed": 0, "stopped": "no bud grows"})
            break
        if nodes.n + int(nmet.sum()) > params.max_nodes:
            history.append(entry | {"lit": len(lit), "new": 0, "shed": 0, "stopped": "max_nodes"})
            break
        _extend(nodes, bud_node[lit], ~is_api[lit], v, nmet, t, rules)
        # refinement on the fly: Eq. 5 radii, shedding of thin branches that stopped growing
        n = nodes.n
        levels = levels_of(nodes.depth[:n])
        radii = allometric_radii(nodes.pos[:n], nodes.parent[:n], root_radii, prior.diameter_coefficient,
                                 levels=levels, alive=nodes.alive[:n])
        shed = _shed(nodes, radii, levels, t, shed_radius, params.shed_age) if params.shed else 0
        shed_total += shed
        history.append(entry | {"lit": len(lit), "new": int(nmet.sum()), "shed": shed})
        radii = np.maximum(radii, 0.0)
    pos, parents, lateral, depth = nodes.alive_tree()
    rad = allometric_radii(pos, parents, root_radii, prior.diameter_coefficient, levels=levels_of(depth))
    return GrowthOutput(pos, parents, lateral, np.maximum(rad, 0.5 * prior.tip_radius), t + 1, shed_total, len(mk),
                        history)
