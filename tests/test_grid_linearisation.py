"""The one builder of a spline grid's linearisation (`minimise.linearisation.GridLinearisation`):
span quadrature → local basis → `Assembly` → `SplineLinearisation` is built there and nowhere
else, and what it builds is the field's displacement exactly, with the held unknowns of the
boundary, one assembly per grid until new points are given."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest
import torch

from taichi_ndf.boundary import BoundaryConditions, PinnedPoint
from taichi_ndf.field import SplineConfig, SplineField
from taichi_ndf.geometry import Plane
from taichi_ndf.minimise.linear_solve import LinearSolver, LinearSolverConfig, damped_solve
from taichi_ndf.minimise.linearisation import GridLinearisation
from taichi_ndf.problem.loads import Loads, PointLoad

ROOT = Path(__file__).resolve().parent.parent
# The chain's links, and the modules that may call them: the builder's, and assembly.py's
# own `displacement_at` (a displacement at given points, no linearisation).
LINKS = {"span_quadrature", "local_basis_at", "Assembly", "SplineLinearisation"}
ALLOWED = {"taichi_ndf/minimise/linearisation.py": LINKS,
           "taichi_ndf/minimise/assembly.py": {"local_basis_at"}}
SURFACE = Plane(bounds=((0.0, 1.0), (0.0, 1.0)))


def _calls(path: Path) -> set[str]:
    """Names of the chain's links called in a module (as `f(...)` or `m.f(...)`)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Call):
            func = node.func
            name = func.id if isinstance(func, ast.Name) else getattr(func, "attr", None)
            if name in LINKS:
                found.add(name)
    return found


def test_the_chain_is_built_in_one_place():
    """No module of the package calls a link of the chain but the builder (issue 26: it was
    hand-built in seven places)."""
    offenders = {}
    for package in ("taichi_ndf", "inverse"):
        for path in sorted((ROOT / package).rglob("*.py")):
            name = path.relative_to(ROOT).as_posix()
            extra = _calls(path) - ALLOWED.get(name, set())
            if extra:
                offenders[name] = sorted(extra)
    assert not offenders, f"the spline linearisation built outside the builder: {offenders}"


@pytest.fixture
def grid():
    """A 3 × 2-span cubic grid with random coefficients, pinned freely at a corner (a gauge:
    held unknowns), and its quadrature with one point load."""
    config = SplineConfig(spans=(3, 2), degree=3, domain=SURFACE.domain.bounds)
    field = SplineField(config, dtype=torch.float64)
    generator = torch.Generator().manual_seed(0)
    field.coefficients.copy_(0.01 * torch.randn(field.coefficients.shape, generator=generator,
                                                dtype=torch.float64))
    boundary = BoundaryConditions([PinnedPoint((0.0, 0.0), components="xz", rotation="free")],
                                  SURFACE.domain, surface=SURFACE)
    loads = Loads(point_loads=(PointLoad((0.5, 0.5), (0.0, 0.0, -1.0)),))
    samples = GridLinearisation.quadrature(SURFACE, config, loads, dtype=torch.float64)
    return field, boundary, samples


def test_the_linearisation_is_the_fields_displacement(grid):
    """U(C) of the built linearisation = the operator's jets of the field at the assembly's
    points, at a load factor; at other points the same through `at_points`."""
    field, boundary, samples = grid
    builder = GridLinearisation(field, boundary, length=1.0)
    linear = builder.linearisation(0.7, samples)
    assert len(linear.samples) == len(samples) == 3 * 2 * 16 + 1
    expected = builder.operator.jets(linear.samples.xi, t=0.7)
    torch.testing.assert_close(linear.displacement(field.coefficients), expected, rtol=1e-12,
                               atol=1e-14)
    xi = torch.rand(7, 2, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    at = builder.at_points(xi, 0.7)
    c = field.coefficients
    u = at.offset + torch.einsum("cnja,nac->njc", at.jacobian.dense(), c[at.index])
    u = u + torch.einsum("cja,ac->jc", at.pin[:, 0], c[at.pin_index])[None]
    torch.testing.assert_close(builder.operator.to_world(u), builder.operator.jets(xi, t=0.7),
                               rtol=1e-12, atol=1e-14)


def test_held_unknowns_assembly_kept_per_grid_and_rebuilt_on_new_points(grid):
    """The free pin's gauge is held (its largest coefficient, components x and z), its
    gradient entries are zero; without new points the grid's assembly is reused (the load
    factor moved), new points (a contact round's) give a new one with the same held
    unknowns."""
    field, boundary, samples = grid
    builder = GridLinearisation(field, boundary)
    with pytest.raises(RuntimeError):
        builder.linearisation(1.0)
    first = builder.linearisation(1.0, samples)
    fixed = builder.fixed
    assert fixed is not None and len(fixed) == 2
    assert sorted(fixed % 3) == [0, 2] and len(set(fixed // 3)) == 1
    gradient = first.gradient(torch.ones(len(samples), 6, 3, dtype=torch.float64))
    assert np.all(gradient.reshape(-1)[torch.from_numpy(fixed)].numpy() == 0.0)
    again = builder.linearisation(0.5)
    assert again.assembly is first.assembly
    doubled = samples.joined(samples)  # other points: a new assembly
    other = builder.linearisation(0.5, doubled)
    assert other.assembly is not first.assembly and builder.assembly is other.assembly
    assert np.array_equal(builder.fixed, fixed)


def test_the_linear_solver_knob(grid):
    """linear=None: the direct damped solve; a LinearSolverConfig: the grid's LinearSolver,
    one per builder (kept over Newton steps and contact rounds)."""
    field, boundary, samples = grid
    direct = GridLinearisation(field, boundary).linearisation(1.0, samples)
    assert direct._solve is damped_solve
    builder = GridLinearisation(field, boundary, linear=LinearSolverConfig())
    assert isinstance(builder.solver, LinearSolver)
    assert builder.linearisation(1.0, samples)._solve is builder.solver
    assert builder.linearisation(0.5)._solve is builder.solver


def test_the_spline_driver_takes_its_linearisation_from_the_discretisation(tmp_path,
                                                                           monkeypatch):
    """`SplineDiscretisation.solve`'s grid levels are linearised by the discretisation's
    builder (`linearise`, once per level, with the run's linear solver), and give what the
    driver's own construction gives, to the last bit."""
    from test_cli import SMALL_NAPKIN, write_scene

    from taichi_ndf.discretise import SplineDiscretisation, of_scene
    from taichi_ndf.scene.reader import load_scene
    from taichi_ndf.solve.spline_solver import solve_spline

    scene = load_scene(write_scene(tmp_path, SMALL_NAPKIN.format(lr=1e-3)), field="spline")
    d = of_scene(scene)
    asked = []
    builder = SplineDiscretisation.linearise

    def counted(self, field, linear=None):
        asked.append((field.config.spans, linear.kind))
        return builder(self, field, linear)

    monkeypatch.setattr(SplineDiscretisation, "linearise", counted)
    d.start(scene.solver, seed=0)
    solution = d.solve(scene.solver)
    assert [kind for _, kind in asked] == [scene.solver.linear_solver] * len(d.run.levels)
    assert [spans for spans, _ in asked] == [tuple(lv.spans) for lv in d.run.levels]
    own = solve_spline(scene.model, scene.field, scene.solver)
    assert own.energy == solution.energy
    assert [lv.iterations for lv in own.levels] == [lv.iterations for lv in d.run.levels]
