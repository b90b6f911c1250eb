"""Tree traits as a forester reads them: DBH, height, trunk and total volume, total and per-order branch length,
branch count; needs no ground truth.

Two sources give the same keys:

- :func:`skeleton_traits`, from a skeleton's nodes: volumes as truncated cones between the node radii;
- :func:`cylinder_traits`, from a cylinder table (columns :data:`plantbench.io.qsm.COLUMNS`: a method's QSM export,
  :func:`plantbench.io.qsm.skeleton_to_cylinders`, or a reference QSM, :mod:`plantbench.io.references`): volumes as
  cylinders, pi r^2 L.

Definitions, the same for both:

- *axes and orders*: an axis starts at a root (order 0) or where an edge (cylinder) leaves its parent other than as
  its continuation, and continues through each node's thickest child (a cylinder table's ``extension``); a lateral
  axis has its parent axis's order + 1. The stem is order 0 (a shrub has several);
- ``dbh_cm``: twice the radius where the thickest order-0 edge crossing ``breast_height`` above the model's lowest
  point is cut (a skeleton: the radius interpolated there; a cylinder: its radius), in cm; None when no stem reaches
  breast height. The reference QSMs' DBH is measured the same way (rtwig's reference.csv);
- ``height_m``: max z - min z of the model;
- ``trunk_volume_l``, ``total_volume_l``: the order-0 and all edges' volumes, litres;
- ``total_length_m`` and ``length_order0_m``, ``length_order1_m``, ``length_order2_m``, ``length_order3plus_m``;
- ``branch_count``: the number of lateral axes (order >= 1), TreeQSM's count of branches. Tools segment axes
  differently, so the count is comparable between methods scored here, not with another tool's number.

An empty model (no edge) has no traits: every value None.
"""

from __future__ import annotations

import numpy as np

from plantbench.plant import Skeleton

__all__ = ["TRAITS", "skeleton_traits", "cylinder_traits", "axis_orders"]

TRAITS = ("dbh_cm", "height_m", "trunk_volume_l", "total_volume_l", "total_length_m", "length_order0_m",
          "length_order1_m", "length_order2_m", "length_order3plus_m", "branch_count")
"""The keys of :func:`skeleton_traits` and :func:`cylinder_traits`."""


def axis_orders(parent: np.ndarray, extension: np.ndarray) -> np.ndarray:
    """Order of each edge (cylinder) of a forest given as ``parent`` (-1 for a first edge) and ``extension`` (the
    child continuing the same axis, -1 at a tip): 0 from a root, the parent's where it continues the parent's axis,
    the parent's + 1 where it leaves as a lateral."""
    n = len(parent)
    order = np.zeros(n, np.int64)
    kids: list[list[int]] = [[] for _ in range(n)]
    for i, p in enumerate(parent.tolist()):
        if p >= 0:
            kids[p].append(i)
    todo = [i for i in range(n) if parent[i] < 0]
    while todo:
        i = todo.pop()
        for k in kids[i]:
            order[k] = order[i] if extension[i] == k else order[i] + 1
            todo.append(k)
    return order


def _traits(z0: float, z1: float, lengths: np.ndarray, volumes: np.ndarray, order: np.ndarray, first: np.ndarray,
            dbh_m: float | None) -> dict[str, float | None]:
    if not len(lengths):
        return dict.fromkeys(TRAITS)
    return {
        "dbh_cm": None if dbh_m is None else 100.0 * dbh_m,
        "height_m": float(z1 - z0),
        "trunk_volume_l": 1000.0 * float(volumes[order == 0].sum()),
        "total_volume_l": 1000.0 * float(volumes.sum()),
        "total_length_m": float(lengths.sum()),
        "length_order0_m": float(lengths[order == 0].sum()),
        "length_order1_m": float(lengths[order == 1].sum()),
        "length_order2_m": float(lengths[order == 2].sum()),
        "length_order3plus_m": float(lengths[order >= 3].sum()),
        "branch_count": float(np.count_nonzero(first & (order >= 1))),
    }


def cylinder_traits(table, *, breast_height: float = 1.3) -> dict[str, float | None]:
    """Traits of a cylinder table (a pandas DataFrame with the columns of :data:`plantbench.io.qsm.COLUMNS`): see
    the module."""
    start = table[["start_x", "start_y", "start_z"]].to_numpy(float)
    axis = table[["axis_x", "axis_y", "axis_z"]].to_numpy(float)
    length = table["length"].to_numpy(float)
    radius = table["radius"].to_numpy(float)
    parent = table["parent"].to_numpy(np.int64)
    extension = table["extension"].to_numpy(np.int64)
    if not len(table):
        return dict.fromkeys(TRAITS)
    end = start + length[:, None] * axis
    order = axis_orders(parent, extension)
    z = np.concatenate([start[:, 2], end[:, 2]])
    z0 = float(z.min())
    lo, hi = np.minimum(start[:, 2], end[:, 2]), np.maximum(start[:, 2], end[:, 2])
    bh = z0 + breast_height
    cut = (order == 0) & (lo <= bh) & (hi >= bh) & (hi > lo)
    dbh = float(2 * radius[cut].max()) if cut.any() else None
    first = (parent < 0) | (extension[np.maximum(parent, 0)] != np.arange(len(parent)))
    return _traits(z0, float(z.max()), length, np.pi * radius**2 * length, order, first, dbh)


def skeleton_traits(skeleton: Skeleton, *, breast_height: float = 1.3) -> dict[str, float | None]:
    """Traits of a skeleton (see the module): one edge per non-root node, the thickest child (lowest index on ties)
    continuing its parent's axis; every edge from a root is a stem (order 0), as the QSM export makes it."""
    from plantbench.geometry.tubes import main_child_mask

    if len(skeleton) == 0 or not np.any(skeleton.parents >= 0):
        return dict.fromkeys(TRAITS)
    pos, rad, par = skeleton.positions, skeleton.radii, skeleton.parents
    child = np.flatnonzero(par >= 0)
    main = main_child_mask(par, rad)
    # edge order: the child node's axis order (0 for a root's continuation)
    node_order = np.zeros(len(skeleton), np.int64)
    from plantbench.skeletons import topological_order

    for v in topological_order(skeleton).tolist():
        p = par[v]
        if p >= 0:
            node_order[v] = 0 if par[p] < 0 else node_order[p] if main[v] else node_order[p] + 1
    a, b = pos[par[child]], pos[child]
    ra, rb = rad[par[child]], rad[child]
    length = np.linalg.norm(b - a, axis=1)
    volume = np.pi * length * (ra**2 + ra * rb + rb**2) / 3.0
    order = node_order[child]
    z0 = float(pos[:, 2].min())
    bh = z0 + breast_height
    za, zb = a[:, 2], b[:, 2]
    cut = (order == 0) & ((za - bh) * (zb - bh) <= 0) & (za != zb)
    dbh = None
    if cut.any():
        f = (bh - za[cut]) / (zb[cut] - za[cut])
        dbh = float(2 * (ra[cut] + f * (rb[cut] - ra[cut])).max())
    first = ~main[child]
    return _traits(z0, float(pos[:, 2].max()), length, volume, order, first, dbh)
