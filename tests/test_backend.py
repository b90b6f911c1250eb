import subprocess
import sys

from plantbench.backend import find_libllvm, kdtree_workers, open3d_threads, thread_budget, thread_map


def test_variant_probe_never_kills_the_caller(tmp_path):
    # run the selection in a child with a private cache: it must return a usable variant name and cache it
    code = (
        "import warnings; warnings.simplefilter('ignore');"
        "from plantbench.backend import select_variant; print(select_variant())"
    )
    env = {"PLANTBENCH_CACHE": str(tmp_path), "PATH": "/usr/bin:/bin", "HOME": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=600)
    assert out.returncode == 0, out.stderr
    variant = out.stdout.strip()
    assert variant in ("llvm_ad_rgb", "scalar_rgb")
    if find_libllvm():
        assert variant == "llvm_ad_rgb"
        assert (tmp_path / "mitsuba_variant.json").exists()


def test_bad_llvm_falls_back_to_scalar(tmp_path):
    # point Dr.Jit at an LLVM that aborts the process (15) or is refused (14): the probe must catch it
    import glob

    bad = sorted(glob.glob("/usr/lib/x86_64-linux-gnu/libLLVM-1[45].so.1"))
    if not bad:
        import pytest

        pytest.skip("no old LLVM on this machine to test the fallback")
    code = (
        "import warnings;"
        "from plantbench.backend import select_variant, BackendWarning;"
        "import plantbench.backend as b; b.LLVM_CANDIDATES = ();"
        "print(select_variant())"
    )
    env = {"PLANTBENCH_CACHE": str(tmp_path), "PATH": "/usr/bin:/bin", "HOME": str(tmp_path),
           "DRJIT_LIBLLVM_PATH": bad[-1]}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=600)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "scalar_rgb"
    assert "BackendWarning" in out.stderr or "unavailable" in out.stderr


def test_thread_budget_from_the_runner(monkeypatch):
    """Libraries that size their pools from the core count get the runner's budget explicitly (else all cores)."""
    monkeypatch.delenv("PLANTBENCH_THREADS", raising=False)
    assert (thread_budget(), kdtree_workers(), open3d_threads()) == (None, -1, 0)
    monkeypatch.setenv("PLANTBENCH_THREADS", "1")
    assert (thread_budget(), kdtree_workers(), open3d_threads()) == (1, 1, 1)
    for bad in ("0", "two", ""):
        monkeypatch.setenv("PLANTBENCH_THREADS", bad)
        assert thread_budget() is None


def test_thread_map_runs_blas_on_one_thread_per_worker(monkeypatch):
    """Inside thread_map's threads BLAS is limited to one thread (its own threads compete with them); one worker
    leaves BLAS as it is."""
    from threadpoolctl import threadpool_info

    def blas_threads(_):
        return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]

    monkeypatch.setenv("PLANTBENCH_THREADS", "2")
    assert all(n == [1] * len(n) and n for n in thread_map(blas_threads, range(2)))
