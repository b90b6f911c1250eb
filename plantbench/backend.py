"""Mitsuba variant selection without risking the process.

With a wrong LLVM (Debian's 15 or 16), Dr.Jit aborts the whole interpreter (SIGABRT, uncatchable) on the first
kernel that uses ``dr.minimum``. So the LLVM variant is probed once in a subprocess that renders a tiny scene
and evaluates ``dr.minimum``; the answer is cached per (mitsuba version, libLLVM path) under the user cache.
``llvm_ad_rgb`` is used when the probe passes, otherwise ``scalar_rgb`` with a warning.

Dr.Jit's LLVM backend compiles its kernels for the host CPU by default: on an AVX-512 machine it uses 16-wide
vectors and other intrinsics (the 14-bit ``rsqrt14`` beside AVX's 12-bit ``rsqrt``) than on an AVX2 one, so renders
and mvs depth maps would change with the machine. :func:`pin_llvm_target` fixes the code generation to one
instruction set and vector width (:data:`PINNED_TARGET`, AVX2 at width 8) on every x86-64 machine, through drjit-core's
exported ``jit_llvm_set_target`` (its Python bindings do not wrap it), before the first kernel, and turns Dr.Jit's
``FastMath`` off (it compiles ``dr.rsqrt`` to ``vrsqrtps``, whose bits differ between CPU models and vendors).
:func:`pin_embree` does the same for Mitsuba's Embree, which picks its kernels from the CPU (docs/tuning/determinism.md).
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import json
import os
import platform
import subprocess
import sys
import warnings
from dataclasses import dataclass
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

from plantbench.paths import cache_dir

__all__ = ["LLVM_CANDIDATES", "find_libllvm", "select_variant", "load_mitsuba", "apply_thread_budget",
           "BackendWarning", "LLVMTarget", "PINNED_TARGET", "requested_llvm_target", "pin_llvm_target",
           "current_llvm_target", "load_drjit", "host_can_pin", "host_has", "host_cpu_name", "cpu_name", "llvm_target_id",
           "BLAS_PIN", "NUMPY_PIN", "dispatch_environment", "pin_dispatch", "dispatch_id", "dispatch_seen",
           "EMBREE_PIN", "EMBREE_REQUIRES", "requested_embree_config", "pin_embree", "embree_config_seen",
           "thread_budget", "thread_map", "kdtree_workers"]

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


def thread_map(fn, items) -> list:
    """``[fn(x) for x in items]`` on the process's thread budget (:func:`thread_budget`, else all cores), in order.
    For independent work whose numpy/OpenCV kernels release the GIL; ``fn`` must not share random state. BLAS runs
    on one thread inside each (OpenBLAS's own threads otherwise compete with these: the mvs stage's consistency
    test on a 36-view 1024 px plant, 2 cores, took 26.5 s with them and 20.0 s without)."""
    from concurrent.futures import ThreadPoolExecutor

    from threadpoolctl import threadpool_limits

    items = list(items)
    n = min(len(items), thread_budget() or os.cpu_count() or 1)
    if n <= 1:
        return [fn(x) for x in items]
    with threadpool_limits(limits=1, user_api="blas"), ThreadPoolExecutor(max_workers=n) as pool:
        return list(pool.map(fn, items))


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


@dataclass(frozen=True)
class LLVMTarget:
    """What Dr.Jit's LLVM backend compiles kernels for.

    cpu : LLVM CPU name ('haswell')
    features : LLVM feature list ('+avx2,+fma,...'); Dr.Jit picks its intrinsics by searching it
    width : vector width in 32-bit lanes (8 for AVX2); a power of two
    """

    cpu: str
    features: str
    width: int

    def spec(self) -> str:
        """'cpu:features:width', the form :envvar:`PLANTBENCH_LLVM_TARGET` takes."""
        return f"{self.cpu}:{self.features}:{self.width}"


PINNED_TARGET = LLVMTarget("haswell", "+avx,+avx2,+fma,+f16c,+bmi,+bmi2,+lzcnt,+popcnt,+sse4.2,+sse4.1,+ssse3,+sse3",
                           8)
"""The code generation every x86-64 machine uses: AVX2 + FMA at width 8, which any x86-64 CPU since 2013 (Intel
Haswell, AMD Zen) runs. AVX-512 machines run it too; they would otherwise pick 16-wide kernels."""

_HOST = "host"


def requested_llvm_target() -> LLVMTarget | None:
    """The target asked for: :data:`PINNED_TARGET`, or ``PLANTBENCH_LLVM_TARGET`` when set ('host': leave Dr.Jit's
    own choice for this CPU, returned as None; or 'cpu:features:width'). Not x86-64: None (the pin is x86 code)."""
    from plantbench.errors import InputError

    value = os.environ.get("PLANTBENCH_LLVM_TARGET", "").strip()
    if value == _HOST:
        return None
    if value:
        parts = value.split(":")
        if len(parts) != 3 or not parts[2].isdigit() or int(parts[2]) & (int(parts[2]) - 1) or int(parts[2]) < 1:
            raise InputError(f"PLANTBENCH_LLVM_TARGET must be 'host' or 'cpu:features:width' with a power-of-two "
                             f"width, got {value!r}")
        return LLVMTarget(parts[0], parts[1], int(parts[2]))
    if platform.machine().lower() not in ("x86_64", "amd64"):
        return None
    return PINNED_TARGET


_CPUINFO_FLAG = {"bmi": "bmi1", "sse3": "pni", "sse4.1": "sse4_1", "sse4.2": "sse4_2"}
"""LLVM feature names that /proc/cpuinfo spells otherwise (the rest are the same)."""


PIN_REQUIRES = "+avx,+avx2,+fma,+f16c,+bmi,+bmi2"
"""The CPU features that mark a CPU able to run :data:`PINNED_TARGET` (every such x86-64 CPU, Intel Haswell and AMD
Zen on, also has the SSE4, POPCNT and LZCNT it lists; /proc/cpuinfo spells LZCNT inconsistently)."""


def host_can_pin() -> bool:
    """True on an x86-64 CPU that runs the pinned target's kernels (:data:`PIN_REQUIRES`)."""
    return platform.machine().lower() in ("x86_64", "amd64") and host_has(PIN_REQUIRES)


def host_has(features: str) -> bool:
    """True when /proc/cpuinfo lists every '+feature' of ``features`` (False when it cannot be read)."""
    try:
        with open("/proc/cpuinfo") as fh:
            flags = set(next(line for line in fh if line.startswith("flags")).split(":", 1)[1].split())
    except (OSError, StopIteration, IndexError):
        return False
    need = {_CPUINFO_FLAG.get(f[1:], f[1:]) for f in features.split(",") if f.startswith("+")}
    return need <= flags


def _jit_core(dr):
    """drjit-core's C++ entry points for the LLVM target (exported by libdrjit-core.so, not bound in Python)."""
    lib = ctypes.CDLL(str(Path(dr.__file__).parent / "libdrjit-core.so"), mode=os.RTLD_NOLOAD | os.RTLD_GLOBAL)
    set_target = lib._Z19jit_llvm_set_targetPKcS0_j
    set_target.argtypes, set_target.restype = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_uint32], None
    cpu, features, width = (lib._Z19jit_llvm_target_cpuv, lib._Z24jit_llvm_target_featuresv,
                            lib._Z21jit_llvm_vector_widthv)
    cpu.restype = features.restype = ctypes.c_char_p
    width.restype = ctypes.c_uint32
    return set_target, cpu, features, width


def current_llvm_target(dr=None) -> LLVMTarget | None:
    """What Dr.Jit's LLVM backend compiles for now (None when its LLVM backend is not loaded)."""
    if dr is None:
        import drjit as dr
    if not dr.has_backend(dr.JitBackend.LLVM):
        return None
    _, cpu, features, width = _jit_core(dr)
    return LLVMTarget(cpu().decode(), (features() or b"").decode(), int(width()))


def pin_llvm_target(dr=None) -> LLVMTarget | None:
    """Set Dr.Jit's LLVM code generation to :func:`requested_llvm_target` (idempotent; kernels compiled before keep
    their target, later ones use the new one: the kernel caches are keyed by it). Returns the target in force, or
    None when Dr.Jit's own host choice stays (asked for, not x86-64, or no LLVM backend).

    A CPU without the pinned target's features (an x86-64 CPU older than AVX2) keeps its host target with a
    :class:`BackendWarning`: its renders are not comparable with other machines'."""
    if dr is None:
        import drjit as dr
    target = requested_llvm_target()
    if target is None or not dr.has_backend(dr.JitBackend.LLVM):
        return None
    if os.environ.get("PLANTBENCH_LLVM_TARGET") is None and not host_can_pin():
        warnings.warn(f"this CPU lacks {PIN_REQUIRES}: Dr.Jit keeps its host target, and renders and mvs depth "
                      "are not comparable with other machines'", BackendWarning, stacklevel=2)
        return None
    # FastMath is per thread: every load_drjit / load_mitsuba (each stage calls one on the thread it builds kernels
    # on) turns it off for the calling thread
    dr.set_flag(dr.JitFlag.FastMath, False)
    set_target, *_ = _jit_core(dr)
    now = current_llvm_target(dr)
    if now != target:
        set_target(target.cpu.encode(), target.features.encode(), target.width)
        now = current_llvm_target(dr)
        if now is None or (now.cpu, now.width) != (target.cpu, target.width):
            raise RuntimeError(f"jit_llvm_set_target({target}) did not take: Dr.Jit reports {now}")
    return target


def llvm_target_id() -> str:
    """What the pins change in outputs, for records and cache keys: the Dr.Jit target's spec with exact math and the
    Embree configuration ('haswell:...:8 exact-math embree:isa=avx512,...'; 'embree:host' where Embree keeps its own
    choice, the pin's library included when it cannot be built), or 'host:<cpu>' when unpinned."""
    target = requested_llvm_target()
    if target is not None:
        config = requested_embree_config()
        if config is not None and _embree_pin_library() is None:
            config = None
        return f"{target.spec()} exact-math embree:{config or 'host'}"
    return f"host:{platform.machine()}:{host_cpu_name()}"


EMBREE_PIN = "isa=avx512,frequency_level=simd256"
"""The Embree configuration every AVX-512 machine uses: the AVX-512 kernels, whose approximate reciprocal
(``vrcp14ps``) is specified bit for bit (AVX2's ``vrcpps`` is not), and the 256-bit frequency level (BVH8), which
Embree otherwise picks by CPU model."""

EMBREE_REQUIRES = "+avx512f,+avx512cd,+avx512dq,+avx512bw,+avx512vl"
"""The CPU features of Embree's AVX-512 (SKX) kernels."""

_EMBREE_SOURCE = Path(__file__).parent / "native" / "embree_pin.c"
_embree_lib = None


def requested_embree_config() -> str | None:
    """The configuration :func:`pin_embree` appends to Mitsuba's: :data:`EMBREE_PIN` where the LLVM target is pinned
    (not ``PLANTBENCH_LLVM_TARGET=host``) on a CPU with :data:`EMBREE_REQUIRES`; None (Embree's own choice) otherwise."""
    if requested_llvm_target() is None or not host_has(EMBREE_REQUIRES):
        return None
    return EMBREE_PIN


def _embree_pin_library() -> Path | None:
    """The shared library of ``native/embree_pin.c``, compiled once per source with the system C compiler into the
    user cache (None, with a warning, when there is no compiler or it fails)."""
    import shutil
    import tempfile

    from plantbench.io.atomic import write_bytes

    source = _EMBREE_SOURCE.read_bytes()
    out = cache_dir() / "native" / f"embree_pin-{hashlib.sha256(source).hexdigest()[:16]}.so"
    if out.exists():
        return out
    cc = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if not cc:
        warnings.warn("no C compiler (cc): Embree keeps its own choice of kernels, and renders are not comparable "
                      "with other CPUs'", BackendWarning, stacklevel=3)
        return None
    try:
        with tempfile.TemporaryDirectory() as tmp:
            built = Path(tmp) / out.name
            proc = subprocess.run([cc, "-O2", "-shared", "-fPIC", "-o", str(built), str(_EMBREE_SOURCE), "-ldl"],
                                  capture_output=True, text=True, timeout=120)
            if proc.returncode:
                raise OSError(proc.stderr.strip()[-300:] or f"exit status {proc.returncode}")
            write_bytes(out, built.read_bytes())
        return out
    except (OSError, subprocess.TimeoutExpired) as exc:
        warnings.warn(f"compiling {_EMBREE_SOURCE} with {cc} failed ({exc}): Embree keeps its own choice of "
                      "kernels, and renders are not comparable with other CPUs'", BackendWarning, stacklevel=3)
        return None


def pin_embree() -> str | None:
    """Make Mitsuba's Embree use :func:`requested_embree_config` (call before ``import mitsuba``; idempotent): loads
    ``native/embree_pin.c``, built into the user cache, which appends the configuration to the one Mitsuba passes
    ``rtcNewDevice``. Returns the configuration in force, or None where Embree keeps its own choice (asked for, a
    CPU without AVX-512, no C compiler, or Mitsuba imported before the pin could be placed), with a
    :class:`BackendWarning` where that makes renders incomparable with other machines'."""
    global _embree_lib
    import importlib.util

    config = requested_embree_config()
    if config is None:
        if requested_llvm_target() is not None and platform.machine().lower() in ("x86_64", "amd64"):
            warnings.warn(f"this CPU lacks {EMBREE_REQUIRES}: Embree keeps its own kernels, and renders are not "
                          "comparable with AVX-512 machines'", BackendWarning, stacklevel=2)
        return None
    if _embree_lib is not None:
        return config
    if "mitsuba" in sys.modules:
        warnings.warn("mitsuba was imported before plantbench could pin Embree's configuration: renders are not "
                      "comparable with other CPUs'", BackendWarning, stacklevel=2)
        return None
    spec = importlib.util.find_spec("mitsuba")
    embree = Path(spec.origin).parent / "libembree3.so" if spec and spec.origin else None
    if embree is None or not embree.exists():
        return None
    library = _embree_pin_library()
    if library is None:
        return None
    lib = ctypes.CDLL(str(library), mode=os.RTLD_GLOBAL)
    lib.plantbench_embree_pin.argtypes = [ctypes.c_char_p, ctypes.c_char_p]
    lib.plantbench_embree_last_config.restype = ctypes.c_char_p
    lib.plantbench_embree_pin(str(embree).encode(), config.encode())
    _embree_lib = lib
    return config


def embree_config_seen() -> tuple[int, str] | None:
    """(devices created, configuration of the last) as Mitsuba's Embree received them through the pin; None when
    the pin is not loaded."""
    if _embree_lib is None:
        return None
    return int(_embree_lib.plantbench_embree_calls()), _embree_lib.plantbench_embree_last_config().decode()


def cpu_name(cpuinfo: str) -> str | None:
    """'<model name> (family F, model M)' from the first processor of a /proc/cpuinfo text (None without a model
    name). The numbers tell apart CPUs whose model name does not: a cloud AMD EPYC reads 'AMD EPYC' on Zen 4
    (family 25) and Zen 5 (family 26) alike, and their renders differed before the fast-math pin."""
    fields: dict[str, str] = {}
    for line in cpuinfo.splitlines():
        if not line.strip():
            if fields:
                break
            continue
        key, _, value = line.partition(":")
        fields.setdefault(key.strip(), value.strip())
    name = fields.get("model name")
    if not name:
        return None
    family, model = fields.get("cpu family"), fields.get("model")
    return f"{name} (family {family}, model {model})" if family and model else name


def host_cpu_name() -> str:
    """This CPU's :func:`cpu_name`, for records (and the name of an ``--another-cpu`` run)."""
    try:
        with open("/proc/cpuinfo") as fh:
            name = cpu_name(fh.read())
    except OSError:
        name = None
    return name or platform.processor() or "unknown"


def load_drjit():
    """Import drjit with the LLVM target pinned (:func:`pin_llvm_target`) and the thread budget applied; returns
    (drjit, drjit.llvm)."""
    llvm = find_libllvm()
    if llvm:
        os.environ.setdefault("DRJIT_LIBLLVM_PATH", llvm)
    import drjit as dr
    import drjit.llvm as jl

    pin_llvm_target(dr)
    apply_thread_budget(dr)
    return dr, jl


def load_mitsuba(variant: str | None = None):
    """Import mitsuba with the selected variant set and Dr.Jit's LLVM target pinned; returns the module."""
    chosen = variant or select_variant()
    if chosen.startswith("llvm"):
        pin_embree()
    import drjit as dr
    import mitsuba as mi

    if mi.variant() != chosen:
        mi.set_variant(chosen)
    if chosen.startswith("llvm"):
        pin_llvm_target(dr)
    apply_thread_budget(dr)
    return mi


# --- the numerical libraries' own CPU dispatch: OpenBLAS, numpy, OpenCV -----------------------------------------

BLAS_PIN = "Haswell"
"""OpenBLAS's kernels for every x86-64 CPU with AVX2 (``OPENBLAS_CORETYPE``). Left to itself OpenBLAS picks them
by CPU model: SkylakeX or Cooperlake (AVX-512) on an Intel Xeon or an AMD Zen 4, Haswell on a Zen 5 (0.3.30/0.3.31
do not know family 26). Their sums run in other orders, so ``-R @ eye`` of a camera differs in its last bit and the
mvs stage's cloud, then every method, follow (docs/tuning/determinism.md)."""

NUMPY_PIN = "X86_V3"
"""numpy's dispatched loops at AVX2 (x86-64-v3): its AVX-512 loops (``exp``, ``log``, ``sin`` ... of float64) round
other last bits than the AVX2 ones, and a CPU without AVX-512 has only the latter."""

_NUMPY_AVX512 = {"new": "X86_V4 AVX512_ICL AVX512_SPR",  # numpy >= 2.4
                 "old": "AVX512F AVX512CD AVX512_KNL AVX512_KNM AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL "
                        "AVX512_SPR"}
_OPENCV_ABOVE_AVX2 = "AVX_VNNI,AVX512-SKX,AVX512-CLX"
"""OpenCV's dispatched levels above AVX2 in opencv-python's builds (``cv2.getCPUFeaturesLine()``)."""

DISPATCH_HOST = "host"
"""``PLANTBENCH_DISPATCH=host`` leaves OpenBLAS, numpy and OpenCV their own choice."""


def _numpy_avx512_names() -> str:
    try:
        major, minor = (int(x) for x in version("numpy").split(".")[:2])
    except (PackageNotFoundError, ValueError):
        return _NUMPY_AVX512["new"]
    return _NUMPY_AVX512["new" if (major, minor) >= (2, 4) else "old"]


def dispatch_environment() -> dict[str, str]:
    """The variables that pin OpenBLAS (:data:`BLAS_PIN`), numpy (:data:`NUMPY_PIN`) and OpenCV to AVX2 kernels on
    an x86-64 CPU with :data:`PIN_REQUIRES`; {} elsewhere or with ``PLANTBENCH_DISPATCH=host``. Each library reads
    its variable once, when it is loaded. (``OPENBLAS_L2_SIZE``, which this project's sandboxes also export, changes
    no result: the same dgemm, dgemv and solve bytes at 512, 2048 and unset.)"""
    if os.environ.get("PLANTBENCH_DISPATCH", "").strip() == DISPATCH_HOST or not host_can_pin():
        return {}
    return {"OPENBLAS_CORETYPE": BLAS_PIN, "NPY_DISABLE_CPU_FEATURES": _numpy_avx512_names(),
            "OPENCV_CPU_DISABLE": _OPENCV_ABOVE_AVX2}


def pin_dispatch(env: dict | None = None) -> dict[str, str]:
    """Set :func:`dispatch_environment` in ``env`` (default ``os.environ``), over any value already there: machines
    set ``OPENBLAS_CORETYPE`` for their own reasons (this project's sandboxes export ``Haswell``), and a pin that
    gave way to them would not be one. ``PLANTBENCH_DISPATCH=host`` leaves the environment as it is (the
    variability study plays another CPU that way). Called when plantbench is imported, so it takes effect when
    numpy, SciPy and OpenCV are first loaded after it (the command line, every job process: a job's environment is
    pinned again, :func:`plantbench.runner.execute.job_environment`); a program that loaded numpy first keeps its
    dispatch (:func:`dispatch_seen` reads what it got). Returns the variables set."""
    env = os.environ if env is None else env
    new = dispatch_environment()
    env.update(new)
    return new


def dispatch_id() -> str:
    """The dispatch a job process gets (its environment is this one's with :func:`pin_dispatch` applied), for cache
    keys and records: 'blas:Haswell numpy:X86_V3 opencv:AVX2' when pinned; a library left to its own choice reads
    'auto' and the id then names the CPU, whose model decides. Read from the environment, not from the libraries
    this process loaded, so a program that imported numpy before plantbench plans the same keys as the command
    line (:func:`dispatch_seen` reads what was loaded)."""
    env = dict(os.environ)
    pinned = pin_dispatch(env)
    blas = env.get("OPENBLAS_CORETYPE") or "auto"
    npy = env.get("NPY_DISABLE_CPU_FEATURES", "")
    numpy_level = "auto" if not npy.strip() else NUMPY_PIN if npy == pinned.get("NPY_DISABLE_CPU_FEATURES") else (
        "without:" + ",".join(npy.split()))
    cv = env.get("OPENCV_CPU_DISABLE", "")
    opencv = "auto" if not cv.strip() else "AVX2" if cv == pinned.get("OPENCV_CPU_DISABLE") else f"without:{cv}"
    out = f"blas:{blas} numpy:{numpy_level} opencv:{opencv}"
    return out + (f" cpu:{host_cpu_name()}" if "auto" in out else "")


def dispatch_seen() -> str:
    """What OpenBLAS and numpy dispatch to in this process, read from the loaded libraries (threadpoolctl, numpy's
    CPU feature table): 'blas:Haswell numpy:X86_V3' (recorded in a capture's capture.json, by the job that made
    it)."""
    import scipy.linalg  # noqa: F401 - loads SciPy's own OpenBLAS (and numpy's), so that both cores are read
    from threadpoolctl import threadpool_info

    cores = sorted({str(i.get("architecture")) for i in threadpool_info() if i.get("internal_api") == "openblas"})
    try:
        from numpy._core._multiarray_umath import __cpu_features__ as features
    except ImportError:  # numpy < 2
        from numpy.core._multiarray_umath import __cpu_features__ as features
    level = "X86_V4" if features.get("X86_V4", features.get("AVX512_SKX")) else (
        "X86_V3" if features.get("X86_V3", features.get("AVX2")) else "baseline")
    if level == "X86_V4" and features.get("AVX512_ICL"):
        level += "+AVX512_ICL"
    return f"blas:{','.join(cores) or 'none'} numpy:{level}"
