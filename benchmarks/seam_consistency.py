"""Seams (issue 30): a tube seamed to itself against the periodic tube, the penalty's error,
and sewing a cylinder sector shut. Spline field + projected Newton, float64, one thread.

Parts (`--parts`):
- refinement: scenes/tube_seam.toml (a tube cut open along θ = 0, seamed with bending
  transmitted; clamped top rim, a pinch by two line loads, gravity) and the same tube with
  angle 360° (periodic, no seam) and with a hinge seam, on n1 × n2 spans: Π of each, the
  relative differences, the largest displacement difference on a 97 × 13 grid of ξ, the
  largest seam gap, CPU and wall per solve;
- annulus: a flat annulus clamped at its inner rim, loaded on part of its outer rim, whole
  (periodic in θ) against slit along θ = 0 and seamed (edges xi2_min / xi2_max), both
  bendings, on n_ρ × n_θ spans: the same columns;
- halves: the tube as two half-cylinder spline patches in one Newton
  (`MultiPatchLinearisation`), joined by two seams with bending transmitted, against the
  periodic tube on the same span density;
- penalty: the seamed tube on one grid with the seam's penalty factor β = 1e2 … 1e6: the
  gap, |Π_seamed − Π_periodic| / |Π_periodic| and the displacement difference (∝ 1/β while
  the penalty's error dominates the discretisation's);
- sewing: a 300° cylinder sector (its edges 0.1 m apart at rest) held at one point opposite
  the cut, sewn shut by a hinge seam over load steps 0.1 … 1.0 (the seam's rest gap closes
  with the load factor): the largest gap after each step.

- diagnosis (not in the default parts): why the seamed tube differs from the periodic one on
  a coarse grid: on the --penalty-spans grid the seamed and the periodic tube with the Newton
  tolerance loosened to 1e-8 and tightened to 1e-15, the seam's quadrature raised to 256 × 6
  points and β to 1e5; then on the --spans grids both tubes' Π, the seamed tube's jump of
  ∂²u/∂θ² across the seam (the periodic spline has none), and each one's distance from the
  periodic tube's Richardson value.

CPU: user + sys of this process (`resource.getrusage`) per solve; load: the 1-minute load
average after the solve (the machine is shared).

    python benchmarks/seam_consistency.py [--parts refinement,annulus,halves,penalty,sewing]
        [--spans 8x2,16x4,32x8,64x16] [--annulus-spans 4x16,8x32,16x64] [--halves-spans 32x8,64x16]
        [--penalty-spans 32x8] [--factors 1e2,1e3,1e4,1e5,1e6]
"""

from __future__ import annotations

import argparse
import copy
import math
import os
import resource
import sys
import time
import tomllib
from pathlib import Path

import torch

import taichi_ndf
from taichi_ndf.boundary import BoundaryConditions, ClampedEdge
from taichi_ndf.field.spline import SplineConfig, SplineField
from taichi_ndf.geometry import Cylinder
from taichi_ndf.minimise.assembly import displacement_at
from taichi_ndf.minimise.linearisation import GridLinearisation
from taichi_ndf.minimise.multipatch import MultiPatchLinearisation
from taichi_ndf.minimise.newton import NewtonConfig, minimise
from taichi_ndf.objective import Objective, ShellEnergyTerm
from taichi_ndf.objective.seam import SeamTerm, with_seam_points
from taichi_ndf.problem.line_loads import LineLoad
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.quadrature import span_quadrature
from taichi_ndf.problem.seams import EdgeSegment, SeamSpec
from taichi_ndf.scene.reader import parse_scene
from taichi_ndf.solve.spline_solver import solve_spline

ROOT = Path(__file__).resolve().parents[1]

sys.path.insert(0, str(Path(__file__).resolve().parent))
from provenance import commit  # noqa: E402  (the commit each benchmark states)


def cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def tube_document() -> dict:
    return tomllib.loads((ROOT / "scenes" / "tube_seam.toml").read_text())


def variant(document: dict, kind: str, spans, penalty: float | None = None) -> dict:
    """The tube as `kind`: "periodic" (360°, no seam), "transmitted" or "hinge"."""
    document = copy.deepcopy(document)
    document["field"]["spans"] = list(spans)
    if kind == "periodic":
        document["geometry"]["angle_deg"] = 360.0
        del document["seams"]
    else:
        document["seams"][0]["bending"] = kind
        if penalty is not None:
            document["seams"][0]["stiffness"] = penalty
    return document


def solve(document: dict) -> dict:
    scene = parse_scene(document, base_dir=ROOT / "scenes")
    cpu, wall = cpu_seconds(), time.perf_counter()
    run = solve_spline(scene.model, scene.field, scene.solver)
    cpu, wall = cpu_seconds() - cpu, time.perf_counter() - wall
    return {"scene": scene, "run": run, "cpu": cpu, "wall": wall, "load": os.getloadavg()[0],
            "converged": all(lv.converged for lv in run.levels),
            "iterations": sum(lv.iterations for lv in run.levels)}


def displacements(result: dict, theta_max: float, length: float) -> torch.Tensor:
    """u (97 · 13, 3) [m] on a grid of ξ over θ ∈ [0, theta_max], z ∈ [0, length]."""
    theta = torch.linspace(0.0, theta_max, 97, dtype=torch.float64)
    z = torch.linspace(0.0, length, 13, dtype=torch.float64)
    xi = torch.stack(torch.meshgrid(theta, z, indexing="ij"), dim=-1).reshape(-1, 2)
    return result["scene"].model.displacement(result["run"].field, xi)


def seam_gap(result: dict) -> float:
    """The largest |x_A − x_B| [m] over the seam's Gauss points (0 without a seam)."""
    model, field = result["scene"].model, result["run"].field
    seams = [t for t in model.terms if isinstance(t, SeamTerm)]
    if not seams:
        return 0.0
    samples = with_seam_points(span_quadrature(model.surface, field.config, None,
                                               dtype=torch.float64), seams)
    operator = model.operator(field)
    u = operator.jets(samples.xi)
    return max(float(s.gaps(samples, u).max()) for s in seams)


def compare(seamed: dict, periodic: dict) -> tuple[float, float]:
    """(|Π_s − Π_p| / |Π_p|, max |u_s − u_p| [m]) on the seamed domain's grid."""
    surface = seamed["scene"].model.surface
    (_, theta_max), (_, length) = surface.domain.bounds
    du = displacements(seamed, theta_max, length) - displacements(periodic, theta_max, length)
    energy = periodic["run"].energy
    return abs(seamed["run"].energy - energy) / abs(energy), float(du.norm(dim=1).max())


def refinement(spans_list) -> None:
    print("\n### Tube seamed to itself against the periodic tube (scenes/tube_seam.toml)\n")
    print("| spans | Π periodic [J] | max |u| periodic [m] | Π seamed [J] | rel. diff | "
          "max |Δu| [m] | seam gap max [m] | Π hinge [J] | hinge rel. diff | hinge max |Δu| "
          "[m] | CPU p / s / h [s] | wall p / s / h [s] | load |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    document = tube_document()
    for spans in spans_list:
        results = {k: solve(variant(document, k, spans))
                   for k in ("periodic", "transmitted", "hinge")}
        p, s, h = results["periodic"], results["transmitted"], results["hinge"]
        rel, du = compare(s, p)
        rel_h, du_h = compare(h, p)
        flags = "".join("" if r["converged"] else f" ({k} not converged)"
                        for k, r in results.items())
        (_, top), (_, length) = p["scene"].model.surface.domain.bounds
        largest = float(displacements(p, top, length).norm(dim=1).max())
        print(f"| {spans[0]}×{spans[1]} | {p['run'].energy:.10g} | {largest:.4f} | "
              f"{s['run'].energy:.10g} | "
              f"{rel:.2e} | {du:.2e} | {seam_gap(s):.2e} | {h['run'].energy:.10g} | "
              f"{rel_h:.2e} | {du_h:.2e} | {p['cpu']:.1f} / {s['cpu']:.1f} / {h['cpu']:.1f} | "
              f"{p['wall']:.1f} / {s['wall']:.1f} / {h['wall']:.1f} | {h['load']:.1f} |{flags}",
              flush=True)


def annulus_document(kind: str, spans) -> dict:
    """A flat annulus (radii 0.05 m and 0.15 m, the 2 mm rubber of tube_seam) clamped at its
    inner rim, under gravity and a line load of 0.5 N/m downwards along the outer rim from
    θ = 0.2 to 0.6 rad: "periodic" (no slit) or slit along θ = 0 and seamed (`kind` the
    seam's bending)."""
    document = {
        "name": "annulus_seam",
        "geometry": {"type": "annulus", "inner_radius": 0.05, "outer_radius": 0.15,
                     "slit": kind != "periodic"},
        "material": {"type": "linear", "young_modulus": 5e6, "poisson_ratio": 0.3,
                     "thickness": 2e-3, "areal_density": 2.0},
        "loads": {"gravity": [0.0, 0.0, -9.81],
                  "line": [{"path": [[0.15, 0.2], [0.15, 0.6]], "force": [0.0, 0.0, -0.5]}]},
        "boundary": {"constraint": [{"type": "clamped_edge", "edge": "xi1_min"}]},
        "field": {"type": "spline", "spans": list(spans)},
        "training": {"method": "newton", "load_steps": [0.5, 1.0]}}
    if kind != "periodic":
        document["seams"] = [{"name": "slit", "a": "xi2_min", "b": "xi2_max",
                              "bending": kind}]
    return document


def annulus_displacements(result: dict) -> torch.Tensor:
    """u (9 · 97, 3) [m] on a grid of ξ over ρ ∈ [0.05, 0.15], θ ∈ [0, 2π]."""
    rho = torch.linspace(0.05, 0.15, 9, dtype=torch.float64)
    theta = torch.linspace(0.0, 2 * math.pi, 97, dtype=torch.float64)
    xi = torch.stack(torch.meshgrid(rho, theta, indexing="ij"), dim=-1).reshape(-1, 2)
    return result["scene"].model.displacement(result["run"].field, xi)


def annulus(spans_list) -> None:
    print("\n### Slit annulus seamed along θ = 0 against the whole annulus\n")
    print("| spans (ρ × θ) | Π whole [J] | max |u| whole [m] | Π seamed [J] | rel. diff | max "
          "|Δu| [m] | seam gap max [m] | Π hinge [J] | hinge rel. diff | hinge max |Δu| [m] | "
          "CPU w / s / h [s] | wall w / s / h [s] | load |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for spans in spans_list:
        results = {k: solve(annulus_document(k, spans))
                   for k in ("periodic", "transmitted", "hinge")}
        p, s, h = results["periodic"], results["transmitted"], results["hinge"]
        u = annulus_displacements(p)
        energy = p["run"].energy
        rows = [(abs(r["run"].energy - energy) / abs(energy),
                 float((annulus_displacements(r) - u).norm(dim=1).max())) for r in (s, h)]
        flags = "".join("" if r["converged"] else f" ({k} not converged)"
                        for k, r in results.items())
        print(f"| {spans[0]}×{spans[1]} | {energy:.10g} | {float(u.norm(dim=1).max()):.4f} | "
              f"{s['run'].energy:.10g} | {rows[0][0]:.2e} | {rows[0][1]:.2e} | "
              f"{seam_gap(s):.2e} | {h['run'].energy:.10g} | {rows[1][0]:.2e} | "
              f"{rows[1][1]:.2e} | {p['cpu']:.1f} / {s['cpu']:.1f} / {h['cpu']:.1f} | "
              f"{p['wall']:.1f} / {s['wall']:.1f} / {h['wall']:.1f} | {h['load']:.1f} |{flags}",
              flush=True)


def two_halves(spans) -> dict:
    """The tube of tube_seam.toml as two half-cylinder patches (θ ∈ [0, π] and, turned by π
    about z, [π, 2π]), each on n1/2 × n2 spans with its top rim clamped and its pinch line,
    joined by two seams with bending transmitted (`MultiPatchLinearisation`), solved by the
    one Newton at load factors 0.5 and 1: Π, u on both halves' 49 × 13 grids of ξ, the
    largest gap, CPU and wall."""
    document = tube_document()
    material = parse_scene(document, base_dir=ROOT / "scenes").model.material
    radius, length = document["geometry"]["radius"], document["geometry"]["length"]
    gravity = tuple(document["loads"]["gravity"])
    halves = [Cylinder(radius=radius, length=length, angle=math.pi),
              Cylinder(radius=radius, length=length, angle=math.pi,
                       frame=((-1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, 1.0)))]
    pinch = [LineLoad(((0.5, 0.0), (0.5, length)), tuple(line["force"]))
             for line in document["loads"]["line"]]  # θ = 0.5 on each half's own ξ
    seams = [SeamTerm(SeamSpec(f"s{i}", EdgeSegment("xi1_max"), EdgeSegment("xi1_min")),
                      halves[i], material, surface_b=halves[1 - i]) for i in range(2)]
    grids = []
    for i, surface in enumerate(halves):
        field = SplineField(SplineConfig(spans=(spans[0] // 2, spans[1]),
                                         domain=surface.domain.bounds), dtype=torch.float64)
        grid = GridLinearisation(field, BoundaryConditions([ClampedEdge("xi2_max")],
                                                           domain=surface.domain),
                                 length=math.sqrt(surface.domain.rectangle_area))
        points = GridLinearisation.quadrature(surface, field.config,
                                              Loads(gravity=gravity, line_loads=(pinch[i],)),
                                              dtype=torch.float64)
        grid.assemble(points.joined(seams[i].points(0)).joined(seams[1 - i].points(1)))
        grids.append(grid)
    cpu, wall = cpu_seconds(), time.perf_counter()
    length_scale = math.sqrt(halves[0].domain.rectangle_area)
    linear = MultiPatchLinearisation(grids, 1.0, length=length_scale)
    terms = (seams[0].between(linear.rows(0), linear.rows(1)),
             seams[1].between(linear.rows(1), linear.rows(0)))
    objective = Objective(ShellEnergyTerm(material, Loads(gravity=gravity)), terms)
    coefficients = torch.zeros(linear.coefficient_offsets[-1], 3, dtype=torch.float64)
    converged, iterations = True, 0
    for step in document["training"]["load_steps"]:
        linear = MultiPatchLinearisation(grids, step, length=length_scale)
        solution = minimise(linear, objective.potential(step), coefficients, NewtonConfig())
        coefficients = solution.parameters
        converged &= solution.converged
        iterations += len(solution.history)
    cpu, wall = cpu_seconds() - cpu, time.perf_counter() - wall
    theta = torch.linspace(0.0, math.pi, 49, dtype=torch.float64)
    z = torch.linspace(0.0, length, 13, dtype=torch.float64)
    xi = torch.stack(torch.meshgrid(theta, z, indexing="ij"), dim=-1).reshape(-1, 2)
    u = [displacement_at(grid.operator, xi, coefficients[linear.coefficient_offsets[i]:
                                                         linear.coefficient_offsets[i + 1]],
                         1.0)[:, 0] for i, grid in enumerate(grids)]
    gap = max(float(t.gaps(linear.samples, linear.displacement(coefficients)).max())
              for t in terms)
    return {"energy": solution.energy, "u": u, "xi": xi, "gap": gap, "cpu": cpu, "wall": wall,
            "converged": converged, "iterations": iterations, "load": os.getloadavg()[0]}


def halves(spans_list) -> None:
    print("\n### Two half-cylinder patches seamed into the tube against the periodic tube\n")
    print("| spans (whole tube) | Π periodic [J] | Π two halves [J] | rel. diff | max |Δu| [m] "
          "| seam gap max [m] | Newton iterations | CPU p / halves [s] | wall p / halves [s] "
          "| load |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    document = tube_document()
    for spans in spans_list:
        periodic = solve(variant(document, "periodic", spans))
        joined = two_halves(spans)
        model, field = periodic["scene"].model, periodic["run"].field
        shifted = joined["xi"] + torch.tensor([math.pi, 0.0], dtype=torch.float64)
        du = max(float((joined["u"][0] - model.displacement(field, joined["xi"]))
                       .norm(dim=1).max()),
                 float((joined["u"][1] - model.displacement(field, shifted)).norm(dim=1).max()))
        energy = periodic["run"].energy
        print(f"| {spans[0]}×{spans[1]} | {energy:.10g} | {joined['energy']:.10g} | "
              f"{abs(joined['energy'] - energy) / abs(energy):.2e} | {du:.2e} | "
              f"{joined['gap']:.2e} | {joined['iterations']} | {periodic['cpu']:.1f} / "
              f"{joined['cpu']:.1f} | {periodic['wall']:.1f} / {joined['wall']:.1f} | "
              f"{joined['load']:.1f} |{'' if joined['converged'] else ' (not converged)'}",
              flush=True)


def penalty(spans, factors) -> None:
    print(f"\n### Penalty factor β on {spans[0]}×{spans[1]} spans (bending transmitted)\n")
    print("| β | k_x [N/m²] | seam gap max [m] | rel. diff Π | max |Δu| [m] | Newton "
          "iterations | CPU [s] | wall [s] | load |")
    print("|---|---|---|---|---|---|---|---|---|")
    document = tube_document()
    periodic = solve(variant(document, "periodic", spans))
    for beta in factors:
        s = solve(variant(document, "transmitted", spans, penalty=beta))
        rel, du = compare(s, periodic)
        term = next(t for t in s["scene"].model.terms if isinstance(t, SeamTerm))
        print(f"| {beta:.0e} | {term.position_stiffness:.3g} | {seam_gap(s):.2e} | {rel:.2e} | "
              f"{du:.2e} | {s['iterations']} | {s['cpu']:.1f} | {s['wall']:.1f} | "
              f"{s['load']:.1f} |{'' if s['converged'] else ' (not converged)'}", flush=True)


def sewing(spans) -> None:
    print(f"\n### Sewing a 300° sector shut (hinge seam, {spans[0]}×{spans[1]} spans)\n")
    document = tube_document()
    document["geometry"]["angle_deg"] = 300.0
    document["loads"] = {}
    document["boundary"] = {"constraint": [
        {"type": "pinned_point", "xi": [math.radians(150.0), 0.15], "rotation": "held"}]}
    document["seams"][0]["bending"] = "hinge"
    document["field"]["spans"] = list(spans)
    steps = [round(0.1 * k, 1) for k in range(1, 11)]
    document["training"]["load_steps"] = steps
    del document["probes"]
    scene = parse_scene(document, base_dir=ROOT / "scenes")
    term = next(t for t in scene.model.terms if isinstance(t, SeamTerm))
    rest = term.gaps(term.points(), torch.zeros(len(term.xi), 6, 3, dtype=torch.float64))
    cpu, wall = cpu_seconds(), time.perf_counter()
    run = solve_spline(scene.model, scene.field, scene.solver)
    cpu, wall = cpu_seconds() - cpu, time.perf_counter() - wall
    print(f"rest gap max {float(rest.max()):.4f} m; after the last step: seam gap max "
          f"{seam_gap({'scene': scene, 'run': run}):.2e} m; Π {run.energy:.6g} J; converged "
          f"{all(lv.converged for lv in run.levels)}; Newton iterations "
          f"{sum(lv.iterations for lv in run.levels)}; CPU {cpu:.1f} s, wall {wall:.1f} s, "
          f"load {os.getloadavg()[0]:.1f}")
    print("\n| load factor | Π [J] | converged |")
    print("|---|---|---|")
    for step in run.load_steps:
        print(f"| {step['load_factor']} | {step['energy']:.6g} | {step['converged']} |")


def curvature_jump(result: dict) -> tuple[float, float]:
    """(max over z of |∂²u/∂θ²(0, z) − ∂²u/∂θ²(θ_max, z)|, max |∂²u/∂θ²| over the 97 × 13
    grid) [m/rad²] of a seamed tube: the seam ties u and ∂u/∂θ, not the curvature, which
    the periodic spline keeps continuous."""
    from taichi_ndf import jets

    model, field = result["scene"].model, result["run"].field
    (_, theta_max), (_, length) = model.surface.domain.bounds
    z = torch.linspace(0.0, length, 13, dtype=torch.float64)
    ends = [torch.stack((torch.full_like(z, t), z), dim=1) for t in (0.0, theta_max)]
    a, b = (model.displacement_jets(field, xi)[:, jets.D11] for xi in ends)
    theta = torch.linspace(0.0, theta_max, 97, dtype=torch.float64)
    xi = torch.stack(torch.meshgrid(theta, z, indexing="ij"), dim=-1).reshape(-1, 2)
    whole = model.displacement_jets(field, xi)[:, jets.D11]
    return float((a - b).norm(dim=1).max()), float(whole.norm(dim=1).max())


def diagnosis(spans_list, one) -> None:
    """Why the seamed tube differs from the periodic one on a coarse grid (module
    docstring, "diagnosis")."""
    from taichi_ndf.minimise.extrapolation import richardson

    print("\n### The seamed tube's difference from the periodic tube: tolerance, seam "
          "quadrature, penalty, grid\n")
    document = tube_document()
    print(f"On {one[0]}×{one[1]} spans: each variant against the periodic tube solved with the "
          "same Newton tolerance.\n")
    print("| variant | Π periodic [J] | Π seamed [J] | rel. diff | max |Δu| [m] | Newton it. "
          "p / s | CPU p / s [s] | load |")
    print("|---|---|---|---|---|---|---|---|")
    base = {}
    for name, change, seam in (
            ("as shipped (λ²/2 ≤ 1e-12 |Π|, 64 × 4 seam points, β = 1e4)", {}, {}),
            ("Newton tolerance 1e-8", {"newton_tolerance": 1e-8}, {}),
            ("Newton tolerance 1e-15", {"newton_tolerance": 1e-15}, {}),
            ("seam quadrature 256 × 6 points", {}, {"segments": 256, "nodes": 6}),
            ("β = 1e5", {}, {"stiffness": 1e5})):
        docs = {}
        for kind in ("periodic", "transmitted"):
            d = variant(document, kind, one)
            d["training"].update(change)
            if kind != "periodic":
                d["seams"][0].update(seam)
            docs[kind] = d
        key = json_key(docs["periodic"])
        p = base[key] if key in base else solve(docs["periodic"])
        base[key] = p
        s = solve(docs["transmitted"])
        rel, du = compare(s, p)
        print(f"| {name} | {p['run'].energy:.10g} | {s['run'].energy:.10g} | {rel:.3e} | "
              f"{du:.2e} | {p['iterations']} / {s['iterations']} | {p['cpu']:.1f} / "
              f"{s['cpu']:.1f} | {s['load']:.1f} |", flush=True)
    print("\nUnder refinement (as shipped): each discretisation's Π against the Richardson "
          "value of the periodic tube's, and the seamed tube's curvature jump at the seam.\n")
    print("| spans | Π periodic [J] | Π seamed [J] | rel. diff | Π_s − Π_p [J] | "
          "curvature jump at the seam / max |∂²u/∂θ²| | CPU p / s [s] | load |")
    print("|---|---|---|---|---|---|---|---|")
    periodic, seamed = [], []
    for spans in spans_list:
        p = solve(variant(document, "periodic", spans))
        s = solve(variant(document, "transmitted", spans))
        rel, _ = compare(s, p)
        jump, largest = curvature_jump(s)
        periodic.append(p["run"].energy)
        seamed.append(s["run"].energy)
        print(f"| {spans[0]}×{spans[1]} | {periodic[-1]:.10g} | {seamed[-1]:.10g} | {rel:.3e} | "
              f"{seamed[-1] - periodic[-1]:+.3e} | {jump / largest:.3e} | {p['cpu']:.1f} / "
              f"{s['cpu']:.1f} | {s['load']:.1f} |", flush=True)
    if len(periodic) >= 3:
        limit = richardson(periodic)
        print(f"\nΠ periodic extrapolated: {limit.describe('J')}")
        for spans, p, s in zip(spans_list, periodic, seamed, strict=True):
            off = [abs(v - limit.value) / abs(limit.value) for v in (p, s)]
            print(f"{spans[0]}×{spans[1]}: periodic off by {off[0]:.2e}, seamed by "
                  f"{off[1]:.2e} (relative)")


def json_key(document: dict) -> str:
    import json

    return json.dumps(document, sort_keys=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--parts", default="refinement,annulus,halves,penalty,sewing")
    parser.add_argument("--halves-spans", default="32x8,64x16")
    parser.add_argument("--annulus-spans", default="4x16,8x32,16x64")
    parser.add_argument("--spans", default="8x2,16x4,32x8,64x16")
    parser.add_argument("--penalty-spans", default="32x8")
    parser.add_argument("--factors", default="1e2,1e3,1e4,1e5,1e6")
    args = parser.parse_args()
    spans = [tuple(int(v) for v in s.split("x")) for s in args.spans.split(",")]
    one = tuple(int(v) for v in args.penalty_spans.split("x"))
    taichi_ndf.init(arch="cpu", precision="f64", seed=0)
    torch.set_num_threads(1)
    print(f"commit {commit()}, float64, one thread, load {os.getloadavg()[0]:.1f} at start")
    parts = args.parts.split(",")
    if "refinement" in parts:
        refinement(spans)
    if "annulus" in parts:
        annulus([tuple(int(v) for v in s.split("x")) for s in args.annulus_spans.split(",")])
    if "halves" in parts:
        halves([tuple(int(v) for v in s.split("x")) for s in args.halves_spans.split(",")])
    if "penalty" in parts:
        penalty(one, [float(f) for f in args.factors.split(",")])
    if "sewing" in parts:
        sewing(one)
    if "diagnosis" in parts:
        diagnosis(spans, one)


if __name__ == "__main__":
    main()
