"""A material per panel with obstacles (issue 30): the two panels over the sphere of
tests/test_contact_panels.py (each 0.2 m square, 4 × 4 spans, outer edges clamped, seamed
along x = 0.2 m, a sphere of radius 5 cm under the seam, check grid 24² per panel, load steps
0.5, 1) with the panels' materials varied: one material; the same with the shell term forced
to a `PanelEnergy` of the two equal materials (the one-material `ShellEnergyTerm` switched off
in discretise/multipatch.py, as tests/test_contact_panel_materials.py does); the right panel
10 × as stiff (`stiffness_scale`, same density); both 10 × as stiff; the right panel denim.
Prints per case Π, Newton iterations per load step, convergence, rounds / check points, the
seam's gap, the mean sag (−u_z) of each panel over a 41² grid, CPU and wall of the solve; the
forced `PanelEnergy`'s differences from one material; load average and commit.

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python benchmarks/panel_materials_contact.py
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import torch

import taichi_ndf

ROOT = Path(__file__).resolve().parents[1]
STIFF = {"preset": "cotton_polyester", "stiffness_scale": 10}


def _solve(document: dict, *, panel_energy: bool = False):
    from test_contact_panels import _scene

    import taichi_ndf.discretise.multipatch as multipatch
    from taichi_ndf.discretise import of_scene

    scene = _scene(document)
    panels = of_scene(scene)
    panels.start(scene.solver, seed=0)
    one = multipatch.ShellEnergyTerm
    if panel_energy:
        multipatch.ShellEnergyTerm = lambda material, loads: None
    cpu, wall = time.process_time(), time.perf_counter()
    try:
        solution = panels.solve(scene.solver)
    finally:
        multipatch.ShellEnergyTerm = one
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    s = torch.linspace(0.0, 1.0, 41, dtype=torch.float64)
    xi = torch.stack(torch.meshgrid(0.2 * s, 0.2 * s, indexing="ij"), dim=-1).reshape(-1, 2)
    sag = [-1e3 * float(panels.displacement_of(i, xi)[:, 0, 2].mean()) for i in range(2)]
    c = torch.cat([f.coefficients.detach() for f in panels.fields])
    return solution, panels, sag, c, cpu, wall


def main() -> None:
    sys.path.insert(0, str(ROOT / "tests"))
    from test_contact_panels import _sheet

    taichi_ndf.init(arch="cpu", precision="f64", seed=0)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                            capture_output=True, text=True).stdout.strip()
    print(f"commit {commit}, load before {os.getloadavg()[0]:.2f}")

    def sheet(left=None, right=None) -> dict:
        document = _sheet()
        for panel, material in zip(document["panels"], (left, right), strict=True):
            if material is not None:
                panel["material"] = material
        return document

    cases = [("one material", sheet(), False),
             ("PanelEnergy, equal materials", sheet(), True),
             ("right × 10 stiffness", sheet(right=STIFF), False),
             ("both × 10 stiffness", sheet(STIFF, STIFF), False),
             ("right denim", sheet(right="denim"), False)]
    print("| case | Π [J] | iterations (0.5, 1) | converged | rounds / check points "
          "| seam gap [m] | mean sag left / right [mm] | CPU [s] | wall [s] |")
    print("|---|---|---|---|---|---|---|---|---|")
    results = []
    for name, document, forced in cases:
        solution, panels, sag, c, cpu, wall = _solve(document, panel_energy=forced)
        results.append((solution, c))
        steps = solution.document["load_steps"]
        print(f"| {name} | {solution.energy:.12g} | "
              f"{', '.join(str(s['iterations']) for s in steps)} ({solution.iterations}) | "
              f"{all(panels.converged)} | {solution.contact_counts['newton_rounds']} / "
              f"{solution.contact.count} | {max(solution.document['seam_gaps'].values()):.2g} "
              f"| {sag[0]:.3f} / {sag[1]:.3f} | {cpu:.2f} | {wall:.2f} |", flush=True)
    (a, ca), (b, cb) = results[0], results[1]
    print(f"PanelEnergy against one material: Π {abs(b.energy - a.energy) / abs(a.energy):.2g}"
          f" relative, coefficients {float((cb - ca).abs().max() / ca.abs().max()):.2g} of the "
          f"largest; load after {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
