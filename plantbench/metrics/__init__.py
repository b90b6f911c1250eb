"""Metrics: pure functions (ground truth first, options keyword-only, no I/O) and :func:`evaluate`, which reads a
case folder and a method's output folder and computes them all. Importing this package registers every metric's
:class:`MetricInfo` in :data:`plantbench.registry.metrics`.

Modules: :mod:`.stava` (S_T), :mod:`.surface` (mesh-to-scan), :mod:`.reprojection`, :mod:`.leaves`, :mod:`.points`
(point cloud and surface accuracy), :mod:`.skeleton`, :mod:`.evaluate` (I/O). Heavy backends (Open3D) are imported
inside the functions that use them.
"""

from __future__ import annotations

from plantbench.metrics.info import METRICS, MetricInfo
from plantbench.registry import metrics as _registry

__all__ = ["MetricInfo", "METRICS"]

for _name, _info in METRICS.items():
    _registry.register(_name, _info)
