"""A handle that holds a patch (`Handle.radius`): the whole disc moves with the handle, its
slope held; the band starts at the rim; the composed jets are the field's derivatives."""

from pathlib import Path

import numpy as np
import pytest
import torch
from test_boundary import autograd_jets, random_jets, smooth_raw

from taichi_ndf import jets
from taichi_ndf.boundary import BoundaryConditions, Handle
from taichi_ndf.field.spline import SplineConfig, SplineField
from taichi_ndf.geometry import ParameterDomain, Plane
from taichi_ndf.minimise.linearisation import GridLinearisation
from taichi_ndf.minimise.sensitivity import exact_hessian, sensitivity
from taichi_ndf.objective.objective import Objective
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.model import ShellModel
from taichi_ndf.shell.materials import LinearIsotropic

PLATE = ParameterDomain(((0.0, 2.0), (-1.0, 1.0)))  # η = (ξ¹/2, (ξ² + 1)/2)
GRIP = Handle((0.0, -1.0), (0.1, -0.2, 0.3), radius=0.1)  # a corner's quarter disc
OTHER = Handle((2.0, -1.0), (0.0, 0.05, 0.0), radius=0.1)


def in_eta(points):
    return torch.tensor(points, dtype=torch.float64) * torch.tensor([2.0, 2.0]) \
        - torch.tensor([0.0, 1.0])


def test_the_whole_patch_moves_with_the_handle_and_keeps_its_slope():
    bc = BoundaryConditions([GRIP, OTHER], PLATE)
    inside = in_eta([[0.0, 0.0], [0.05, 0.05], [0.099, 0.0], [0.0, 0.07], [0.06, 0.06]])
    raw = random_jets(len(inside), seed=7)
    u = bc.compose(inside, raw, t=0.6)
    torch.testing.assert_close(u[:, jets.VALUE], 0.6 * torch.tensor(
        [[0.1, -0.2, 0.3]], dtype=torch.float64).expand(len(inside), 3), rtol=0, atol=1e-15)
    assert u[:, 1:].abs().max() < 1e-14  # translated: no slope, no curvature on the patch


def test_the_band_starts_at_the_rim():
    bc = BoundaryConditions([GRIP], PLATE, length=0.1)
    # along the edge η² = 0 at η¹ = rim + s: φ = 1 − (1 − s²/ℓ²)³, 1 beyond rim + ℓ
    s = torch.tensor([0.02, 0.05, 0.09, 0.11], dtype=torch.float64)
    xi = in_eta(torch.stack((0.1 + s, torch.zeros_like(s)), 1).tolist())
    phi = bc.vanishing_factor(xi)[:, jets.VALUE, 0]
    expected = torch.where(s < 0.1, 1 - (1 - s**2 / 0.01) ** 3, torch.ones_like(s))
    torch.testing.assert_close(phi, expected, rtol=1e-12, atol=1e-15)


def test_composed_jets_are_the_derivatives_of_the_composed_field_around_the_patch():
    bc = BoundaryConditions([GRIP, OTHER], PLATE)
    xi = in_eta([[0.12, 0.03], [0.08, 0.1], [0.15, 0.15], [0.19, 0.01], [0.9, 0.12],
                 [0.5, 0.5], [0.11, 0.0005]])

    def u(q):
        return bc.compose(q, smooth_raw(q), t=0.7)[:, jets.VALUE]

    torch.testing.assert_close(bc.compose(xi, smooth_raw(xi), t=0.7), autograd_jets(u, xi),
                               rtol=1e-9, atol=1e-10)


def test_radius_zero_is_the_point_handle():
    point = Handle((0.0, -1.0), (0.1, -0.2, 0.3))
    xi = in_eta([[0.02, 0.01], [0.12, 0.03], [0.5, 0.5]])
    raw = random_jets(len(xi), seed=3)
    torch.testing.assert_close(
        BoundaryConditions([Handle((0.0, -1.0), (0.1, -0.2, 0.3), radius=0.0)],
                           PLATE).compose(xi, raw),
        BoundaryConditions([point], PLATE).compose(xi, raw), rtol=0, atol=0)


@pytest.mark.parametrize("constraints, message", [
    ([Handle((0.0, -1.0), (0.1, 0, 0), radius=0.45)], "below 0.5"),
    ([Handle((0.0, -1.0), (0.1, 0, 0), radius=0.3), Handle((1.0, -1.0), (0, 0.1, 0),
                                                              radius=0.3)], "contradictory"),
])
def test_patches_that_do_not_fit_are_refused(constraints, message):
    with pytest.raises(ValueError, match=message):
        BoundaryConditions(constraints, PLATE)


@pytest.mark.parametrize("radius", [-0.1, 0.5, float("nan")])
def test_a_bad_radius_is_refused(radius):
    with pytest.raises(ValueError, match="radius"):
        Handle((0.0, 0.0), (0.1, 0, 0), radius=radius)



def test_a_scenes_handle_reads_its_radius(tmp_path):
    from taichi_ndf.scene.reader import load_scene
    from taichi_ndf.scene.schema import SceneError

    scene = Path(__file__).resolve().parents[1] / "scenes" / "napkin_handles.toml"
    handles = [c for c in load_scene(scene).model.boundary.constraints
               if isinstance(c, Handle)]
    assert [h.radius for h in handles] == [0.0, 0.0]
    text = scene.read_text().replace('type = "handle"', 'type = "handle"\nradius = 0.03')
    patched = tmp_path / "napkin_grips.toml"
    patched.write_text(text)
    handles = [c for c in load_scene(patched).model.boundary.constraints
               if isinstance(c, Handle)]
    assert [h.radius for h in handles] == [0.03, 0.03]
    patched.write_text(text.replace("radius = 0.03", "radius = -0.03", 1))
    with pytest.raises(SceneError, match="radius"):
        load_scene(patched)


def test_a_turning_grip_turns_its_patch_rigidly_about_its_point_and_composes_smoothly():
    """`Handle.turn`: on the patch, x = r_h + t d + R(t·turn)(r − r_h) exactly (position,
    slope and curvature: a rigid turn about the handle's point), the composed jets around the
    patch are the composed field's derivatives, and no turn is the translated patch."""
    from taichi_ndf.boundary.segments import rotations
    from taichi_ndf.geometry.analytic import Plane

    surface = Plane(bounds=((0.0, 2.0), (-1.0, 1.0)))
    turn = (0.3, 0.0, 0.1)  # about the edge's direction, tilted
    grip = Handle((0.0, -1.0), (0.1, -0.2, 0.3), radius=0.1, turn=turn)
    bc = BoundaryConditions([grip, OTHER], PLATE, surface=surface)
    inside = in_eta([[0.0, 0.0], [0.05, 0.05], [0.099, 0.0], [0.0, 0.07], [0.06, 0.06]])
    u = bc.compose(inside, random_jets(len(inside), seed=7), t=0.6)
    r = surface.jets(inside)
    held = torch.tensor([0.0, -1.0, 0.0], dtype=torch.float64)
    angle = torch.tensor([0.6 * (0.3**2 + 0.1**2) ** 0.5], dtype=torch.float64)
    m = rotations(turn, angle)[0] - torch.eye(3, dtype=torch.float64)
    expected = r @ m.T
    expected[:, jets.VALUE] += 0.6 * torch.tensor([0.1, -0.2, 0.3],
                                                  dtype=torch.float64) - m @ held
    torch.testing.assert_close(u, expected, rtol=0, atol=1e-14)
    assert float(expected[:, 2].abs().max()) > 0.01  # the slope across the edge does turn
    xi = in_eta([[0.12, 0.03], [0.08, 0.1], [0.15, 0.15], [0.19, 0.01], [0.9, 0.12]])

    def composed(q):
        return bc.compose(q, smooth_raw(q), t=0.7)[:, jets.VALUE]

    torch.testing.assert_close(bc.compose(xi, smooth_raw(xi), t=0.7), autograd_jets(composed, xi),
                               rtol=1e-9, atol=1e-10)
    still = BoundaryConditions([GRIP, OTHER], PLATE, surface=surface)
    plain = BoundaryConditions([GRIP, OTHER], PLATE)
    torch.testing.assert_close(still.compose(xi, smooth_raw(xi), t=0.7),
                               plain.compose(xi, smooth_raw(xi), t=0.7), rtol=0, atol=0)
    with pytest.raises(ValueError, match="turn needs the reference surface"):
        BoundaryConditions([grip], PLATE)
    with pytest.raises(ValueError, match="Handle: turn"):
        Handle((0.0, -1.0), (0.0, 0.0, 0.0), turn=(float("nan"), 0.0, 0.0))


def test_coefficients_wholly_inside_a_grip_are_held_so_the_equilibriums_k_is_regular():
    # A 2 × 2 m plate on 8² cubic spans, held at two corners by patches of radius 0.2: φ is 0
    # on a patch, so the coefficients whose support's quadrature points all lie in it move
    # nothing; their K rows are zero (the swing's "K is singular" at rest, wip-sftmat12)
    # unless held. Held: exactly those; K over the free unknowns factorises.
    surface = Plane(bounds=((0.0, 2.0), (-1.0, 1.0)))
    grips = [Handle((0.0, -1.0), (0.0, 0.0, 0.0), radius=0.2),
             Handle((2.0, -1.0), (0.0, 0.0, 0.0), radius=0.2)]
    model = ShellModel(surface, LinearIsotropic(300.0, 1e-4, 0.25, 0.2),
                       Loads(gravity=(0.0, 9.81, 0.0)),
                       BoundaryConditions(grips, surface.domain, surface=surface))
    config = SplineConfig(spans=(8, 8), degree=3, domain=((0.0, 2.0), (-1.0, 1.0)))
    grid = GridLinearisation(SplineField(config), model.boundary)
    samples = GridLinearisation.quadrature(model.surface, config, model.loads,
                                           dtype=torch.float64)
    linear = grid.linearisation(1.0, samples)
    xi, index = linear.assembly.samples.xi, linear.assembly.basis.index
    eta = (xi - torch.tensor([0.0, -1.0], dtype=xi.dtype)) / 2.0
    inside = torch.minimum(eta.norm(dim=1), (eta - torch.tensor([1.0, 0.0])).norm(dim=1)) <= 0.2
    read_outside = torch.zeros(config.num_coefficients, dtype=torch.bool)
    read_outside[index[~inside].unique()] = True
    wholly_inside = torch.nonzero(~read_outside).flatten().numpy()
    assert wholly_inside.size >= 2  # the fixture shows it
    expected = (wholly_inside[:, None] * 3 + np.arange(3)).reshape(-1)
    np.testing.assert_array_equal(linear.fixed, expected)
    potential = Objective.of_model(model).potential(1.0)
    coefficients = torch.zeros(config.num_coefficients, 3, dtype=torch.float64)
    matrix = exact_hessian(linear, potential, coefficients)
    rhs = torch.ones(config.num_coefficients, 3, 1, dtype=torch.float64)
    with pytest.raises(RuntimeError, match="singular"):  # every unknown free
        sensitivity(matrix, rhs)
    solved = sensitivity(matrix, rhs, linear.fixed)
    assert torch.isfinite(solved.derivative).all()
    assert (solved.derivative.reshape(-1, 1)[expected] == 0).all()
