"""The method protocol and external-command methods.

A method is any object with

- ``name`` : str
- ``inputs`` : ``"views"`` (reads ``views/images`` + ``views/cameras.json``), ``"scan"`` (reads the coordinates of
  ``scan/scan.ply``) or ``"points"`` (reads ``points.ply`` of an earlier point stage: the ``mvs`` cloud for view
  captures, the scan's coordinates for scan captures)
- ``reconstruct(capture_dir, out_dir, *, seed, species=None, **options) -> None`` writing the output contract
  into ``out_dir``: ``skeleton.ply`` (required), ``mesh.ply``, ``leaves.json``, ``points.ply`` (optional).

``species`` is the one piece of prior knowledge a method may receive (the runner passes it as a hint);
``options`` are the suite's ``[method_options.NAME]`` keywords. For a ``"points"`` method, ``capture_dir`` holds
``points.ply`` and, for view captures, ``views/`` (images and cameras) beside it.
Methods must not read ground truth (``plant/``, ``views/depth``, ``views/instance``, the scan's labels) unless they
are explicitly named oracles.
"""

from __future__ import annotations

import os
import shlex
import subprocess
from pathlib import Path
from typing import Literal, Protocol, runtime_checkable

from plantbench.errors import InputError, PlantbenchError

__all__ = ["Method", "ExternalCommand", "INPUT_KINDS", "method_from_spec", "MethodFailed", "ORACLE_CLOUD",
           "split_cloud"]

INPUT_KINDS = ("views", "scan", "points")

ORACLE_CLOUD = "@oracle"
"""Suffix of a suite's method entry (``livny@oracle``): the point-cloud method on the mvs stage's oracle cloud (exact
depth, its default noise, fused as the estimated depth is) beside its cells on the mvs cloud: the stage-wise
attribution of issue 25 within one run. Such a cell reads ground truth through its cloud: it is marked an oracle."""


class MethodFailed(PlantbenchError):
    """A method ran and failed (non-zero exit, missing output)."""


@runtime_checkable
class Method(Protocol):
    name: str
    inputs: Literal["views", "scan", "points"]

    def reconstruct(
        self, capture_dir: Path, out_dir: Path, *, seed: int, species: str | None = None, **options
    ) -> None:  # pragma: no cover - protocol
        ...


class ExternalCommand:
    """A method given as a command line with ``{capture}``, ``{out}`` (and optional ``{seed}``, ``{species}``)
    placeholders, run without a shell: ``cmd:"my_tool --in {capture} --out {out}"``."""

    def __init__(self, command: str, *, inputs: str = "views", name: str | None = None) -> None:
        argv = shlex.split(command)
        if not argv:
            raise InputError("external method: empty command")
        if not any("{out}" in a for a in argv):
            raise InputError(f"external method '{command}': the command must contain the {{out}} placeholder")
        if inputs not in INPUT_KINDS:
            raise InputError(f"external method: inputs must be one of {INPUT_KINDS}, got {inputs!r}")
        self.argv = argv
        self.inputs = inputs
        self.name = name or "cmd:" + command

    def reconstruct(
        self, capture_dir: Path, out_dir: Path, *, seed: int, species: str | None = None, **options
    ) -> None:
        values = {"capture": str(capture_dir), "out": str(out_dir), "seed": str(seed), "species": species or ""}
        argv = [a.format(**values) for a in self.argv]
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        proc = subprocess.run(argv, capture_output=True, text=True, env=dict(os.environ))
        if proc.stdout:
            print(proc.stdout, end="")
        if proc.returncode != 0:
            raise MethodFailed(f"{self.name} exited {proc.returncode}: {proc.stderr.strip()[-2000:]}")


def split_cloud(spec: str) -> tuple[str, bool]:
    """(the method spec, whether it asks for the oracle cloud) of a suite's method entry: ``"livny@oracle"`` ->
    ``("livny", True)``, ``"livny"`` -> ``("livny", False)``. A ``cmd:`` spec is never split (its command line may
    hold any text)."""
    if not spec.startswith("cmd:") and spec.endswith(ORACLE_CLOUD):
        return spec[: -len(ORACLE_CLOUD)], True
    return spec, False


def method_from_spec(spec: str):
    """A registered method name, ``cmd:COMMAND`` for an external command, or ``ladder:RUNG`` for a rung of the
    calibration ladder (:mod:`plantbench.methods.ladder`). A suite's ``NAME@oracle`` entry is resolved by the runner
    (:func:`split_cloud`), not here."""
    if spec.startswith("cmd:"):
        return ExternalCommand(spec[4:])
    if spec.startswith("ladder:"):
        from plantbench.methods.ladder import ladder_method

        return ladder_method(spec)
    from plantbench.registry import methods

    return methods.get(spec)
