"""The quick suite end to end: one local worker beside a 2-worker Dask LocalCluster (fresh caches each).

Acceptance (issue 10): the 2-worker cluster runs the quick suite >= 1.6x faster than 1 worker, with the same
results table. Each variant runs once (a round is minutes long); compare the two means in one report.

The ratio of one pair is noisy on a shared VM: eight pairs on the 2-core development machine (session 7) gave 1.49,
1.55, 1.61, 1.63, 1.64, 1.70, 1.73 and 1.78x, the 1-worker run alone taking 217-286 s within an hour. In slow phases
jobs side by side took up to 1.3x their time alone, in others 1.1x; the same 15 metric cells run as two concurrent
streams took the CPU time of one stream alone (193 s), so it is the host, not the jobs. Judge it on several pairs,
alternating which variant runs first.
"""

from __future__ import annotations

import shutil

import pytest

from plantbench.runner import run_suite
from plantbench.suites import load_suite

RESULTS: dict[str, object] = {}


@pytest.mark.benchmark(group="quick-suite")
def test_quick_suite_local_1_worker(benchmark, tmp_path):
    suite = load_suite("quick")

    def run():
        shutil.rmtree(tmp_path / "runs", ignore_errors=True)
        return run_suite(suite, tmp_path / "runs", workers=1)

    RESULTS["local"] = benchmark.pedantic(run, rounds=1, iterations=1)


@pytest.mark.benchmark(group="quick-suite")
def test_quick_suite_dask_2_workers(benchmark, tmp_path):
    distributed = pytest.importorskip("dask.distributed")
    import dask

    from plantbench.runner.execute import DASK_CLUSTER_CONFIG

    suite = load_suite("quick")
    with dask.config.set(DASK_CLUSTER_CONFIG), distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cl:
        with distributed.Client(cl) as client:
            def run():
                shutil.rmtree(tmp_path / "runs", ignore_errors=True)
                return run_suite(suite, tmp_path / "runs", executor="dask", client=client)

            RESULTS["dask"] = benchmark.pedantic(run, rounds=1, iterations=1)
    if "local" in RESULTS:
        a, b = RESULTS["local"].table, RESULTS["dask"].table
        keep_a, keep_b = a[a["metric"] != "runtime_s"], b[b["metric"] != "runtime_s"]
        assert keep_a.reset_index(drop=True).equals(keep_b.reset_index(drop=True))
        print(f"\nspeed-up of 2 Dask workers over 1 local worker: {RESULTS['local'].seconds / RESULTS['dask'].seconds:.2f}x")
