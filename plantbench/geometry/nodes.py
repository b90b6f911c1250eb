"""Growable per-node arrays for growth loops (the generator's Palubicki growth, Guo et al.'s guided growth)."""

from __future__ import annotations

import numpy as np

__all__ = ["GrowableNodes"]


class GrowableNodes:
    """Node columns that grow by doubling, with the first ``n`` rows in use.

    ``columns``: name -> (trailing shape, dtype, fill): e.g. ``{"pos": ((3,), np.float64, 0.0), "parent": ((),
    np.int64, -1)}``; every column is an attribute (``nodes.pos[:nodes.n]``). Rows not yet added hold ``fill``, so a
    column that is written only later (a child pointer) reads as its fill until then. A column named ``alive`` is set
    True for every row added.
    """

    def __init__(self, columns: dict[str, tuple[tuple[int, ...], type, object]], cap: int = 4096) -> None:
        self.n = 0
        self._columns = dict(columns)
        for name, (tail, dtype, fill) in self._columns.items():
            setattr(self, name, np.full((cap, *tail), fill, dtype))

    def _reserve(self, need: int) -> None:
        cap = len(getattr(self, next(iter(self._columns))))
        if need <= cap:
            return
        new = max(need, 2 * cap)
        for name, (tail, dtype, fill) in self._columns.items():
            arr = np.full((new, *tail), fill, dtype)
            arr[:cap] = getattr(self, name)
            setattr(self, name, arr)

    def add(self, **cols) -> np.ndarray:
        """Append rows with the given columns (as many as the first column given has; the other columns keep their
        fill); returns their indices."""
        k = len(next(iter(cols.values())))
        self._reserve(self.n + k)
        idx = np.arange(self.n, self.n + k)
        for name, val in cols.items():
            getattr(self, name)[idx] = val
        if "alive" in self._columns:
            self.alive[idx] = True
        self.n += k
        return idx

    def alive_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """The rows whose ``alive`` is set, in order, and their parents renumbered among them (-1 for a root, or for
        a row whose parent is not alive): (keep (m,) int, parents (m,) int)."""
        n = self.n
        keep = np.flatnonzero(self.alive[:n])
        remap = np.full(n, -1, np.int64)
        remap[keep] = np.arange(len(keep))
        par = self.parent[keep]
        return keep, np.where(par >= 0, remap[np.maximum(par, 0)], -1)
