"""Dr.Jit's LLVM code generation and Mitsuba's Embree are pinned, so renders and mvs depth maps do not depend on the
machine's CPU.

Each child process starts as if on another CPU (Dr.Jit's target set to a pretend host before plantbench loads it),
renders a small plant with Mitsuba and estimates one mvs depth map, and prints hashes of the outputs. With the pin
(the default) the pretend hosts give identical bytes; without it (``PLANTBENCH_LLVM_TARGET=host``) they differ,
which shows the comparison can fail. The pretend hosts run on any x86-64 CPU with AVX2; on an AVX-512 CPU the
16-wide host target is tried too.

What a pretend host cannot show, another vendor's approximate instructions, is checked on what reaches the CPU: the
pinned kernels hold no approximate x86 intrinsic (``rsqrt``/``rcp``, whose bits differ between CPUs; Dr.Jit's log
of the kernels' LLVM IR) and Embree receives the pinned configuration, which changes its kernels (an AVX-512 host
told to use AVX2 renders other bytes).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys

import pytest

from plantbench.backend import EMBREE_PIN, EMBREE_REQUIRES, PINNED_TARGET, find_libllvm, host_can_pin, host_has
from plantbench.paths import project_root

AVX2_WIDTH_4 = PINNED_TARGET.spec()[: -len(str(PINNED_TARGET.width))] + "4"
AVX512_WIDTH_16 = ("skylake-avx512:+avx512f,+avx512dq,+avx512vl,+avx512bw,+avx512cd,+avx2,+avx,+fma,+f16c,+bmi,+bmi2,"
                   "+popcnt,+sse4.2:16")

CHILD = r"""
import hashlib, json, os, sys
from pathlib import Path
import numpy as np
from plantbench import backend
os.environ["DRJIT_LIBLLVM_PATH"] = backend.find_libllvm()
import drjit as dr
dr.set_log_level(dr.LogLevel.Trace)                               # the kernels' LLVM IR, logged to stdout
if len(sys.argv) > 3:
    backend.EMBREE_PIN = sys.argv[3]                              # another Embree configuration
cpu, features, width = sys.argv[1].split(":")
set_target = backend._jit_core(dr)[0]
set_target(cpu.encode(), features.encode(), int(width))           # the pretend host's own choice

from PIL import Image
from plantbench.cameras import read_cameras
from plantbench.capture import CaptureOptions, capture_case
from tests.capture.plants import write_test_plant
from reference_impl.mvs.neighbours import depth_range, scene_centre
from reference_impl.mvs.params import DepthParams
from reference_impl.mvs.patchmatch import estimate_depth

case = Path(sys.argv[2])
write_test_plant(case, height=2.0)
capture_case(case, CaptureOptions(views=6, width=96, height=96, spp=4, elevation=(20.0, 20.0), scan=False), seed=3)
out = {"target": backend.current_llvm_target(dr).spec(), "fast_math": bool(dr.flag(dr.JitFlag.FastMath)),
       "embree": backend.embree_config_seen()}
for sub in ("images", "depth"):
    h = hashlib.sha256()
    for f in sorted((case / "views" / sub).iterdir()):
        h.update(f.read_bytes())
    out[sub] = h.hexdigest()

# mvs on the rendered views: view 0 against its two neighbours on the ring
cams, names = read_cameras(case / "views" / "cameras.json")
imgs = [np.asarray(Image.open(case / "views" / "images" / n)) for n in names]
near, far = depth_range(cams[0], scene_centre(cams), 1.25)
dm = estimate_depth(imgs[0], [imgs[1], imgs[5]], cams[0], [cams[1], cams[5]], (near, far),
                    DepthParams(hypotheses=32, pm_iterations=1), rng=np.random.default_rng(0))
out["mvs_depth"] = hashlib.sha256(np.ascontiguousarray(dm.depth).tobytes()).hexdigest()
out["mvs_finite"] = int(np.isfinite(dm.depth).sum())
print(json.dumps(out))
"""

pytestmark = pytest.mark.skipif(
    not host_can_pin() or not find_libllvm(),
    reason="needs an x86-64 CPU with AVX2 and LLVM 19 (the pinned target)")


APPROXIMATE = re.compile(r"llvm\.x86\.[a-z0-9]+\.(?:rsqrt|rcp)[a-z0-9.]*")
"""x86 intrinsics whose results the ISA bounds but does not fix (AVX's rsqrt.ps / rcp.ps; AVX-512's 14-bit ones)."""


def _child(host: str, folder, *, pin: bool = True, embree: str | None = None) -> dict:
    env = dict(os.environ, PYTHONPATH=str(project_root()), PLANTBENCH_THREADS="1")
    env.pop("PLANTBENCH_LLVM_TARGET", None)
    if not pin:
        env["PLANTBENCH_LLVM_TARGET"] = "host"
    args = [host, str(folder)] + ([embree] if embree else [])
    proc = subprocess.run([sys.executable, "-c", CHILD, *args], capture_output=True, text=True,
                          env=env, timeout=600, cwd=project_root())
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    log = proc.stdout + proc.stderr
    out["approximate"] = sorted(set(APPROXIMATE.findall(log)))
    out["kernels_logged"] = log.count("define void @drjit_")
    return out


AVX512 = host_has(EMBREE_REQUIRES)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    hosts = [AVX2_WIDTH_4, PINNED_TARGET.spec()] + ([AVX512_WIDTH_16] if AVX512 else [])
    base = tmp_path_factory.mktemp("llvm")
    pinned = {h: _child(h, base / f"pinned{i}") for i, h in enumerate(hosts)}
    unpinned = {h: _child(h, base / f"host{i}", pin=False) for i, h in enumerate(hosts[:2])}
    return pinned, unpinned


def test_pinned_kernels_hold_no_approximate_instruction(runs):
    """Fast math off: ``dr.rsqrt`` and divisions compile to IEEE sqrt and division, exact on every CPU. Unpinned
    (Dr.Jit's default FastMath), the same renders use ``rsqrt.ps``: the search finds what it looks for."""
    pinned, unpinned = runs
    for host, out in pinned.items():
        assert out["kernels_logged"] > 5 and not out["fast_math"], host
        assert out["approximate"] == [], f"pretend host {host}: {out['approximate']}"
    assert any(out["approximate"] for out in unpinned.values())
    assert all(out["fast_math"] for out in unpinned.values())


@pytest.mark.skipif(not AVX512, reason="the Embree pin needs AVX-512 (EMBREE_REQUIRES)")
def test_embree_receives_the_pinned_configuration_and_it_matters(runs, tmp_path):
    pinned, unpinned = runs
    for host, out in pinned.items():
        calls, config = out["embree"]
        assert calls >= 1 and config.endswith("," + EMBREE_PIN) and config.startswith("threads="), host
    assert all(out["embree"] is None for out in unpinned.values())   # 'host' leaves Embree alone
    other = _child(PINNED_TARGET.spec(), tmp_path / "avx2", embree="isa=avx2")
    assert other["embree"][1].endswith(",isa=avx2")
    assert other["images"] != pinned[PINNED_TARGET.spec()]["images"]


def test_pinned_outputs_do_not_depend_on_the_host_target(runs):
    pinned, _ = runs
    first = next(iter(pinned.values()))
    assert first["mvs_finite"] > 500  # the depth map is not empty
    same = ("images", "depth", "mvs_depth", "mvs_finite")
    for host, out in pinned.items():
        assert out["target"] == PINNED_TARGET.spec(), host
        assert {k: out[k] for k in same} == {k: first[k] for k in same}, f"pretend host {host} gave other outputs"


def test_unpinned_outputs_do_depend_on_it(runs):
    """Without the pin, AVX2 at width 4 and at width 8 give other renders and so other mvs depth: the comparison
    above would catch a pin that did not take. The exact depth maps are ray cast, not shaded: identical either way."""
    _, unpinned = runs
    four, eight = unpinned[AVX2_WIDTH_4], unpinned[PINNED_TARGET.spec()]
    assert four["target"].endswith(":4") and eight["target"].endswith(":8")
    assert four["images"] != eight["images"]
    assert four["mvs_depth"] != eight["mvs_depth"]
    assert four["depth"] == eight["depth"]


def test_target_spec_from_the_environment(monkeypatch):
    from plantbench.backend import LLVMTarget, requested_llvm_target
    from plantbench.errors import InputError

    monkeypatch.delenv("PLANTBENCH_LLVM_TARGET", raising=False)
    assert requested_llvm_target() == PINNED_TARGET
    monkeypatch.setenv("PLANTBENCH_LLVM_TARGET", "host")
    assert requested_llvm_target() is None
    monkeypatch.setenv("PLANTBENCH_LLVM_TARGET", "x86-64-v2:+sse4.2,+popcnt:4")
    assert requested_llvm_target() == LLVMTarget("x86-64-v2", "+sse4.2,+popcnt", 4)
    for bad in ("haswell", "haswell:+avx2:6", "haswell:+avx2:eight"):
        monkeypatch.setenv("PLANTBENCH_LLVM_TARGET", bad)
        with pytest.raises(InputError, match="PLANTBENCH_LLVM_TARGET"):
            requested_llvm_target()


def test_embree_pin_that_cannot_be_built_warns_and_leaves_embree(monkeypatch, tmp_path):
    from plantbench import backend

    monkeypatch.setenv("PLANTBENCH_CACHE", str(tmp_path))
    monkeypatch.setenv("CC", str(tmp_path / "no-such-cc"))
    with pytest.warns(backend.BackendWarning, match="no-such-cc"):
        assert backend._embree_pin_library() is None
    monkeypatch.setenv("CC", "false")                   # fails without a word
    with pytest.warns(backend.BackendWarning, match="exit status 1"):
        assert backend._embree_pin_library() is None
    if backend.requested_embree_config() is not None:   # records and cache keys do not claim a pin that is not there
        with pytest.warns(backend.BackendWarning):
            assert backend.llvm_target_id().endswith(" exact-math embree:host")
    assert not list(tmp_path.rglob("*.so")) and not list(tmp_path.rglob("*.tmp"))
    monkeypatch.delenv("CC")
    blocked = tmp_path / "a-file"
    blocked.write_text("")
    monkeypatch.setenv("PLANTBENCH_CACHE", str(blocked))   # the cache cannot be made: a warning, not a crash
    with pytest.warns(backend.BackendWarning, match="a-file"):
        assert backend._embree_pin_library() is None
    monkeypatch.setenv("PLANTBENCH_CACHE", str(tmp_path))
    built = backend._embree_pin_library()
    assert built is not None and built.parent.parent == tmp_path and backend._embree_pin_library() == built
    if backend.requested_embree_config() is not None:
        assert backend.llvm_target_id().endswith(" embree:" + backend.EMBREE_PIN)
