"""Writing a report's figures: atomically (a figure is whole or absent), its folder made, the figure closed."""

from __future__ import annotations

import os
from pathlib import Path

from plantbench.io.atomic import atomic_write

__all__ = ["save_png"]


def save_png(fig, path: str | os.PathLike, *, dpi: int = 110) -> Path:
    """Save the matplotlib ``fig`` as a PNG at ``path`` through a temporary file, then close it; returns the path."""
    import matplotlib.pyplot as plt

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(path) as fh:
        fig.savefig(fh, format="png", dpi=dpi)
    plt.close(fig)
    return path
