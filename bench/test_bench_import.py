"""Import time of the package (the CLI's start-up): ``import plantbench`` with its registry and schemas, in a fresh
interpreter, beside a fresh interpreter importing only numpy and scipy.sparse, which plantbench cannot start without."""

import subprocess
import sys

import pytest


def _fresh(code: str) -> None:
    subprocess.run([sys.executable, "-c", code], check=True)


@pytest.mark.benchmark(group="import")
def test_bare_numpy_scipy(benchmark):
    benchmark.pedantic(_fresh, args=("import numpy, scipy.sparse",), rounds=5, iterations=1)


@pytest.mark.benchmark(group="import")
def test_plantbench_import(benchmark):
    benchmark.pedantic(_fresh, args=("import plantbench, plantbench.registry, plantbench.schemas",), rounds=5,
                       iterations=1)
