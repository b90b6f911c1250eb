import subprocess
import sys


def test_import_is_light():
    """``import plantbench`` (the CLI's start-up) pulls in none of the heavy libraries; how long it takes is measured
    in bench/test_bench_import.py, beside numpy and scipy alone."""
    code = (
        "import sys; import plantbench; import plantbench.registry, plantbench.schemas;"
        "print([m for m in ('mitsuba', 'drjit', 'open3d', 'pycolmap', 'cv2', 'skimage') if m in sys.modules])"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]", out
