"""Newton's stopping test on a coarse-to-fine solve (`NewtonConfig.discretisation_fraction`):
a finer level stops once its decrement is far below the change of Π from the coarser grid (the
estimated discretisation error) — one Newton step per level on a linear case — and the
exact-tolerance mode (0) still polishes to the decrement tolerance."""

import dataclasses
import math

import pytest
import torch

from taichi_ndf.field.spline import SplineConfig, SplineField
from taichi_ndf.minimise.newton import NewtonConfig
from taichi_ndf.minimise.refinement import solve_levels
from taichi_ndf.objective import Objective, ShellEnergyTerm
from taichi_ndf.problem.quadrature import span_quadrature
from taichi_ndf.validation import CASES, load_case_scene

DT = torch.float64

def _levels(model, spans, config, levels=3):
    surface = model.surface
    field = SplineField(SplineConfig(spans=spans, domain=surface.domain.bounds), dtype=DT)
    return solve_levels(field, model.boundary,
                        lambda f: span_quadrature(surface, f.config, model.loads, dtype=DT),
                        Objective(ShellEnergyTerm(model.material, model.loads)),
                        levels=levels, config=config,
                        length=math.sqrt(surface.domain.rectangle_area))


@pytest.mark.parametrize("case", ["square_plate", "scordelis_lo_roof"])
def test_a_linear_case_takes_one_newton_step_per_finer_level(case):
    _, model, _ = load_case_scene(CASES[case])
    config = NewtonConfig()
    assert config.discretisation_fraction > 0  # the default
    stopped = _levels(model, (2, 2), config)
    exact = _levels(model, (2, 2), dataclasses.replace(config, discretisation_fraction=0.0))
    for level in (1, 2):
        (solution,), (polished,) = stopped[level], exact[level]
        assert solution.converged and polished.converged
        assert sum(h.step_length > 0 for h in solution.history) == 1, solution.history
        assert len(solution.history) == 2  # the step, then the test that stops
        assert len(polished.history) > len(solution.history)
        # Newton's error, far below the change from the coarser grid
        change = abs(polished.energy - exact[level - 1][0].energy)
        assert abs(solution.energy - polished.energy) <= config.discretisation_fraction * change


def test_the_first_level_has_no_estimate_and_polishes():
    _, model, _ = load_case_scene(CASES["square_plate"])
    (first,), = _levels(model, (2, 2), NewtonConfig(), levels=1)
    assert first.converged
    assert 0.5 * first.history[-1].decrement <= 1e-12 * abs(first.energy)


def test_discretisation_fraction_is_validated():
    with pytest.raises(ValueError, match="discretisation_fraction"):
        NewtonConfig(discretisation_fraction=1.0)
    with pytest.raises(ValueError, match="discretisation_fraction"):
        NewtonConfig(discretisation_fraction=-1e-3)
