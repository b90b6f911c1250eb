"""Reference cylinder models (QSMs) made by published tools from a real scan: TreeQSM, SimpleForest and aRchi tables
read into one cylinder table (the columns of :data:`plantbench.io.qsm.COLUMNS`), so that their traits
(:func:`plantbench.metrics.traits.cylinder_traits`) are computed as a method's are.

Column mapping (0-based rows, -1 for none, ``branch_order`` 0 for the stem):

=================  ===========================================  ==========================================  ==============================================
our column         TreeQSM v2.4 (rTwig's export)                SimpleForest                                aRchi
=================  ===========================================  ==========================================  ==============================================
start_x/y/z        start_x/y/z                                  startX/Y/Z                                  startX/Y/Z
axis, length       axis_x/y/z, length                           (endX/Y/Z - start) / |end - start|,         (endX/Y/Z - start) / |end - start|,
                                                                |end - start|                               |end - start|
radius             radius                                       radius                                      radius_cyl
parent             parent - 1 (1-based, 0 none)                 parentID (0-based ID, -1 none)              parent_ID - 1 (cyl_ID is 1-based, 0 none)
extension          extension - 1                                the child with the same branchID            the child with the same axis_ID
branch             branch                                       branchID                                    axis_ID
branch_order       branch_order                                 branchOrder                                 branching_order - 1 (aRchi's stem is 1)
=================  ===========================================  ==========================================  ==============================================

aRchi's ``extension_ID`` is not read: it does not follow its ``axis_ID`` axes (taking it as the continuation puts
half of the stem in laterals). SimpleForest's and aRchi's own ``length`` columns are not read (the end points define the cylinder); a SimpleForest
or aRchi row is found by its ID column, whatever the row order. The tables stay in their own frame (the scan
file's): :func:`reference_in_case_frame` moves one into a case's frame with the transform ``case.json`` records.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd

from plantbench.errors import InputError
from plantbench.io.qsm import COLUMNS, read_csv_table

__all__ = ["TOOLS", "read_reference", "reference_in_case_frame"]

TOOLS = ("treeqsm", "simpleforest", "archi")


def _read_csv(path: Path) -> pd.DataFrame:
    return read_csv_table(path)


def _numeric(df: pd.DataFrame, names: list[str], path: Path, tool: str) -> dict[str, np.ndarray]:
    missing = [c for c in names if c not in df.columns]
    if missing:
        raise InputError(f"not a {tool} table: missing column(s) {', '.join(missing)}", path=path)
    out = {}
    for c in names:
        try:
            v = pd.to_numeric(df[c], errors="raise").to_numpy(np.float64)
        except (ValueError, TypeError):
            raise InputError(f"column {c}: not numeric", path=path) from None
        if not np.all(np.isfinite(v)):
            raise InputError(f"column {c}: NaN or infinite values", path=path)
        out[c] = v
    return out


def _from_ends(start: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    vec = end - start
    length = np.linalg.norm(vec, axis=1)
    axis = np.where(length[:, None] > 0, vec / np.where(length > 0, length, 1.0)[:, None], [0.0, 0.0, 1.0])
    return axis, length


def _by_id(ids: np.ndarray, refs: np.ndarray, none: float, path: Path, column: str) -> np.ndarray:
    """Row index of each ``refs`` ID (``none``: -1)."""
    row = {int(i): k for k, i in enumerate(ids.tolist())}
    if len(row) != len(ids):
        raise InputError("duplicate cylinder IDs", path=path)
    try:
        return np.array([-1 if r == none else row[int(r)] for r in refs.tolist()], np.int64)
    except KeyError as exc:
        raise InputError(f"column {column}: ID {exc} names no cylinder", path=path) from None


def _continuations(parent: np.ndarray, branch: np.ndarray) -> np.ndarray:
    """Each cylinder's extension: its first child of the same branch (axis), -1 if none."""
    extension = np.full(len(parent), -1, np.int64)
    for i, p in enumerate(parent.tolist()):
        if p >= 0 and branch[i] == branch[p] and extension[p] < 0:
            extension[p] = i
    return extension


def _table(start, axis, length, radius, parent, extension, branch, order) -> pd.DataFrame:
    return pd.DataFrame({
        "start_x": start[:, 0], "start_y": start[:, 1], "start_z": start[:, 2],
        "axis_x": axis[:, 0], "axis_y": axis[:, 1], "axis_z": axis[:, 2], "length": length, "radius": radius,
        "parent": parent, "extension": extension, "branch": branch.astype(np.int64),
        "branch_order": order.astype(np.int64)}, columns=list(COLUMNS))


def read_reference(tool: str, path: str | os.PathLike) -> pd.DataFrame:
    """The cylinder table of a ``tool`` ('treeqsm', 'simpleforest' or 'archi') export, in the file's frame: columns
    :data:`plantbench.io.qsm.COLUMNS` (see the module for the mapping). InputError naming the file on a missing
    column, a non-numeric or non-finite value, an unknown ID, a radius <= 0 or no cylinder."""
    path = Path(path)
    if tool not in TOOLS:
        raise InputError(f"unknown reference tool {tool!r} (one of {', '.join(TOOLS)})")
    df = _read_csv(path)
    if not len(df):
        raise InputError("no cylinders", path=path)
    if tool == "treeqsm":
        c = _numeric(df, list(COLUMNS), path, tool)
        base = 0 if np.any(c["parent"] == -1) else 1  # rTwig's export: 1-based, 0 for none
        n = len(df)
        parent, extension = (c[k].astype(np.int64) - base for k in ("parent", "extension"))
        if parent.min() < -1 or parent.max() >= n or extension.min() < -1 or extension.max() >= n:
            raise InputError("column parent or extension: index out of range", path=path)
        out = _table(np.stack([c["start_x"], c["start_y"], c["start_z"]], 1),
                     np.stack([c["axis_x"], c["axis_y"], c["axis_z"]], 1), c["length"], c["radius"], parent,
                     extension, c["branch"], c["branch_order"])
    elif tool == "simpleforest":
        names = ["ID", "parentID", "startX", "startY", "startZ", "endX", "endY", "endZ", "radius", "branchID",
                 "branchOrder"]
        c = _numeric(df, names, path, tool)
        start = np.stack([c["startX"], c["startY"], c["startZ"]], 1)
        axis, length = _from_ends(start, np.stack([c["endX"], c["endY"], c["endZ"]], 1))
        parent = _by_id(c["ID"], c["parentID"], -1, path, "parentID")
        out = _table(start, axis, length, c["radius"], parent, _continuations(parent, c["branchID"]), c["branchID"],
                     c["branchOrder"])
    else:
        names = ["cyl_ID", "parent_ID", "extension_ID", "startX", "startY", "startZ", "endX", "endY", "endZ",
                 "radius_cyl", "axis_ID", "branching_order"]
        c = _numeric(df, names, path, tool)
        start = np.stack([c["startX"], c["startY"], c["startZ"]], 1)
        axis, length = _from_ends(start, np.stack([c["endX"], c["endY"], c["endZ"]], 1))
        parent = _by_id(c["cyl_ID"], c["parent_ID"], 0, path, "parent_ID")
        out = _table(start, axis, length, c["radius_cyl"], parent, _continuations(parent, c["axis_ID"]), c["axis_ID"],
                     c["branching_order"] - 1)
    if np.any(out["radius"] <= 0):
        raise InputError("radii must be > 0", path=path)
    return out


def reference_in_case_frame(table: pd.DataFrame, frame) -> pd.DataFrame:
    """``table`` (in the scan file's frame) moved into a case's frame (:class:`plantbench.capture.importers.CaseFrame`:
    units, up axis and offset, as ``plantbench import scan`` recorded them); lengths and radii scaled by the units."""
    from plantbench.capture.importers import to_local

    f = float(frame.units_factor)
    R = np.asarray(frame.rotation, float)
    out = table.copy()
    start = to_local(table[["start_x", "start_y", "start_z"]].to_numpy(float), frame)
    axis = table[["axis_x", "axis_y", "axis_z"]].to_numpy(float) @ R.T
    out[["start_x", "start_y", "start_z"]] = start
    out[["axis_x", "axis_y", "axis_z"]] = axis
    out["length"] = table["length"] * f
    out["radius"] = table["radius"] * f
    return out
