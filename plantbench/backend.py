"""Mitsuba variant selection without risking the process.

With a wrong LLVM (Debian's 15 or 16), Dr.Jit aborts the whole interpreter (SIGABRT, uncatchable) on the first
kernel that uses ``dr.minimum``. So the LLVM variant is probed once in a subprocess that renders a tiny scene
and evaluates ``dr.minimum``; the answer is cached per (mitsuba version, libLLVM path) under the user cache.
``llvm_ad_rgb`` is used when the probe passes, otherwise ``scalar_rgb`` with a warning.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import subprocess
import sys
import warnings
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

from plantbench.paths import cache_dir

__all__ = ["LLVM_CANDIDATES", "find_libllvm", "select_variant", "load_mitsuba", "apply_thread_budget",
           "BackendWarning"]

LLVM_CANDIDATES = (
    "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1",
    "/usr/lib/x86_64-linux-gnu/libLLVM-19.so.1",
    "/usr/lib/aarch64-linux-gnu/libLLVM.so.19.1",
    "/usr/lib/llvm-19/lib/libLLVM.so.19.1",
)

_PROBE = r"""
import mitsuba as mi
mi.set_variant("llvm_ad_rgb")
import drjit as dr
x = dr.minimum(mi.Float([1.0, 2.0, 3.0]), mi.Float([2.0, 1.0, 0.0]))
assert list(x) == [1.0, 1.0, 0.0], list(x)
scene = mi.load_dict({"type": "scene", "i": {"type": "path"}, "s": {"type": "sphere"}, "e": {"type": "constant"},
                      "c": {"type": "perspective", "film": {"type": "hdrfilm", "width": 8, "height": 8}}})
img = mi.render(scene, spp=2)
dr.sync_thread()
print("OK")
"""


class BackendWarning(UserWarning):
    """The fast Mitsuba variant is unavailable; rendering falls back to the slow scalar variant."""


def find_libllvm() -> str | None:
    """Path of an LLVM >= 19 shared library: ``DRJIT_LIBLLVM_PATH`` when set and present, else a known location."""
    env = os.environ.get("DRJIT_LIBLLVM_PATH")
    if env and Path(env).exists():
        return env
    return next((p for p in LLVM_CANDIDATES if Path(p).exists()), None)


def _mitsuba_version() -> str:
    try:
        return version("mitsuba")
    except PackageNotFoundError:
        return "missing"


@functools.cache
def select_variant() -> str:
    """'llvm_ad_rgb' when a subprocess probe of it succeeds, else 'scalar_rgb' (with a :class:`BackendWarning`).

    ``PLANTBENCH_VARIANT`` forces a variant. Sets ``DRJIT_LIBLLVM_PATH`` in this process when LLVM 19 is found, so
    that Dr.Jit loads it rather than an older system LLVM.
    """
    forced = os.environ.get("PLANTBENCH_VARIANT")
    llvm = find_libllvm()
    if llvm:
        os.environ["DRJIT_LIBLLVM_PATH"] = llvm
    if forced:
        return forced
    reason = ""
    if llvm is None:
        reason = "no LLVM 19 library found (apt-get install libllvm19)"
    else:
        probe_id = hashlib.sha256(_PROBE.encode()).hexdigest()[:12]
        key = f"{_mitsuba_version()}|{llvm}|{Path(llvm).stat().st_mtime_ns}|{probe_id}"
        cache = cache_dir() / "mitsuba_variant.json"
        try:
            cached = json.loads(cache.read_text())
        except (OSError, ValueError):
            cached = {}
        if key in cached:
            ok, reason = cached[key]["ok"], cached[key]["reason"]
        else:
            env = dict(os.environ, DRJIT_LIBLLVM_PATH=llvm)
            try:
                proc = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, timeout=300)
                ok = proc.returncode == 0 and "OK" in proc.stdout
                reason = "" if ok else f"probe exited {proc.returncode}: {(proc.stderr or proc.stdout).strip()[-300:]}"
            except subprocess.TimeoutExpired:
                ok, reason = False, "probe timed out"
            cached[key] = {"ok": ok, "reason": reason}
            try:
                cache.parent.mkdir(parents=True, exist_ok=True)
                tmp = cache.with_suffix(f".{os.getpid()}.tmp")
                tmp.write_text(json.dumps(cached))
                os.replace(tmp, cache)
            except OSError:
                pass
        if ok:
            return "llvm_ad_rgb"
    warnings.warn(f"Mitsuba llvm_ad_rgb unavailable ({reason}); using scalar_rgb, 3-10x slower", BackendWarning, stacklevel=2)
    return "scalar_rgb"


def thread_budget() -> int | None:
    """The number of threads this process may use: ``PLANTBENCH_THREADS`` when the runner set it (several jobs
    sharing the cores; :func:`plantbench.runner.execute.job_environment`), else None (all cores).

    OpenMP and BLAS read their own variables; libraries that size their pools from the core count alone (Dr.Jit,
    scipy's cKDTree ``workers=-1``, Open3D's ray casting through Embree/TBB) are passed this explicitly."""
    n = os.environ.get("PLANTBENCH_THREADS", "")
    return int(n) if n.isdigit() and int(n) > 0 else None


def kdtree_workers() -> int:
    """``workers`` for scipy's cKDTree queries: the thread budget, else all cores (-1)."""
    return thread_budget() or -1


def open3d_threads() -> int:
    """``nthreads`` for Open3D's RaycastingScene and its queries: the thread budget, else automatic (0)."""
    return thread_budget() or 0


def apply_thread_budget(dr) -> None:
    """Cap Dr.Jit's (so Mitsuba's) thread pool at the thread budget (:func:`thread_budget`) when there is one."""
    n = thread_budget()
    if n and dr.thread_count() != n:
        dr.set_thread_count(n)


def load_mitsuba(variant: str | None = None):
    """Import mitsuba with the selected variant set; returns the module."""
    chosen = variant or select_variant()
    import drjit as dr
    import mitsuba as mi

    if mi.variant() != chosen:
        mi.set_variant(chosen)
    apply_thread_budget(dr)
    return mi
