"""Quantitative structure models (QSM) as cylinder tables, the exchange format of TreeQSM and rTwig.

One row per cylinder, columns :data:`COLUMNS`:

- ``start_x, start_y, start_z``: the cylinder's base; ``axis_x, axis_y, axis_z``: unit axis; ``length``, ``radius``
  (metres);
- ``parent``: the cylinder ending where this one starts, -1 for a first cylinder; ``extension``: the child cylinder
  continuing the same branch, -1 at a tip;
- ``branch``: id of the branch (axis) the cylinder belongs to; ``branch_order``: 0 for the stem, +1 per lateral.

Indices here are 0-based with -1 for "none". TreeQSM and rTwig number cylinders from 1 with 0 for "none": a table
with no -1 in ``parent`` is read as 1-based (a 0-based table always has one, its first cylinder's).

From a :class:`~plantbench.plant.Skeleton` (:func:`skeleton_to_cylinders`): one cylinder per edge (parent node ->
child node), in breadth-first order (a parent cylinder precedes its children); radius = the mean of the two node
radii; extension = the child cylinder with the largest radius (ties: the lowest index); branch = the thickest-child
axis rule (a cylinder continues its parent's branch when it is the parent's extension, else starts a new branch;
ids in order of first appearance), so a branch is a whole axis from its base to a tip, as in TreeQSM, not a
Stava-style unbranched chain; branch_order = the skeleton's ``order`` at the cylinder's end node.

Back to a skeleton (:func:`cylinders_to_skeleton`): every cylinder gives its end node (radius and order: the
cylinder's). A cylinder's start merges with its parent's end when they coincide within :data:`MERGE_TOLERANCE`;
otherwise (a TreeQSM branch often starts on its parent's surface, mid-cylinder) it gets a node of its own,
attached to the nearer end of its parent cylinder. First cylinders with the same start share one root node whose
radius and order are those of its first cylinder. So a round trip keeps node positions and orders, and the node
radii become the mean of each edge's two node radii (the root: its first cylinder's): radius profiles are smoothed
by half an edge. A skeleton's isolated nodes (no edge) have no cylinder and are lost.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd

from plantbench.errors import InputError
from plantbench.io.atomic import atomic_write
from plantbench.plant import Skeleton
from plantbench.skeletons import children_lists, topological_order

__all__ = ["COLUMNS", "MERGE_TOLERANCE", "skeleton_to_cylinders", "cylinders_to_skeleton", "write_qsm_csv", "read_csv_table",
           "read_qsm_csv"]

COLUMNS = ("start_x", "start_y", "start_z", "axis_x", "axis_y", "axis_z", "length", "radius", "parent", "extension",
           "branch", "branch_order")

MERGE_TOLERANCE = 1e-6
"""Metres: a cylinder's start within this of its parent's end is the same skeleton node."""

_INDEX_COLUMNS = ("parent", "extension", "branch", "branch_order")


def skeleton_to_cylinders(skeleton: Skeleton) -> pd.DataFrame:
    """The cylinder table of ``skeleton``: one row per edge, columns :data:`COLUMNS` (see the module)."""
    topo = topological_order(skeleton)
    child_nodes = topo[skeleton.parents[topo] >= 0]  # one cylinder per non-root node, parents first
    if not len(child_nodes):
        raise InputError("the skeleton has no edge: nothing to write as cylinders")
    cyl_of = np.full(len(skeleton), -1, np.int64)  # the cylinder ending at each node
    cyl_of[child_nodes] = np.arange(len(child_nodes))
    par_nodes = skeleton.parents[child_nodes]
    p0, p1 = skeleton.positions[par_nodes], skeleton.positions[child_nodes]
    vec = p1 - p0
    length = np.linalg.norm(vec, axis=1)
    axis = np.where(length[:, None] > 0, vec / np.where(length > 0, length, 1.0)[:, None], [0.0, 0.0, 1.0])
    radius = 0.5 * (skeleton.radii[par_nodes] + skeleton.radii[child_nodes])
    parent = cyl_of[par_nodes]
    kids = children_lists(skeleton)
    extension = np.full(len(child_nodes), -1, np.int64)
    for i, node in enumerate(child_nodes):
        ks = cyl_of[kids[node]]
        if len(ks):
            extension[i] = ks[np.lexsort((ks, -radius[ks]))[0]]  # thickest, then lowest index
    branch = np.full(len(child_nodes), -1, np.int64)
    n_branches = 0
    for i in range(len(child_nodes)):  # parents precede children
        p = parent[i]
        if p >= 0 and extension[p] == i:
            branch[i] = branch[p]
        else:
            branch[i], n_branches = n_branches, n_branches + 1
    return pd.DataFrame({
        "start_x": p0[:, 0], "start_y": p0[:, 1], "start_z": p0[:, 2],
        "axis_x": axis[:, 0], "axis_y": axis[:, 1], "axis_z": axis[:, 2],
        "length": length, "radius": radius, "parent": parent, "extension": extension, "branch": branch,
        "branch_order": skeleton.order[child_nodes].astype(np.int64),
    }, columns=list(COLUMNS))


def _validated(df: pd.DataFrame) -> dict[str, np.ndarray]:
    """The columns as arrays, 0-based, checked: present, numeric, finite, lengths >= 0, radii > 0, indices in range."""
    missing = [c for c in COLUMNS if c not in df.columns]
    if missing:
        raise InputError(f"missing column(s) {', '.join(missing)} (a QSM table needs {', '.join(COLUMNS)})")
    if not len(df):
        raise InputError("no cylinders")
    cols = {}
    for c in COLUMNS:
        try:
            v = pd.to_numeric(df[c], errors="raise").to_numpy(np.float64)
        except (ValueError, TypeError):
            raise InputError(f"column {c}: not numeric") from None
        if not np.all(np.isfinite(v)):
            raise InputError(f"column {c}: {int((~np.isfinite(v)).sum())} NaN or infinite value(s)")
        cols[c] = v
    for c in _INDEX_COLUMNS:
        if np.any(cols[c] != np.round(cols[c])):
            raise InputError(f"column {c}: not integers")
        cols[c] = cols[c].astype(np.int64)
    if not np.any(cols["parent"] == -1):  # TreeQSM / rTwig: 1-based, 0 for none
        for c in ("parent", "extension"):
            cols[c] = cols[c] - 1
    n = len(df)
    for c in ("parent", "extension"):
        if cols[c].min() < -1 or cols[c].max() >= n:
            raise InputError(f"column {c}: index out of range (0..{n - 1}, or -1 for none)")
    if np.any(cols["length"] < 0) or np.any(cols["radius"] <= 0):
        raise InputError("lengths must be >= 0 and radii > 0")
    norm = np.linalg.norm(np.stack([cols["axis_x"], cols["axis_y"], cols["axis_z"]], axis=1), axis=1)
    if np.any((norm == 0) & (cols["length"] > 0)):
        raise InputError("a cylinder of non-zero length has a zero axis")
    return cols


def _cylinder_order(parent: np.ndarray) -> np.ndarray:
    """Cylinder indices with every parent before its children; InputError on a cycle."""
    n = len(parent)
    kids: list[list[int]] = [[] for _ in range(n)]
    for i, p in enumerate(parent.tolist()):
        if p >= 0:
            kids[p].append(i)
    order = [i for i in range(n) if parent[i] < 0]
    k = 0
    while k < len(order):
        order.extend(kids[order[k]])
        k += 1
    if len(order) != n:
        raise InputError("column parent: the cylinders' parents form a cycle")
    return np.asarray(order, np.int64)


def cylinders_to_skeleton(df: pd.DataFrame) -> Skeleton:
    """The skeleton of a cylinder table (the inverse of :func:`skeleton_to_cylinders`; see the module for what a
    round trip keeps). Raises InputError on missing columns, non-numeric or non-finite values, bad indices, cycles."""
    c = _validated(df)
    start = np.stack([c["start_x"], c["start_y"], c["start_z"]], axis=1)
    axis = np.stack([c["axis_x"], c["axis_y"], c["axis_z"]], axis=1)
    norm = np.linalg.norm(axis, axis=1)
    axis = axis / np.where(norm > 0, norm, 1.0)[:, None]
    end = start + c["length"][:, None] * axis
    parent, radius, order = c["parent"], c["radius"], c["branch_order"]
    pos: list[np.ndarray] = []
    rad: list[float] = []
    par: list[int] = []
    ordr: list[int] = []

    def add(p: np.ndarray, r: float, q: int, o: int) -> int:
        pos.append(p)
        rad.append(float(r))
        par.append(q)
        ordr.append(int(o))
        return len(pos) - 1

    start_node = np.full(len(df), -1, np.int64)
    end_node = np.full(len(df), -1, np.int64)
    roots: list[int] = []
    for i in _cylinder_order(parent).tolist():
        p = int(parent[i])
        if p < 0:
            same = [r for r in roots if np.linalg.norm(pos[r] - start[i]) <= MERGE_TOLERANCE]
            if same:
                start_node[i] = same[0]
            else:
                start_node[i] = add(start[i], radius[i], -1, order[i])
                roots.append(int(start_node[i]))
        elif np.linalg.norm(end[p] - start[i]) <= MERGE_TOLERANCE:
            start_node[i] = end_node[p]
        else:  # starts off its parent's end: a node of its own on the nearer end of the parent
            near = end_node[p] if np.linalg.norm(end[p] - start[i]) <= np.linalg.norm(start[p] - start[i]) \
                else start_node[p]
            start_node[i] = add(start[i], radius[i], int(near), order[i])
        end_node[i] = add(end[i], radius[i], int(start_node[i]), order[i])
    return Skeleton(np.array(pos).reshape(-1, 3), np.array(rad), np.array(par, np.int64), np.array(ordr, np.int64))


def write_qsm_csv(path: str | os.PathLike, skeleton: Skeleton) -> pd.DataFrame:
    """Write ``skeleton``'s cylinder table as CSV (columns :data:`COLUMNS`, no index, floats round-tripping exactly);
    returns the table."""
    df = skeleton_to_cylinders(skeleton)
    with atomic_write(path, "w") as fh:
        df.to_csv(fh, index=False, float_format="%.17g", lineterminator="\n")
    return df


def read_csv_table(path: str | os.PathLike) -> pd.DataFrame:
    """A CSV file as a DataFrame, column names stripped; InputError naming the file when it is missing or not a
    readable CSV (the QSM tables here and the reference QSMs, :mod:`plantbench.io.references`)."""
    path = Path(path)
    if not path.is_file():
        raise InputError("file not found", path=path)
    try:
        df = pd.read_csv(path, skipinitialspace=True)
    except (pd.errors.EmptyDataError, pd.errors.ParserError, UnicodeDecodeError) as exc:
        raise InputError(f"not a readable CSV file ({exc})", path=path) from None
    df.columns = [str(col).strip() for col in df.columns]
    return df


def read_qsm_csv(path: str | os.PathLike) -> Skeleton:
    """Read a cylinder table CSV (TreeQSM / rTwig columns; extra columns ignored) as a skeleton; InputError naming
    the file on anything unreadable."""
    path = Path(path)
    df = read_csv_table(path)
    try:
        return cylinders_to_skeleton(df)
    except InputError as exc:
        raise InputError(str(exc), path=path) from None
