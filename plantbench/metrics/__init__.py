"""Metrics: pure functions (ground truth first, options keyword-only, no I/O) and :func:`evaluate`, which reads a
case folder and a method's output folder and computes them all. The table of metrics (name, unit, direction,
definition) is :data:`plantbench.metrics.info.METRICS`; :data:`plantbench.registry.metrics` serves it.

Modules: :mod:`.stava` (S_T), :mod:`.surface` (mesh-to-scan), :mod:`.reprojection`, :mod:`.leaves`, :mod:`.points`
(point cloud and surface accuracy), :mod:`.skeleton`, :mod:`.structure` (branch-level matching), :mod:`.info` (the
table), :mod:`.evaluate` (I/O). Heavy backends (Open3D) are imported inside the functions that use them.

This file imports nothing: a method that uses a metric helper (the mvs stage's distances, guo's silhouettes) imports
only that module, so its cache key (:func:`plantbench.runner.plan.code_hash`) does not change when a metric is added
to the table.
"""
