"""Shared fixtures."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture
def rng() -> np.random.Generator:
    """A seeded generator: tests that draw random data are reproducible."""
    return np.random.Generator(np.random.PCG64(12345))
