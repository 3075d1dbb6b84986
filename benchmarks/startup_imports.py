"""CPU (user + sys) of each import ndf-sim makes before its solve, in the order it makes
them, then reading the napkin scene and `taichi_ndf.init`; one process, one table.

    python benchmarks/startup_imports.py          # from the repository root
"""

import resource
import sys
from pathlib import Path

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "napkin.toml"


def cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def main() -> None:
    rows = [("python start", cpu())]
    import numpy  # noqa: F401

    rows.append(("numpy", cpu()))
    import torch  # noqa: F401

    rows.append(("torch", cpu()))
    from taichi_ndf.runtime import language

    language()
    rows.append(("taichi (bound by taichi_ndf.runtime)", cpu()))
    import scipy.linalg  # noqa: F401
    import scipy.sparse  # noqa: F401

    rows.append(("scipy.linalg, scipy.sparse", cpu()))
    import cv2  # noqa: F401

    rows.append(("cv2", cpu()))
    from taichi_ndf.app import outputs, simulation  # noqa: F401
    from taichi_ndf.discretise import of_scene  # noqa: F401

    rows.append(("taichi_ndf's modules for ndf-sim (kernel decorations included)", cpu()))
    from taichi_ndf.scene.reader import load_scene

    load_scene(SCENE, field="spline")
    rows.append(("reading scenes/napkin.toml", cpu()))
    import taichi_ndf

    taichi_ndf.init()
    rows.append(("taichi_ndf.init (ti.init)", cpu()))
    print("| step | CPU s |\n|---|---|")
    last = 0.0
    for name, seconds in rows:
        print(f"| {name} | {seconds - last:.3f} |")
        last = seconds
    print(f"| total | {last:.3f} |")
    print(f"trimesh imported: {'trimesh' in sys.modules}, "
          f"matplotlib: {'matplotlib' in sys.modules}")


if __name__ == "__main__":
    main()
