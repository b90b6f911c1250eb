"""Capture: multi-view rendering with exact ground-truth maps and cameras, and simulated laser scans.

``capture_case(case_dir, settings, seed=...)`` is the entry point (:mod:`plantbench.capture.capture`). Importing
this package is cheap: Mitsuba and open3d are imported only when rendering or ray casting.
"""

from plantbench.capture.capture import capture_case, is_complete
from plantbench.capture.settings import CaptureOptions, as_options

__all__ = ["capture_case", "is_complete", "CaptureOptions", "as_options"]
