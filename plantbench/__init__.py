"""plantbench: a benchmark suite with synthetic ground truth for 3D plant reconstruction.

Importing the package is cheap: heavy backends (Mitsuba, Open3D, pycolmap) are imported where they are used.
"""

from importlib.metadata import PackageNotFoundError, version

from plantbench.backend import pin_dispatch

# before numpy, SciPy or OpenCV is loaded: their CPU dispatch pinned to AVX2 kernels (docs/tuning/determinism.md)
pin_dispatch()

try:
    __version__ = version("plantbench")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
