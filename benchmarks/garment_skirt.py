"""The two-panel skirt (issue 30, "Garments") against the periodic one-patch skirt.

scenes/skirt_panels.toml: a front and a back panel, each a half-cylinder of radius 0.15 m and
length 0.4 m (cotton/polyester), sewn at both sides with bending transmitted, the waist
(ξ² = 0.4 m) clamped, gravity at load steps 0.5, 1 — solved by `MultiPatchDiscretisation`
(one projected Newton over both panels, float64) on n × m spans per panel; the reference is
the same skirt as one periodic cylinder (`[geometry] type = "cylinder"`, a whole turn, the same
waist clamped) on 2n × m spans by the spline path. Prints per grid: Π of both, their relative
difference, the largest displacement difference [m] over 25 × 7 points per panel (the back
panel's ξ¹ shifted by π: it is turned by π about z), the largest displacement, the seams'
largest gap, Newton iterations, convergence, CPU and wall time of each solve, load average,
commit.

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python benchmarks/garment_skirt.py [n m ...]

--four: scenes/skirt_four_panels.toml (four flat-cut knit panels, the waist gathered from a
0.1875 m onto a 0.15 m circle) on n × m spans per panel, and the same skirt with its waist
held on the wrap's circle (no `held_radius`): per case Π, Newton iterations, convergence, the
seams' largest gap, the waist's and the hem's radius (min / mean / max over 17 points per
panel) and the hem's mean height (placed at z = 0), CPU and wall time.

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python benchmarks/garment_skirt.py --four [n m ...]

--refine: the four-panel skirt (gathered; --refine-plain: its waist held on the wrap's
circle) on grids refined by 2 each (default 4 × 6, 8 × 12, 16 × 24 per panel): per grid Π,
the front and left panels' hem probes, the hem's radius per panel, the hem height, Newton
iterations per load step, convergence (Newton's own test at every load step), the seams'
gap, CPU, wall, load; then Richardson's observed order and extrapolation of Π and of the
mean hem radius (`taichi_ndf.minimise.extrapolation.richardson`, expected order 4).

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python benchmarks/garment_skirt.py --refine [n m ...]

--clamps: the two-panel skirt at rest wrapped (the `--flat` material, B = 1e-4 N·m) on 8 × 4,
16 × 8 and 32 × 16 spans per panel, its waist clamped by `ClampedEdge` (φ, the single-patch
clamp) against the same waist held as a flat-cut panel's is (`held_at_rest`): Π of both,
their relative difference, the largest distance between their deformed positions (13 × 5
points per panel), the largest displacement, Newton iterations, CPU and wall.

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python benchmarks/garment_skirt.py --clamps

--flat: the two-panel skirt cut flat (`rest = "flat"`: the wrap is the panels' start)
against the same skirt at rest wrapped (`held_at_rest`: the same hold of the waist), 16 × 8
spans per panel, a linear isotropic material (D = 6.4 N/m, ν = 0.25, ρ_A = 0.144 kg/m²) of
bending stiffness B = 7.68e-7 ("cloth"), 1e-4 and 3e-4 N·m: Π of both, their difference
against the wrapped bending energy ½ B (1/R)² × area, the largest distance between the two
skirts' deformed positions (13 × 5 points per panel), Newton iterations, CPU and wall.

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python benchmarks/garment_skirt.py --flat
"""

from __future__ import annotations

import dataclasses
import math
import os
import resource
import sys
import time
import tomllib
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from provenance import commit  # noqa: E402

import taichi_ndf  # noqa: E402
from taichi_ndf.boundary import BoundaryConditions  # noqa: E402
from taichi_ndf.discretise import of_scene  # noqa: E402
from taichi_ndf.problem.start_shape import StartShape  # noqa: E402
from taichi_ndf.scene.reader import parse_scene  # noqa: E402

SCENE = ROOT / "scenes" / "skirt_panels.toml"
FOUR = ROOT / "scenes" / "skirt_four_panels.toml"
GRIDS = ((16, 8), (32, 8))
FOUR_GRIDS = ((8, 12), (12, 18))
REFINE_GRIDS = ((4, 6), (8, 12), (16, 24))


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _solve(scene):
    d = of_scene(scene)
    cpu, wall = _cpu(), time.perf_counter()
    d.start(scene.solver, seed=0)
    solution = d.solve(scene.solver)
    d.check_solution(solution)
    return d, solution, _cpu() - cpu, time.perf_counter() - wall


def periodic_document(garment: dict, spans) -> dict:
    """The garment's skirt as one periodic cylinder on (2 n, m) spans."""
    front = garment["panels"][0]
    return {"name": "skirt_periodic", "material": garment["material"],
            "loads": garment["loads"],
            "geometry": {"type": "cylinder", "radius": front["wrap_radius"],
                         "length": front["height"]},
            "boundary": {"constraint": [{"type": "clamped_edge", "edge": "xi2_max"}]},
            "field": {"type": "spline", "spans": [2 * spans[0], spans[1]]},
            "training": garment["training"]}


def flat_document(rest: str, bending: float, spans=(16, 8)) -> dict:
    """The two-panel skirt with its panels' rest shape `rest` ("placed" or "flat") and a
    linear isotropic material of bending stiffness `bending` [N·m] (module docstring)."""
    document = tomllib.loads(SCENE.read_text())
    document["field"]["spans"] = list(spans)
    document["material"] = {"type": "linear", "membrane_stiffness": 6.4,
                            "bending_stiffness": bending, "poisson_ratio": 0.25,
                            "areal_density": 0.144}
    for panel in document["panels"]:
        panel.pop("probes", None)
        panel["rest"] = rest
    return document


def held_at_rest(scene):
    """The garment scene with each panel's clamp replaced by a flat-cut panel's hold (the
    clamped edges' position and slope kept, `Patch.held`) and its start its rest shape:
    the support of a flat-cut panel, so that the two differ only in their rest shapes."""
    patches = []
    for patch in scene.field.patches:
        edges = tuple(c.edge for c in patch.model.boundary.constraints)
        free = BoundaryConditions([], domain=patch.model.surface.domain)
        patches.append(dataclasses.replace(patch, model=dataclasses.replace(
            patch.model, boundary=free), start=StartShape("rigid"), held=edges))
    return dataclasses.replace(scene, field=dataclasses.replace(scene.field,
                                                                patches=tuple(patches)))


def _grid_xi(panels) -> torch.Tensor:
    """13 × 5 points (θ, z) of a wrapped panel's chart (65, 2)."""
    _, (lo, hi) = panels.spec.patches[0].model.surface.domain.bounds
    theta = torch.linspace(0.0, math.pi, 13, dtype=torch.float64)
    z = torch.linspace(lo, hi, 5, dtype=torch.float64)
    return torch.stack(torch.meshgrid(theta, z, indexing="ij"), dim=-1).reshape(-1, 2)


def positions(panels, radius: float, flat: bool, *, rest: bool = False) -> torch.Tensor:
    """Deformed positions (2 × 65, 3) [m] of both panels at `_grid_xi` of the placed sector
    (a flat-cut panel's ξ¹ is the arc length R θ); rest: the rest positions instead."""
    xi = _grid_xi(panels)
    if flat:
        xi = xi * torch.tensor([radius, 1.0], dtype=torch.float64)
    return torch.cat([panels.spec.patches[i].model.surface.jets(xi)[:, 0]
                      + (0.0 if rest else panels.displacement_of(i, xi)[:, 0])
                      for i in range(2)])


def flat_row(bending: float) -> str:
    """One row of the flat-cut table."""
    placed, reference, cpu0, wall0 = _solve(held_at_rest(parse_scene(
        flat_document("placed", bending), base_dir=SCENE.parent, path=SCENE)))
    document = flat_document("flat", bending)
    flat, solution, cpu, wall = _solve(parse_scene(document, base_dir=SCENE.parent,
                                                   path=SCENE))
    radius, height = document["panels"][0]["wrap_radius"], document["panels"][0]["height"]
    wrapped = 0.5 * bending / radius ** 2 * 2 * math.pi * radius * height
    x_placed = positions(placed, radius, False)
    shape = float((positions(flat, radius, True) - x_placed).norm(dim=1).max())
    u = float((x_placed - positions(placed, radius, False, rest=True)).norm(dim=1).max())
    difference = solution.energy - reference.energy
    return (f"| {bending:.3g} | {reference.energy:.6g} | {solution.energy:.6g} | "
            f"{difference:.4g} | {wrapped:.4g} | {difference / wrapped - 1:+.1%} | "
            f"{shape * 1e3:.3f} | {u * 1e3:.2f} | {reference.iterations} / "
            f"{solution.iterations} | {cpu0:.1f} / {cpu:.1f} | {wall0:.1f} / {wall:.1f} |")


def run(spans) -> dict:
    garment = tomllib.loads(SCENE.read_text())
    garment["field"]["spans"] = list(spans)
    panels, panel_solution, panel_cpu, panel_wall = _solve(
        parse_scene(garment, base_dir=SCENE.parent, path=SCENE))
    periodic_scene = parse_scene(periodic_document(garment, spans), base_dir=SCENE.parent)
    periodic, solution, cpu, wall = _solve(periodic_scene)
    dt = torch.float64
    theta = torch.linspace(0.0, math.pi, 25, dtype=dt)
    xi = torch.stack(torch.meshgrid(theta, torch.linspace(0.0, 0.4, 7, dtype=dt),
                                    indexing="ij"), dim=-1).reshape(-1, 2)
    difference, largest = 0.0, 0.0
    for i in range(2):
        u = panels.displacement_of(i, xi)[:, 0]
        at = xi + torch.tensor([math.pi * i, 0.0], dtype=dt)
        reference = periodic.displacement(at, 1.0)[:, 0]
        difference = max(difference, float((u - reference).norm(dim=1).max()))
        largest = max(largest, float(reference.norm(dim=1).max()))
    return {"spans": spans, "energy": panel_solution.energy, "reference": solution.energy,
            "relative": abs(panel_solution.energy - solution.energy) / abs(solution.energy),
            "difference": difference, "largest": largest,
            "gap": max(panel_solution.document["seam_gaps"].values()),
            "iterations": panel_solution.iterations, "converged": all(panels.converged),
            "cpu": panel_cpu, "wall": panel_wall, "reference_iterations": solution.iterations,
            "reference_cpu": cpu, "reference_wall": wall}


def _rim(panels, height: float) -> torch.Tensor:
    """Deformed positions (4 × 17, 3) [m] of every panel's edge at ξ² = height."""
    out = []
    for i, patch in enumerate(panels.spec.patches):
        (lo, hi), _ = patch.model.surface.domain.bounds
        s = torch.linspace(lo, hi, 17, dtype=torch.float64)
        xi = torch.stack((s, torch.full_like(s, height)), dim=1)
        out.append(patch.model.surface.jets(xi)[:, 0] + panels.displacement_of(i, xi)[:, 0])
    return torch.cat(out)


def _solve_four(spans, gathered: bool):
    """The four-panel skirt's scene document on `spans` per panel (its waist gathered, or not:
    no `held_radius`) and its solve (`_solve`: panels, solution, CPU, wall)."""
    garment = tomllib.loads(FOUR.read_text())
    garment["field"]["spans"] = list(spans)
    if not gathered:
        for panel in garment["panels"]:
            del panel["held_radius"]
    return garment, _solve(parse_scene(garment, base_dir=FOUR.parent, path=FOUR))


def four(spans, gathered: bool) -> str:
    """One row of the four-panel table."""
    garment, (panels, solution, cpu, wall) = _solve_four(spans, gathered)
    height = garment["panels"][0]["height"]
    waist, hem = (_rim(panels, z)[:, :2].norm(dim=1) for z in (height, 0.0))
    z = float(_rim(panels, 0.0)[:, 2].mean())
    return (f"| {spans[0]} × {spans[1]} | {'0.15' if gathered else 'none'} | "
            f"{solution.energy:.6g} | {solution.iterations} | {all(panels.converged)} | "
            f"{max(solution.document['seam_gaps'].values()):.1e} | {float(waist.min()):.4f} / "
            f"{float(waist.max()):.4f} | {float(hem.min()):.4f} / {float(hem.mean()):.4f} / "
            f"{float(hem.max()):.4f} | {z * 1e3:.2f} | {cpu:.1f} | {wall:.1f} |")


def refinement_row(spans, gathered: bool = True) -> dict:
    """The four-panel skirt on `spans` per panel: Π, the front and left hem probes, the hem's
    radius per panel (min / max over 17 points), Newton iterations per load step and
    convergence (Newton's own test at every load step), CPU and wall."""
    _, (panels, solution, cpu, wall) = _solve_four(spans, gathered)
    hem = _rim(panels, 0.0)
    radius = hem[:, :2].norm(dim=1).reshape(4, -1)
    steps = solution.document["load_steps"]
    return {"spans": spans, "energy": solution.energy, "probes": solution.probes,
            "radius": radius, "hem_z": float(hem[:, 2].mean()),
            "iterations": [s["iterations"] for s in steps],
            "converged": [s["converged"] for s in steps],
            "gap": max(solution.document["seam_gaps"].values()), "cpu": cpu, "wall": wall,
            "load": os.getloadavg()[0], "eigenvalues": lowest_eigenvalues(panels)}


def lowest_eigenvalues(panels, count: int = 4) -> list[float]:
    """The `count` lowest eigenvalues of the exact Hessian of Π, over the mean of its
    diagonal's magnitudes (its scale), at the panels' solution at load factor 1, over the
    unknowns Newton steps (`HeldEdges`: Tᵀ K T without its held rows; seams sewn from the
    start, one material): the solve's own objective rebuilt as
    `MultiPatchDiscretisation.solve` builds it. A negative one: the state is a saddle; near
    0: a buckling mode."""
    import numpy as np
    import scipy.sparse.linalg as spla

    from taichi_ndf.discretise.panel_energy import SewnFromStart
    from taichi_ndf.minimise.newton import NewtonConfig
    from taichi_ndf.minimise.point_blocks import PointBlocks, coupled_blocks
    from taichi_ndf.objective import Objective, ShellEnergyTerm
    from taichi_ndf.objective.seam import SeamTerm
    from taichi_ndf.problem.loads import Loads

    spec, linear = panels.spec, panels._linear
    patches = spec.patches
    seams = [SeamTerm(s.spec, patches[s.a].model.surface, spec.seam_material(s),
                      surface_b=patches[s.b].model.surface).between(linear.rows(s.a),
                                                                     linear.rows(s.b))
             for s in spec.seams]
    start = linear.displacement(panels._start)
    objective = Objective(ShellEnergyTerm(spec.materials[0], Loads(gravity=spec.gravity)),
                          tuple(SewnFromStart(t, start) for t in seams))
    potential = objective.potential(1.0)
    c = torch.cat([f.coefficients.detach() for f in panels.fields])
    u = linear.displacement(c)
    blocks = PointBlocks(linear, potential, c, u, NewtonConfig().fd_step)
    matrix = linear.hessian(blocks, coupled_blocks(potential, linear.samples, u))
    free = np.ones(matrix.shape[0], dtype=bool)
    free[linear.fixed] = False
    reduced = matrix[free][:, free].tocsc()
    reduced = 0.5 * (reduced + reduced.T)
    scale = float(np.abs(reduced.diagonal()).mean())
    values = spla.eigsh(reduced, k=count, sigma=-1e-9 * scale, which="LM",
                        return_eigenvectors=False)
    return sorted(float(v) / scale for v in values)


def refinement_table(grids, gathered: bool = True) -> None:
    """`--refine`: the four-panel skirt on grids refined by 2 each (module docstring), then
    Richardson's order and extrapolation of Π and of the mean hem radius
    (`minimise.extrapolation.richardson`)."""
    from taichi_ndf.minimise.extrapolation import richardson

    print(f"waist held on {'0.15 m (gathered)' if gathered else 'the wrap (not gathered)'}")
    print("| spans per panel | Π [J] | front hem u [mm] | left hem u [mm] | hem radius min / "
          "max per panel [m] | hem height [mm] | Newton it. per load step | converged | "
          "seam gap [m] | CPU [s] | wall [s] | load | lowest eigenvalues of K / mean diag |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    rows = []
    for spans in grids:
        r = refinement_row(spans, gathered)
        rows.append(r)
        probe = {k: " ".join(f"{1e3 * v:+.2f}" for v in r["probes"][f"{k}.hem"])
                 for k in ("front", "left")}
        radius = ", ".join(f"{float(x.min()):.4f} / {float(x.max()):.4f}" for x in r["radius"])
        print(f"| {spans[0]} × {spans[1]} | {r['energy']:.7g} | {probe['front']} | "
              f"{probe['left']} | {radius} | {1e3 * r['hem_z']:.2f} | "
              f"{' '.join(map(str, r['iterations']))} | {all(r['converged'])} | "
              f"{r['gap']:.1e} | {r['cpu']:.1f} | {r['wall']:.1f} | {r['load']:.1f} | "
              f"{' '.join(f'{v:.3g}' for v in r['eigenvalues'])} |", flush=True)
    if len(rows) >= 2:
        converged = [all(r["converged"]) for r in rows]
        for name, values, order in (
                ("Π [J]", [r["energy"] for r in rows], 4.0),
                ("mean hem radius [m]", [float(r["radius"].mean()) for r in rows], 4.0)):
            e = richardson(values, order=order, converged=converged)
            changes = " ".join(f"{b - a:+.4g}" for a, b in zip(values, values[1:], strict=False))
            print(f"{name}: changes {changes}; Richardson {e.describe()}")


def clamp_row(spans) -> str:
    """`--clamps`: one row of the two-panel skirt at rest wrapped (B = 1e-4 N·m) with its
    waist clamped by `ClampedEdge` (φ) against the same waist held (`held_at_rest`)."""
    document = flat_document("placed", 1e-4, spans)
    scenes = [parse_scene(document, base_dir=SCENE.parent, path=SCENE) for _ in range(2)]
    a, sa, ca, wa = _solve(scenes[0])
    b, sb, cb, wb = _solve(held_at_rest(scenes[1]))
    xa, xb = positions(a, 0.15, False), positions(b, 0.15, False)
    u = float((xa - positions(a, 0.15, False, rest=True)).norm(dim=1).max())
    return (f"| {spans[0]} × {spans[1]} | {sa.energy:.7g} | {sb.energy:.7g} | "
            f"{(sb.energy - sa.energy) / abs(sa.energy):+.2e} | "
            f"{1e3 * float((xa - xb).norm(dim=1).max()):.3f} | {1e3 * u:.2f} | "
            f"{sa.iterations} / {sb.iterations} | {ca:.1f} / {cb:.1f} | {wa:.1f} / {wb:.1f} |")


def main() -> None:
    taichi_ndf.init(arch="cpu", precision="f64")
    torch.set_num_threads(1)
    if sys.argv[1:2] == ["--flat"]:
        print(f"commit {commit()}, load average {os.getloadavg()[0]:.1f} (start)")
        print("| B [N·m] | Π wrapped rest [J] | Π cut flat [J] | ΔΠ [J] | ½ B/R² × area [J] | "
              "ΔΠ / (½ B/R² A) − 1 | max \\|x_flat − x_wrapped\\| [mm] | max \\|u\\| "
              "wrapped [mm] | Newton it. wrapped / flat | CPU wrapped / flat [s] | "
              "wall wrapped / flat [s] |")
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        for bending in (7.68e-7, 1e-4, 3e-4):
            print(flat_row(bending), flush=True)
        print(f"load average {os.getloadavg()[0]:.1f} (end)")
        return
    if sys.argv[1:2] == ["--clamps"]:
        print(f"commit {commit()}, load average {os.getloadavg()[0]:.1f} (start)")
        print("| spans per panel | Π `ClampedEdge` [J] | Π held [J] | (Π_held − Π_φ)/\\|Π_φ\\| | "
              "max \\|Δx\\| [mm] | max \\|u\\| [mm] | Newton it. φ / held | CPU φ / held [s] | "
              "wall φ / held [s] |")
        print("|---|---|---|---|---|---|---|---|---|")
        for spans in ((8, 4), (16, 8), (32, 16)):
            print(clamp_row(spans), flush=True)
        print(f"load average {os.getloadavg()[0]:.1f} (end)")
        return
    if sys.argv[1:2] in (["--refine"], ["--refine-plain"]):
        args = [int(v) for v in sys.argv[2:]]
        grids = tuple(zip(args[::2], args[1::2], strict=True)) if args else REFINE_GRIDS
        print(f"commit {commit()}, load average {os.getloadavg()[0]:.1f} (start)")
        refinement_table(grids, gathered=sys.argv[1] == "--refine")
        print(f"load average {os.getloadavg()[0]:.1f} (end)")
        return
    if sys.argv[1:2] == ["--four"]:
        args = [int(v) for v in sys.argv[2:]]
        grids = tuple(zip(args[::2], args[1::2], strict=True)) if args else FOUR_GRIDS
        print(f"commit {commit()}, load average {os.getloadavg()[0]:.1f} (start)")
        print("| spans per panel | waist held on [m] | Π [J] | Newton it. | converged | "
              "seam gap [m] | waist radius min / max [m] | hem radius min / mean / max [m] | "
              "hem height [mm] | CPU [s] | wall [s] |")
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        for spans in grids:
            for gathered in (True, False):
                print(four(spans, gathered), flush=True)
        print(f"load average {os.getloadavg()[0]:.1f} (end)")
        return
    args = [int(v) for v in sys.argv[1:]]
    grids = tuple(zip(args[::2], args[1::2], strict=True)) if args else GRIDS
    print(f"commit {commit()}, load average {os.getloadavg()[0]:.1f} (start)")
    print("| spans per panel | Π panels [J] | Π periodic [J] (2n × m) | Π rel. diff. | "
          "max |u − u_periodic| [m] | max |u| [m] | seam gap [m] | Newton it. panels / "
          "periodic | converged | CPU panels [s] | wall panels [s] | CPU periodic [s] | "
          "wall periodic [s] |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for spans in grids:
        r = run(spans)
        print(f"| {spans[0]} × {spans[1]} | {r['energy']:.8g} | {r['reference']:.8g} | "
              f"{r['relative']:.2e} | {r['difference']:.2e} | {r['largest']:.3e} | "
              f"{r['gap']:.1e} | {r['iterations']} / {r['reference_iterations']} | "
              f"{r['converged']} | {r['cpu']:.1f} | {r['wall']:.1f} | {r['reference_cpu']:.1f} | "
              f"{r['reference_wall']:.1f} |", flush=True)
    print(f"load average {os.getloadavg()[0]:.1f} (end)")


if __name__ == "__main__":
    main()
