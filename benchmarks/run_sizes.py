"""Peak memory and time of the sizes a scene sets, for the before-work size checks
(`taichi_ndf.problem.run_size`): spline grids (bytes per Gauss point, seconds per Newton iteration),
the contact check grid (bytes per check point) and SIREN training (bytes per sample × width).

Each case is `ndf-sim` in its own process; peak: ru_maxrss of that process (`os.wait4`, Linux
KiB), growth over the smallest case of its family, divided by the growth of the count.
Usage: python benchmarks/run_sizes.py [--quick]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

PLANE = """name = "size"
[geometry]
type = "plane"
bounds = [[0.0, 1.0], [0.0, 1.0]]
[material]
preset = "cloth"
[loads]
gravity = [0.0, 0.0, -9.81]
[[boundary.constraint]]
type = "clamped_edge"
edge = "xi1_min"
[output]
resolution = [8, 8]
"""
SPLINE = PLANE + """[field]
type = "spline"
spans = [{n}, {n}]
[training]
method = "newton"
newton_max_iterations = {iterations}
"""
CONTACT = SPLINE + """[[obstacles]]
type = "sphere"
centre = [0.5, 0.5, -0.3]
radius = 0.2
[contact]
check_resolution = {resolution}
"""
SIREN = PLANE + """[field]
width = {width}
hidden_layers = 3
[training]
iterations = 3
samples = {samples}
monitor_samples = {samples}
lbfgs_iterations = 0
"""


def measure(text: str, folder: Path) -> tuple[float, float]:
    """Peak RSS [bytes] and wall time [s] of ndf-sim on the scene `text`."""
    scene = folder / f"s{time.monotonic_ns()}.toml"
    scene.write_text(text)
    start = time.perf_counter()
    process = subprocess.Popen([sys.executable, "-m", "taichi_ndf.cli.sim", str(scene), "--out",
                                str(folder / scene.stem), "--precision", "f64"],
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(process.pid, 0)
    wall = time.perf_counter() - start
    if status != 0:
        raise RuntimeError(process.stderr.read().decode())
    return usage.ru_maxrss * 1024.0, wall


def family(name, texts, counts, unit, folder):
    """Measure and print one row per size as it comes."""
    print(f"\n{name}\n| {unit} | peak [MiB] | wall [s] | bytes per {unit} over the first |")
    print("|---|---|---|---|", flush=True)
    base = None
    for text, count in zip(texts, counts, strict=True):
        peak, wall = measure(text, folder)
        base = base or (count, peak)
        per = "" if count == base[0] else f"{(peak - base[1]) / (count - base[0]):.0f}"
        print(f"| {count} | {peak / 2**20:.0f} | {wall:.1f} | {per} |", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--families", default="spline,contact,siren",
                        help="comma-separated subset of spline, contact, siren")
    args = parser.parse_args()
    families = args.families.split(",")
    spans = (8, 48, 96) if args.quick else (8, 64, 128, 192)
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        if "spline" in families:
            family("spline, cubic, 4 x 4 Gauss points per span, 2 Newton iterations",
                   [SPLINE.format(n=n, iterations=2) for n in spans],
                   [16 * n * n for n in spans], "Gauss point", folder)
        # A check point close to the obstacle joins the solve's points (~19 kB each): 1024²
        # held 18.8 GB; keep the grid small.
        resolutions = (16, 128, 256)
        if "contact" in families:
            family("contact check grid (spline 8 x 8, 2 Newton iterations)",
                   [CONTACT.format(n=8, iterations=2, resolution=r) for r in resolutions],
                   [r * r for r in resolutions], "check point", folder)
        widths = ((16, 1024), (128, 4096), (256, 16384))
        if "siren" in families:
            family("SIREN, 3 hidden layers, 3 Adam iterations",
                   [SIREN.format(width=w, samples=s) for w, s in widths],
                   [w * s for w, s in widths], "sample x width", folder)


if __name__ == "__main__":
    main()
