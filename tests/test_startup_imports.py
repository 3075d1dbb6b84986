"""What a solve imports (issue 28, start-up): ndf-sim's modules leave the picture and contact
libraries unimported until a picture or a self-contact search needs them, and binding the
Taichi language after torch no longer scans sys.modules once per Taichi-internal decorator.
Each check runs in a fresh interpreter (the test session has imported everything)."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _run(code: str) -> str:
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout.strip().splitlines()[-1]


def test_the_sim_modules_do_not_import_pictures_meshes_or_kd_trees():
    lazy = ("matplotlib", "cv2", "trimesh", "networkx", "scipy.spatial", "scipy.optimize")
    loaded = _run("import sys\n"
                  "import taichi_ndf.cli.sim, taichi_ndf.app.simulation, taichi_ndf.discretise\n"
                  "import taichi_ndf.render, taichi_ndf.contact\n"
                  f"print(sorted(m for m in {lazy!r} if m in sys.modules))")
    assert loaded == "[]"


def test_the_colour_map_is_made_on_first_use_and_is_opencvs_viridis():
    shown = _run("import sys\n"
                 "import numpy as np\n"
                 "from taichi_ndf.render import mpl\n"
                 "before = 'cv2' in sys.modules\n"
                 "import cv2\n"
                 "ramp = np.arange(256, dtype=np.uint8)[:, None]\n"
                 "same = np.array_equal(mpl.VIRIDIS_BGR, "
                 "cv2.applyColorMap(ramp, cv2.COLORMAP_VIRIDIS)[:, 0])\n"
                 "print(before, same, mpl.VIRIDIS_BGR.shape, mpl.viridis_bgr() is mpl.VIRIDIS_BGR)")
    assert shown == "False True (256, 3) True"


def test_binding_the_language_after_torch_scans_no_frame_info():
    """Taichi decorates ~90 functions of its own while it is imported; each asked
    `inspect.getframeinfo` (a walk of sys.modules, ~3 000 entries once torch is in) until the
    runtime patched `_inside_class` as its module ran."""
    calls = _run("import inspect, torch\n"
                 "calls = []\n"
                 "own = inspect.getframeinfo\n"
                 "inspect.getframeinfo = lambda *a, **k: (calls.append(1), own(*a, **k))[1]\n"
                 "from taichi_ndf import runtime\n"
                 "ti = runtime.language()\n"
                 "impl = __import__(ti.__name__ + '.lang.kernel_impl', fromlist=['x'])\n"
                 "print(len(calls), impl._inside_class.__module__)")
    assert calls == "0 taichi_ndf.runtime"
