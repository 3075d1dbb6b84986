"""An elastic (Winkler) foundation, an energy term reached from a scene (`[[terms]]`,
`ShellModel.terms`, `Objective.of_model`): its Hessian blocks against central differences of
its gradient, its scene keys, and two closed forms: a free plate under uniform pressure
settles by w = p/k, and a hinged strip on the foundation bends as the beam on an elastic
foundation (D w'''' + k w = p)."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import pytest
import torch

from taichi_ndf import jets
from taichi_ndf.geometry import Plane
from taichi_ndf.objective import FoundationTerm, Objective
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.sampling import sample_surface
from taichi_ndf.scene.reader import parse_scene
from taichi_ndf.scene.schema import SceneError
from taichi_ndf.shell.hessian import sample_hessians
from taichi_ndf.solve.spline_solver import solve_spline

PLATE = {
    "name": "foundation",
    "geometry": {"type": "plane", "bounds": [[0.0, 1.0], [0.0, 0.5]]},
    "material": {"type": "linear", "membrane_stiffness": 100.0, "bending_stiffness": 1e-3,
                 "poisson_ratio": 0.0, "areal_density": 0.1},
    "loads": {"pressure": 4e-3},
    "terms": [{"type": "foundation", "stiffness": 40.0}],
    "field": {"type": "spline", "spans": [16, 2]},
    "training": {"load_steps": [1.0]},
}


def parse(document):
    return parse_scene(copy.deepcopy(document), base_dir=Path("."))


def test_the_hessian_blocks_are_the_central_differences_of_the_gradient():
    torch.manual_seed(0)
    surface = Plane(((0.0, 2.0), (0.0, 1.0)))
    samples = sample_surface(surface, 16, Loads(), torch.Generator().manual_seed(1))
    u = 0.01 * torch.randn(len(samples.xi), jets.CHANNELS, 3, dtype=torch.float64)
    term = FoundationTerm(250.0)

    def potential(s, u_jets, grad):
        value, gradient = term.evaluate(s, u_jets, 1.0, grad=grad)
        return type("R", (), {"total": value, "grad_u_jets": gradient})

    steps = torch.full((jets.CHANNELS,), 1e-4, dtype=torch.float64)
    exact = term.hessian_blocks(samples, u, 1.0, steps=steps)
    differenced = sample_hessians(potential, samples, u, steps=steps)
    assert torch.allclose(exact, differenced, rtol=1e-9, atol=1e-12)
    # the value: ½ k Σ w √a |u|² (a plane: √a = 1)
    value, _ = term.evaluate(samples, u, 1.0, grad=False)
    expected = 0.5 * 250.0 * float((samples.weight * (u[:, 0] ** 2).sum(dim=1)).sum())
    assert value == pytest.approx(expected, rel=1e-12)


def test_the_scene_key_puts_the_term_on_the_model_and_in_the_objective():
    model = parse(PLATE).model
    term, = model.terms
    assert isinstance(term, FoundationTerm) and term.stiffness == 40.0
    assert Objective.of_model(model).extra == (term,)
    document = dict(PLATE)
    del document["terms"]
    assert parse(document).model.terms == ()


@pytest.mark.parametrize("table, message", [
    ({"type": "foundation"}, r"terms\[0\].stiffness: required key is missing"),
    ({"type": "foundation", "stiffness": -1.0}, r"terms\[0\].stiffness: must be > 0"),
    ({"type": "winkler", "stiffness": 1.0}, r"terms\[0\].type: must be one of"),
    ({"type": "foundation", "stiffness": 1.0, "k": 2}, r"terms\[0\]: unknown key\(s\) 'k'"),
])
def test_term_errors_name_the_key(table, message):
    document = dict(PLATE, terms=[table])
    with pytest.raises(SceneError, match=message):
        parse(document)


def test_a_free_plate_under_pressure_settles_by_p_over_k():
    """No support but the foundation: the translation w = p/k along the normal leaves the
    strains zero and balances the pressure exactly."""
    scene = parse(dict(PLATE, field={"type": "spline", "spans": [4, 2]}))
    run = solve_spline(scene.model, scene.field, scene.solver)
    xi = torch.tensor([[0.1, 0.1], [0.5, 0.25], [0.9, 0.45]], dtype=torch.float64)
    u = scene.model.displacement(run.field, xi)
    expected = torch.tensor([0.0, 0.0, 4e-3 / 40.0], dtype=torch.float64)
    assert torch.allclose(u, expected.expand_as(u), rtol=0, atol=1e-10), u


def _beam_on_foundation(x, *, length, bending, k, p):
    """w(x) of a beam on an elastic foundation (D w'''' + k w = p) hinged at both ends (w =
    w'' = 0 at x = 0, L): w = p/k + A cosh βs cos βs + B sinh βs sin βs, s = x − L/2,
    β = (k / 4D)^¼."""
    beta = (k / (4.0 * bending)) ** 0.25
    h = beta * length / 2
    ch, c, sh, s = math.cosh(h), math.cos(h), math.sinh(h), math.sin(h)
    # w(L/2) = 0: p/k + A ch c + B sh s = 0; w''(L/2) = 0: −A sh s + B ch c = 0
    a = -(p / k) * ch * c / (ch * ch * c * c + sh * sh * s * s)
    b = a * sh * s / (ch * c)
    t = beta * (x - length / 2)
    return p / k + a * torch.cosh(t) * torch.cos(t) + b * torch.sinh(t) * torch.sin(t)


def test_a_hinged_strip_bends_as_the_beam_on_an_elastic_foundation():
    """Poisson ratio 0 and free long edges: the strip is a beam; β L = 10 with L = 1 m, so
    the edges' dip reaches 1/β = 0.1 m in (w = p/k = 0.1 mm far from them; the membrane
    strains (w′)² ~ 1e-6 add a relative 1e-4). Largest error over x, relative to p/k, with
    16 / 32 / 64 spans: 1.2 / 0.75 / 0.13 %, on the middle half 0.18 / 0.11 / 0.02 %."""
    document = dict(PLATE, boundary={"constraint": [
        {"type": "hinged_edge", "edge": "xi1_min"}, {"type": "hinged_edge", "edge": "xi1_max"}]})
    scene = parse(document)
    run = solve_spline(scene.model, scene.field, scene.solver)
    x = torch.linspace(0.0, 1.0, 41, dtype=torch.float64)
    xi = torch.stack((x, torch.full_like(x, 0.25)), dim=1)
    error = (scene.model.displacement(run.field, xi)[:, 2]
             - _beam_on_foundation(x, length=1.0, bending=1e-3, k=40.0, p=4e-3)).abs() / 1e-4
    assert float(error.max()) < 1.5e-2 and float(error[10:31].max()) < 2.5e-3, error
