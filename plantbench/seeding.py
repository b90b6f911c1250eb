"""Deterministic random streams: one ``numpy.random.Generator`` per (suite, case, stage), from a root seed.

Keys are hashed with SHA-256 (not Python's salted ``hash``), so the same keys give the same stream on every
machine and in every process.
"""

from __future__ import annotations

import hashlib

import numpy as np

__all__ = ["rng", "derive_seed"]


def _key_words(keys: tuple[object, ...]) -> list[int]:
    digest = hashlib.sha256("\x1f".join(str(k) for k in keys).encode()).digest()
    return [int.from_bytes(digest[i : i + 4], "little") for i in range(0, 16, 4)]


def rng(root_seed: int, *keys: object) -> np.random.Generator:
    """Generator for ``keys`` (e.g. ``rng(0, "quick", "maple-1", "capture")``) under ``root_seed``."""
    if not isinstance(root_seed, int | np.integer) or root_seed < 0:
        raise ValueError(f"root seed must be a non-negative integer, got {root_seed!r}")
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence(int(root_seed), spawn_key=_key_words(keys))))


def derive_seed(root_seed: int, *keys: object) -> int:
    """A 63-bit integer seed for ``keys``, for handing to a subprocess or an external method."""
    return int(rng(root_seed, *keys).integers(0, 2**63 - 1))
