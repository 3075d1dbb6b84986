"""Validation against published shell benchmarks (`../shared/spec/benchmarks.md`).

A *case* is a scene file of `validation/scenes/` plus what to read from the trained field: one
or more *quantities* (a displacement component at a probe, a change of distance between two
probes, …), each at a load factor, with its published reference value and tolerance.

Two protocols beyond the scene itself:

- Linear references (plate, roof, cylinder, hemisphere) are values of *linear* shell theory,
  while the solver's kinematics are exact (geometrically nonlinear). A linear case is therefore
  solved in the linear regime: loads × 1/ε and stiffnesses × 1/ε² with ε = `LINEARISATION`
  (1e-3) give displacements ε times the linear ones (~1e-3 of the thickness, so nonlinear terms
  are ~1e-6 of the linear ones) at an unchanged potential energy — which keeps Π, its gradient
  and the optimisers' absolute tolerances as in the scene — and the read displacements are
  divided by ε; the field's output scale is multiplied by ε. At the nominal load the
  immovable-edge plate (w ≈ h/2) stiffens by membrane action, which is physics, not error.
- The end moment of the roll-up cantilever is not a scene load. It is added here as the
  potential of a conservative moment about the y axis: Π_M = −M θ_end, where θ_end, the end
  rotation of the strip's tangent in the xz plane, is measured exactly for any size of rotation
  as ∫ θ_,1 dξ¹ (averaged over the width), θ_,1 = (t_x t′_z − t_z t′_x)/|t|² with
  t = x_,1, t′ = x_,11; θ = 0 at the clamped root. About a fixed axis this "follower" moment is
  exactly conservative, so M θ_end is its work at any rotation (a pair of dead point loads
  would not be). No prescribed end rotation is needed and the tip displacement stays free.
  For a tangent in the xz plane |t|² = t_x² + t_z², the exact rotation rate. Out of that
  plane the full |t|² keeps the rate at most the curvature |t × t′|/|t|² (for a unit tangent
  at angle α to the y axis it is sin α × the curvature); with t_x² + t_z² it would be the
  winding of the tangent's projection, 1/sin α × the curvature, so tilting the strip out of
  its plane would gain moment work cheaply: at λ = 1 Newton found such a state, tip
  u_y = 1.29, Π 1.2 % below the exact circle's.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import platform
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from taichi_ndf import jets
from taichi_ndf.field import NeuralField
from taichi_ndf.io import OutputDir
from taichi_ndf.model import ShellModel
from taichi_ndf.objective import EndMomentTerm, Objective
from taichi_ndf.render import plot_curves, save_png
from taichi_ndf.scene import Scene, load_scene
from taichi_ndf.solver import Solver, SolverConfig

log = logging.getLogger(__name__)

SCENES_DIR = Path(__file__).resolve().parents[1] / "validation" / "scenes"
# Displacement scale ε of the linear-regime solve of a linear case (module docstring).
LINEARISATION = 1e-3

# Probe displacements u [m] (3,) and reference positions r [m] (3,) by probe name.
Readings = dict[str, np.ndarray]


@dataclass(frozen=True)
class Quantity:
    """A scalar read from the field at a load factor and its published reference.

    name: short label, e.g. "W" or "w_centre".
    description: what it is, in words.
    reference: published value.
    tolerance: admissible relative error (0.01 = 1 %).
    read: function (displacements, reference positions) -> value, both by probe name.
    level: load factor (of the case's load steps) at which it is read.
    """

    name: str
    description: str
    reference: float
    tolerance: float
    read: Callable[[Readings, Readings], float]
    level: float = 1.0

    def __post_init__(self):
        if not (math.isfinite(self.reference) and self.reference != 0.0):
            raise ValueError(f"quantity {self.name}: reference must be finite and non-zero")
        if not 0 < self.tolerance < 1:
            raise ValueError(f"quantity {self.name}: tolerance must be in (0, 1)")


@dataclass(frozen=True)
class Case:
    """A benchmark: a scene file and the quantities checked on its solution.

    scene: file name in `scenes_dir` (default `validation/scenes/`).
    load_scale: factor on every scene load (e.g. a single load level of a nonlinear case).
    linear: whether the reference is a linear-theory value, solved in the linear regime
        (module docstring).
    end_moment: the roll-up moment at load factor 1 [N·m] as a function of the model, or None.
    membrane_scale: factor on the membrane stiffness of a linear isotropic material, keeping
        the bending stiffness: a thicker shell of the same B. Kirchhoff–Love bending solutions
        of a flat plate (linear) or an inextensible strip (elastica) depend on B alone, so the
        reference holds, while the optimisation is better conditioned (the stiffness ratio
        D L² / B falls by the factor); used by the quick tests.
    """

    name: str
    scene: str
    quantities: tuple[Quantity, ...]
    load_scale: float = 1.0
    linear: bool = False
    end_moment: Callable[[ShellModel], float] | None = None
    membrane_scale: float = 1.0

    def __post_init__(self):
        for name in ("load_scale", "membrane_scale"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"case {self.name}: {name} must be positive, got {value!r}")
        if not self.quantities:
            raise ValueError(f"case {self.name}: needs at least one quantity")


# -- the end moment of the roll-up ---------------------------------------------------------------


def roll_up_moment(model: ShellModel) -> float:
    """Mmax = 2π B b / L [N·m]: the moment that rolls a strip of length L and width b into a
    full circle (B is the bending stiffness per width, ν = 0)."""
    (lo1, hi1), (lo2, hi2) = model.surface.domain.bounds
    return 2 * math.pi * model.material.bending_stiffness * (hi2 - lo2) / (hi1 - lo1)


# -- quantities ---------------------------------------------------------------------------------


def _component(probe: str, axis: int, sign: float = 1.0):
    def read(u: Readings, r: Readings) -> float:
        return sign * float(u[probe][axis])
    return read


def _distance_change(first: str, second: str, sign: float = 1.0):
    """sign × half the change of the distance between two probes: invariant under rigid
    motion, equal to the radial displacement of each for a symmetric deformation."""
    def read(u: Readings, r: Readings) -> float:
        before = np.linalg.norm(r[first] - r[second])
        after = np.linalg.norm(r[first] + u[first] - r[second] - u[second])
        return sign * 0.5 * float(after - before)
    return read


def _mean(*reads):
    def read(u: Readings, r: Readings) -> float:
        return sum(f(u, r) for f in reads) / len(reads)
    return read


def _roll_up_references(level: float, length: float = 12.0) -> tuple[float, float]:
    """Analytic (−U, W) of the tip of a strip rolled by λ = M/Mmax (ν = 0)."""
    angle = 2 * math.pi * level
    return length * (1 - math.sin(angle) / angle), length * (1 - math.cos(angle)) / angle


def _shear_quantities() -> tuple[Quantity, ...]:
    references = {0.1: (1.309, 0.103), 0.5: (4.933, 1.604), 1.0: (6.698, 3.286)}
    out = []
    for level, (w, u) in references.items():
        out += [Quantity("W", "tip deflection", w, 0.02, _component("tip", 2), level),
                Quantity("-U", "tip shortening", u, 0.02, _component("tip", 0, -1.0), level)]
    return tuple(out)


def _moment_quantities() -> tuple[Quantity, ...]:
    out = []
    for level in (0.25, 0.5, 0.75, 1.0):
        minus_u, w = _roll_up_references(level)
        out.append(Quantity("-U", "tip shortening", minus_u, 0.02, _component("tip", 0, -1.0),
                            level))
        if level < 1.0:  # W = 0 at λ = 1: a relative error is meaningless there
            out.append(Quantity("W", "tip lift", w, 0.02, _component("tip", 2), level))
    return tuple(out)


CASES: dict[str, Case] = {
    case.name: case
    for case in (
        Case("square_plate", "square_plate.toml",
             (Quantity("w_centre", "centre deflection", 0.4875, 0.01,
                       _component("centre", 2)),),
             linear=True),
        Case("scordelis_lo_roof", "scordelis_lo_roof.toml",
             (Quantity("-u_z", "vertical deflection at mid free edge", 0.3024, 0.01,
                       _component("free_edge_mid", 2, -1.0)),),
             linear=True),
        Case("pinched_cylinder", "pinched_cylinder.toml",
             (Quantity("u_r", "radial (inward) displacement under a load", 1.8248e-5, 0.02,
                       _mean(_component("load_0", 0, -1.0), _component("load_pi", 0))),),
             linear=True),
        Case("pinched_hemisphere", "pinched_hemisphere.toml",
             (Quantity("u_r", "radial displacement at a load (rigid-motion invariant)", 0.094,
                       0.02, _mean(_distance_change("out_0", "out_180"),
                                   _distance_change("in_90", "in_270", -1.0))),),
             linear=True),
        Case("cantilever_shear", "cantilever_shear.toml", _shear_quantities()),
        Case("cantilever_moment", "cantilever_moment.toml", _moment_quantities(),
             end_moment=roll_up_moment),
    )
}


# -- running a case -----------------------------------------------------------------------------


@dataclass
class Row:
    """One line of the results table."""

    case: str
    quantity: str
    description: str
    level: float
    computed: float | None  # None: the level was not part of the run (e.g. --quick)
    reference: float
    relative_error: float | None
    tolerance: float
    passed: bool | None
    iterations: int  # Adam iterations, all load steps
    wall_time: float  # [s] of the whole case
    samples: int  # per Adam iteration
    newton_steps: int = 0  # last-layer Newton steps, all phases
    newton_samples: int = 0  # fixed samples of the Newton phases (0: no Newton)


@dataclass
class CaseResult:
    case: Case
    rows: list[Row]
    # value of each quantity (keyed "name @ level") against the iteration count
    convergence: dict[str, tuple[list[int], list[float]]] = field(default_factory=dict)
    solver: dict = field(default_factory=dict)


def load_case_scene(case: Case, scenes_dir: Path = SCENES_DIR) -> tuple[Scene, ShellModel, object]:
    """The case's scene, its model with the case's load scale, and the field configuration."""
    scene = load_scene(Path(scenes_dir) / case.scene)
    model = scene.model
    field_config = scene.field
    loads = model.loads.scaled(case.load_scale)
    if case.membrane_scale != 1.0:
        material = model.material
        model = model.with_material(material.with_stiffness(
            membrane_stiffness=material.membrane_stiffness * case.membrane_scale))
    if case.linear:
        loads = loads.scaled(1 / LINEARISATION)
        model = model.with_material(model.material.scaled(LINEARISATION**-2))
        field_config = dataclasses.replace(
            field_config, output_scale=field_config.output_scale * LINEARISATION)
    return scene, model.with_loads(loads), field_config


def run_case(case: Case, *, quick: bool = False, solver: SolverConfig | None = None,
             iterations: int | None = None, scenes_dir: Path = SCENES_DIR,
             seed: int | None = None) -> CaseResult:
    """Train the case's field and read its quantities.

    quick: use the scene's [training.quick] settings; solver: explicit settings instead.
    iterations: Adam iterations per load step (overrides the settings).
    seed: field initialisation and sampling seed (default: the scene's).
    """
    scene, model, field_config = load_case_scene(case, scenes_dir)
    config = solver or (scene.quick_solver if quick else scene.solver)
    if iterations is not None:
        config = config.with_iterations(iterations)
    if seed is not None:
        config = dataclasses.replace(config, seed=seed)
    config = dataclasses.replace(config, progress=False)
    field_ = NeuralField(field_config, seed=config.seed)
    kwargs = {"checkpoint_path": None}
    if case.end_moment is not None:
        width = model.surface.domain.lengths[1]
        objective = Objective.of_model(model).with_terms(
            EndMomentTerm(case.end_moment(model), width))
        run = Solver(model, field_, config, objective=objective, **kwargs)
    else:
        run = Solver(model, field_, config, **kwargs)
    dtype = field_.parameters[0].dtype
    names = [p.name for p in model.probes]
    xi = torch.tensor([p.xi for p in model.probes], dtype=dtype)
    positions = model.surface.jets(xi)[:, jets.VALUE]
    reference_positions = {n: positions[k].double().numpy() for k, n in enumerate(names)}
    unit = LINEARISATION if case.linear else 1.0
    at_level: dict[float, Readings] = {}

    def readings(probes: dict[str, list[float]]) -> Readings:
        return {n: np.asarray(v, dtype=np.float64) / unit for n, v in probes.items()}

    def on_load_step(load_factor: float) -> None:
        at_level[load_factor] = readings(run.probe_displacements(load_factor))

    start = time.perf_counter()
    result = run.run(on_load_step=on_load_step)
    wall = time.perf_counter() - start
    rows, convergence = [], {}
    for q in case.quantities:
        key = _level_key(q.level, config.load_steps)
        computed = None if key is None else q.read(at_level[key], reference_positions)
        error = None if computed is None else abs(computed - q.reference) / abs(q.reference)
        rows.append(Row(case=case.name, quantity=q.name, description=q.description,
                        level=q.level, computed=computed, reference=q.reference,
                        relative_error=error, tolerance=q.tolerance,
                        passed=None if error is None else error <= q.tolerance,
                        iterations=result.iterations, wall_time=wall, samples=config.samples,
                        newton_steps=result.newton_steps,
                        newton_samples=config.newton_samples if config.newton_iterations else 0))
        if key is not None:
            records = [h for h in result.history if h.load_factor == key]
            convergence[f"{q.name} @ {q.level:g}"] = (
                [h.iteration for h in records],
                [q.read(readings(h.probes), reference_positions) for h in records])
    log.info("%s: %d iterations in %.1f s", case.name, result.iterations, wall)
    return CaseResult(case=case, rows=rows, convergence=convergence,
                      solver={"iterations_per_step": config.iterations,
                              "samples": config.samples,
                              "load_steps": list(config.load_steps),
                              "lbfgs_iterations": config.lbfgs_iterations,
                              "newton_iterations": config.newton_iterations,
                              "newton_every": config.newton_every,
                              "newton_samples": config.newton_samples,
                              "learning_rate": config.adam.lr,
                              "field": field_config.to_dict(),
                              "load_scale": case.load_scale})


def _level_key(level: float, load_steps: tuple[float, ...]) -> float | None:
    for step in load_steps:
        if abs(step - level) < 1e-9:
            return step
    return None


# -- reports ------------------------------------------------------------------------------------


def markdown_table(rows: list[Row]) -> str:
    """The results as a Markdown table."""
    lines = ["| case | quantity | load | computed | reference | rel. error | target | "
             "Adam iterations | Newton steps | wall time [s] | samples (Adam / Newton) |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        computed = "not run" if r.computed is None else f"{r.computed:.5g}"
        if r.relative_error is None:
            error = "–"
        else:
            error = f"{100 * r.relative_error:.2f} %" + ("" if r.passed else " ✗")
        lines.append(f"| {r.case} | {r.quantity} | {r.level:g} | {computed} | {r.reference:.5g} "
                     f"| {error} | {100 * r.tolerance:g} % | {r.iterations} | {r.newton_steps} | "
                     f"{r.wall_time:.0f} | {r.samples} / {r.newton_samples} |")
    return "\n".join(lines) + "\n"


def convergence_plot(result: CaseResult) -> np.ndarray:
    """Computed / reference of each quantity against the iteration count (BGR image)."""
    series = {}
    references = {f"{q.name} @ {q.level:g}": q.reference for q in result.case.quantities}
    for key, (iterations, values) in result.convergence.items():
        series[key] = (np.asarray(iterations, float),
                       np.asarray(values, float) / references[key])
    if series:
        first = min(min(x) for x, _ in series.values() if len(x))
        last = max(max(x) for x, _ in series.values() if len(x))
        series["reference"] = (np.array([first, last], float), np.ones(2))
    return plot_curves(series, title=f"{result.case.name}: value / reference",
                       xlabel="iteration", ylabel="computed / reference")


def machine_description() -> dict:
    import os

    import taichi_ndf

    runtime = taichi_ndf.current()
    return {"python": platform.python_version(), "platform": platform.platform(),
            "processor": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
            "arch": runtime.arch, "precision": runtime.precision}


def write_report(results: list[CaseResult], out: OutputDir, *, quick: bool) -> None:
    """results.md, results.json and <case>_convergence.png into `out`."""
    rows = [r for res in results for r in res.rows]
    machine = machine_description()
    header = (f"Protocol: {'--quick' if quick else 'full'} run; precision {machine['precision']}"
              f", {machine['arch']} ({machine['processor']}, {machine['cpus']} CPUs).\n\n")
    out.write_text("results.md", "# Validation results\n\n" + header + markdown_table(rows))
    out.write_json("results.json", {
        "quick": quick,
        "machine": machine,
        "rows": [dataclasses.asdict(r) for r in rows],
        "cases": {res.case.name: {"solver": res.solver,
                                  "convergence": {k: {"iteration": list(map(int, x)),
                                                      "value": list(map(float, y))}
                                                  for k, (x, y) in res.convergence.items()}}
                  for res in results},
    })
    for res in results:
        if res.convergence:
            save_png(out.file(f"{res.case.name}_convergence.png"), convergence_plot(res))
