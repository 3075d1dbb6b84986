"""A spline field's start coefficients for a start shape (`taichi_ndf.problem.start_shape`):
the one least-squares fit of the start displacement at the Gauss points."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from taichi_ndf import jets
from taichi_ndf.field.spline import SplineConfig, SplineField
from taichi_ndf.minimise.linearisation import GridLinearisation
from taichi_ndf.minimise.newton import NewtonConfig, minimise
from taichi_ndf.problem.model import ShellModel
from taichi_ndf.problem.multipatch import Gathered
from taichi_ndf.problem.quadrature import span_points
from taichi_ndf.problem.sampling import with_point_loads
from taichi_ndf.problem.start_shape import StartShape


@dataclass(frozen=True)
class _FitPotential:
    """½ Σ w √a |u − target|² over the samples [m⁴] (w √a: the Gauss weight times the area
    element): a least-squares fit as a potential, quadratic in the coefficients."""

    target: torch.Tensor  # (N, 3) [m] in the samples' order

    @staticmethod
    def _weight(samples) -> torch.Tensor:
        r = samples.r_jets
        return samples.weight * torch.linalg.cross(r[:, 1], r[:, 2], dim=-1).norm(dim=-1)

    def __call__(self, samples, u, grad):
        w = self._weight(samples)
        residual = u[:, jets.VALUE] - self.target
        gradient = torch.zeros_like(u)
        gradient[:, jets.VALUE] = w[:, None] * residual
        return _Result(0.5 * float((w[:, None] * residual ** 2).sum()), gradient)

    def hessian_blocks(self, samples, u, *, steps):
        blocks = u.new_zeros(len(u), jets.CHANNELS, 3, jets.CHANNELS, 3)
        eye = torch.eye(3, dtype=u.dtype)
        blocks[:, jets.VALUE, :, jets.VALUE, :] = self._weight(samples)[:, None, None] * eye
        return blocks


@dataclass
class _Result:
    total: float
    grad_u_jets: torch.Tensor


def fitted_start(model: ShellModel, config: SplineConfig, shape: StartShape | Gathered, *,
                 load_factor: float = 1.0, dtype: torch.dtype | None = None) -> SplineField:
    """A spline field on `config`'s grid whose displacement is the least-squares fit (at the
    Gauss points of every knot span of the chart, a polygon panel's outside its outline too:
    the start shape is defined there and so every coefficient is fitted; through the model's
    boundary conditions: held unknowns stay as the boundary holds them) of `shape`'s start
    displacement; fitted in float64, returned in `dtype` (None: the grid's default dtype).
    One Newton step solves the quadratic fit; the rest are the minimiser's own check."""
    field = SplineField(config, dtype=torch.float64)
    grid = GridLinearisation(field, model.boundary,
                             length=math.sqrt(model.surface.domain.rectangle_area))
    xi, weight = span_points(config)  # the whole chart: a polygon panel's box too
    samples = with_point_loads(model.surface, xi.to(torch.float64), weight.to(torch.float64),
                               None)
    linear = grid.linearisation(load_factor, samples)
    s = linear.samples
    r = s.r_jets
    target = shape.positions(s.xi, r[:, jets.VALUE], r[:, 1], r[:, 2]) - r[:, jets.VALUE]
    solution = minimise(linear, _FitPotential(target), field.coefficients.detach().clone(),
                        NewtonConfig(max_iterations=5, project=False), report=False)
    out = SplineField(config) if dtype is None else SplineField(config, dtype=dtype)
    out.coefficients.data.copy_(solution.parameters.to(out.coefficients.dtype))
    return out
