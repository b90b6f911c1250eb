"""Benchmarks time each stage beside the raw library doing the same work, so ratios mean something here."""

import numpy as np
import pytest


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.Generator(np.random.PCG64(12345))
