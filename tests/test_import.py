import subprocess
import sys


def test_import_is_light_and_fast():
    code = (
        "import time, sys; t = time.perf_counter(); import plantbench; import plantbench.registry, plantbench.schemas;"
        "dt = time.perf_counter() - t;"
        "heavy = [m for m in ('mitsuba', 'drjit', 'open3d', 'pycolmap', 'cv2', 'skimage') if m in sys.modules];"
        "print(dt, heavy)"
    )
    best = min(
        float(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()[0])
        for _ in range(3)
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip().endswith("[]"), out
    assert best < 0.5, best
