"""The pins of OpenBLAS's, numpy's and OpenCV's CPU dispatch (plantbench.backend.pin_dispatch;
docs/tuning/determinism.md): they reach every process plantbench starts, whatever the machine's environment says,
and they matter (the same product gives other bytes under another OpenBLAS core)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from plantbench.backend import dispatch_environment, dispatch_id, host_can_pin, host_has, pin_dispatch

pytestmark = pytest.mark.skipif(not host_can_pin(), reason="the pins are for x86-64 CPUs with AVX2")

_PROBE = """
import json, hashlib
import plantbench
import numpy as np
from plantbench.backend import dispatch_seen
from plantbench.cameras import look_at
r = np.random.default_rng(0)
a, b = r.normal(size=(300, 200)), r.normal(size=(200, 250))
cams = [look_at(r.uniform(-3, 3, 3), r.uniform(-0.1, 0.1, 3), fov_x_deg=40, width=64, height=64) for _ in range(50)]
print(json.dumps({"seen": dispatch_seen(), "bytes": hashlib.sha256((a @ b).tobytes() + np.exp(a).tobytes()
      + b"".join(c.t.tobytes() for c in cams)).hexdigest()}))
"""


def _probe(**env) -> dict:
    full = {k: v for k, v in os.environ.items() if k not in env}
    full.update({k: v for k, v in env.items() if v is not None})
    for k in [k for k, v in env.items() if v is None]:
        full.pop(k, None)
    out = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, env=full, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_pin_overrides_what_the_environment_says_and_host_leaves_it():
    env = {"OPENBLAS_CORETYPE": "SkylakeX", "NPY_DISABLE_CPU_FEATURES": ""}
    pin_dispatch(env)
    assert env == dispatch_environment() and env["OPENBLAS_CORETYPE"] == "Haswell"
    pinned = _probe(OPENBLAS_CORETYPE="SkylakeX", NPY_DISABLE_CPU_FEATURES="", PLANTBENCH_DISPATCH=None)
    assert pinned["seen"] == "blas:Haswell numpy:X86_V3"
    assert pinned == _probe(OPENBLAS_CORETYPE=None, NPY_DISABLE_CPU_FEATURES=None, PLANTBENCH_DISPATCH=None)


@pytest.mark.skipif(not host_has("+avx512f,+avx512dq,+avx512vl,+avx512bw"), reason="plays an AVX-512 CPU")
def test_the_pin_matters_another_core_gives_other_bytes():
    pinned = _probe(PLANTBENCH_DISPATCH=None)
    skx = _probe(PLANTBENCH_DISPATCH="host", OPENBLAS_CORETYPE="SkylakeX")
    assert skx["seen"].startswith("blas:SkylakeX") and skx["bytes"] != pinned["bytes"]
    avx512 = _probe(PLANTBENCH_DISPATCH="host", OPENBLAS_CORETYPE="Haswell", NPY_DISABLE_CPU_FEATURES="")
    assert "X86_V4" in avx512["seen"] and avx512["bytes"] != pinned["bytes"]


def test_keys_name_the_dispatch_jobs_get_not_what_this_process_loaded(monkeypatch):
    from plantbench.runner.execute import job_environment

    assert dispatch_id() == "blas:Haswell numpy:X86_V3 opencv:AVX2"
    job = job_environment(1)
    assert {k: job[k] for k in dispatch_environment()} == dispatch_environment()
    monkeypatch.setenv("PLANTBENCH_DISPATCH", "host")
    monkeypatch.setenv("OPENBLAS_CORETYPE", "SkylakeX")
    monkeypatch.delenv("NPY_DISABLE_CPU_FEATURES", raising=False)
    host = dispatch_id()
    assert host.startswith("blas:SkylakeX numpy:auto") and " cpu:" in host
    assert job_environment(1)["OPENBLAS_CORETYPE"] == "SkylakeX"
