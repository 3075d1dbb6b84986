"""Held points' positions as unknowns of the material fit (`inverse.material.handles`): the
implicit-function Jacobian of the equilibrium with respect to a handle's displacement against
central differences, and a hanging sheet whose reconstructed corners are off — held there,
B is biased; fitted beside B, the bias goes and the standard error covers the truth."""

import numpy as np
import pytest
import torch

from inverse.material.newton_fit import NewtonEstimateConfig, newton_estimate
from inverse.material.observations import Observation
from inverse.material.outer_fit import OuterConfig
from inverse.material.spline_equilibrium import SplineEquilibrium, SplineModelConfig
from inverse.material.unknowns import parse_unknowns
from inverse.sft.hanging import SheetGrid, hanging_across, hanging_model
from inverse.sft.hanging_synth import HangingConfig, equilibrium_shapes, template_grid
from inverse.sft.material_from_video import frame_observations
from inverse.sft.settings import MaterialFromVideoConfig

GRAVITY = np.array([0.0, 9.81, 0.0])


def _sheet(free=(0, 1), spans=(4, 4)):
    corners = np.array([[-0.075, 0.0, 0.9], [0.075, 0.01, 1.0]])
    material = MaterialFromVideoConfig(areal_density=0.2).start_material
    model = hanging_model((0.15, 0.15), material, corners, hanging_across(corners, GRAVITY),
                          GRAVITY, band=0.1)
    model, unknowns = parse_unknowns("bending,stretch", model)
    spline = SplineModelConfig(spans=spans, degree=4, boundary_length=None)
    return SplineEquilibrium(model, unknowns, spline, spline.grid(model), free_handles=free)


def test_handle_jacobian_matches_central_differences():
    """dx/dδ of the equilibrium positions at three points for each of the 6 handle coordinates
    (−K⁻¹ ∂g/∂δ through the prescribed displacement, plus its explicit part) against central
    differences of re-solved equilibria (h = 10 µm): within 1e-5 of the column's size
    (measured ~1e-7); the material columns are unchanged by the free handles."""
    eq = _sheet()
    theta = [0.2 * 9.81 * 0.03 ** 3, 100.0]
    xi = torch.tensor([[0.05, 0.1], [0.12, 0.14], [0.02, 0.03]], dtype=torch.float64)
    eq.solve(theta)
    analytic = eq.position_sensitivity(xi, eq.sensitivity())
    assert analytic.shape == (3, 3, 2 + 6)
    solution = eq.state()
    h = 1e-5
    for k in range(6):
        step = np.zeros(6)
        step[k] = h
        moved = []
        for sign in (1.0, -1.0):
            eq.set_local(sign * step)
            eq.solve(theta, start=solution)
            moved.append(eq.positions(xi))
        central = (moved[0] - moved[1]) / (2 * h)
        column = analytic[:, :, 2 + k]
        assert float(column.abs().max()) > 0.1  # a corner moves the sheet near it
        assert float((central - column).abs().max()) < 1e-5 * float(column.abs().max())
    held = _sheet(free=())
    held.solve(theta)
    material_columns = held.position_sensitivity(xi, held.sensitivity())
    eq.set_local(np.zeros(6))
    eq.solve(theta, start=solution)
    assert torch.allclose(eq.position_sensitivity(xi, eq.sensitivity())[:, :, :2],
                          material_columns, rtol=1e-8, atol=1e-12)


def test_free_handles_refused_where_not_a_handle():
    eq = _sheet()
    with pytest.raises(ValueError, match="not a Handle"):
        Observation(eq.model, torch.zeros(4, 3), torch.full((4, 2), 0.05), free_handles=(2,))


def test_fitted_corners_remove_the_bias_of_wrong_corners():
    """Three frames of a hanging sheet (c = 5 cm), exact on the fit's own grid, whose held
    corners in frames 1 and 2 are reconstructed 1.5 mm too deep (along the camera's axis, as
    `ndf-sft`'s corner errors lie mostly along the rays, benchmarks/RESULTS.md) and every
    other vertex exact. Held where reconstructed ("held"), each frame's equilibrium is forced
    through the wrong corners and B comes out far off: +27.7 % until 2026-12-07, −13.3 % since
    the quadratic law's Hessian is formed at rest (wip-speed36, K the same to rounding). Forced
    through wrong corners the fit is sensitive to K's rounding: each version reaches its own
    estimate from every start tried (1.4, 1.5, 1.7 × B and the other version's estimate), with
    residual sums 3.14e-4 (+27.7 %) and 3.27e-4 m² (−13.3 %), both stable and converged; so
    from the observed shape the two find different equilibria at one material. Only the size
    of the bias is asserted (> 10 %, both measured); fitted ("fitted":
    frames 1 and 2's corners 6 unknowns each, frame 0's held: they are the given ones) B is
    within 2 % (measured +0.47 % ± 0.55 %) and within 2 standard errors of the truth, and the
    fitted corners are within 0.2 mm of the true ones (measured 0.05 mm)."""
    truth = HangingConfig(frames=3, cells=(8, 8), bending_length=0.05, spans=(5, 5))
    shapes = equilibrium_shapes(truth)
    grid, _, held = template_grid(truth)
    sheet = SheetGrid.from_template(np.column_stack([grid.xi, np.zeros(len(grid.xi))]),
                                    grid.faces, held).with_size(truth.sheet_size)
    observed = [s.copy() for s in shapes]
    for f in (1, 2):  # both corners 1.5 mm further along the camera's axis
        observed[f][list(held), 2] += 1.5e-3
    true_b = truth.material.bending_stiffness
    spline = SplineModelConfig(spans=(5, 5), degree=4, boundary_length=None)
    newton = NewtonEstimateConfig(model=spline, outer=OuterConfig(max_iterations=15),
                                  levels=1, start_from_observations=True, clustered=True)
    results = {}
    for corners in ("held", "fitted"):
        config = MaterialFromVideoConfig(areal_density=0.2, frames=0, corners=corners)
        observations = frame_observations(observed, sheet, config, [0, 1, 2],
                                          given_corners=shapes[0][list(held)])
        _, unknowns = parse_unknowns("bending,stretch", observations[0].model)
        results[corners] = newton_estimate(observations, unknowns, newton,
                                           start=[1.5 * true_b, 120.0])
    held_b = results["held"].estimate.values[0]
    assert abs(held_b / true_b - 1) > 0.10
    fitted = results["fitted"]
    b, se = fitted.estimate.values[0], fitted.estimate.standard_errors[0]
    assert abs(b / true_b - 1) < 0.02
    assert abs(b - true_b) < 2 * se
    offsets = fitted.fits[-1].local_values
    assert [len(v) for v in offsets] == [0, 6, 6]
    for f in (1, 2):
        fitted_corners = observed[f][list(held)] + offsets[f].reshape(2, 3)
        assert np.abs(fitted_corners - shapes[f][list(held)]).max() < 0.2e-3
