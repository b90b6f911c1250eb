"""Suite runner: plan (content-addressed jobs), execute (local processes or Dask), results table."""

from plantbench.runner.run import RunResult, run_suite

__all__ = ["RunResult", "run_suite"]
