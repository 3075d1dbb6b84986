"""Smooth displacement fields fitted to observed shapes.

u(ξ) = Σ_j c_j P_j(ξ): a Legendre series (`LegendreBasis`) per Cartesian component, fitted by
penalised least squares: misfit + λ ∫ |u_,αβ|² (a thin-plate smoothing term that makes the
fit unique where the data are sparser than the basis and controls noise). The boundary
conditions are not imposed: the observation satisfies them already, and passing the fit
through the vanishing factors φ would have to resolve u/φ, whose third derivative jumps at the
edge of φ's band (fit errors of 1e-4 of the size there). The virtual displacements, which must
be admissible, do go through φ (`residual`). With correspondence the fit is one linear solve;
a point cloud is fitted by alternating closest-point projection onto the current surface with
that solve (iterative closest point, point-to-point).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import torch

from inverse.material.basis import LegendreBasis
from inverse.material.observations import Observation
from inverse.material.projection import closest_points, grid_seeds, nearest_seeds
from taichi_ndf import jets

log = logging.getLogger(__name__)


@dataclass
class FittedShape:
    """A displacement field fitted to an observation.

    coefficients: Legendre coefficients, shape (basis.size, 3).
    rms: root-mean-square distance between observed points and the fitted surface [m].
    """

    observation: Observation
    basis: LegendreBasis
    coefficients: torch.Tensor
    rms: float

    def displacement_jets(self, xi: torch.Tensor) -> torch.Tensor:
        """Displacement jets u (N, 6, 3) [m] at ξ (N, 2)."""
        return torch.einsum("ncj,jk->nck", self.basis.jets(xi), self.coefficients)

    def positions(self, xi: torch.Tensor) -> torch.Tensor:
        """Deformed positions x = r + u (N, 3) [m]."""
        r = self.observation.model.surface.jets(xi)[:, jets.VALUE]
        return r + self.displacement_jets(xi)[:, jets.VALUE]


def _roughness(model, basis: LegendreBasis, points: int = 48) -> torch.Tensor:
    """R with cᵀRc = mean over a grid of |P_,11 c|² + 2|P_,12 c|² + |P_,22 c|² (the
    thin-plate energy of the series, per unit parameter area)."""
    (lo1, hi1), (lo2, hi2) = model.surface.domain.bounds
    g1, g2 = torch.meshgrid(torch.linspace(lo1, hi1, points, dtype=torch.float64),
                            torch.linspace(lo2, hi2, points, dtype=torch.float64), indexing="ij")
    f = basis.jets(torch.stack([g1.ravel(), g2.ravel()], dim=1))
    second = [f[:, jets.D11], f[:, jets.D12], f[:, jets.D22]]
    return (second[0].T @ second[0] + 2 * second[1].T @ second[1]
            + second[2].T @ second[2]) / len(f)


def _solve(model, basis: LegendreBasis, roughness: torch.Tensor, xi: torch.Tensor,
           points: torch.Tensor, smoothing: float) -> torch.Tensor:
    """Coefficients (size, 3) of the penalised least-squares fit of r(ξ) + u(ξ) to points."""
    values = basis.jets(xi)[:, jets.VALUE]
    target = points - model.surface.jets(xi)[:, jets.VALUE]
    normal = values.T @ values / len(xi)
    # Relative weight: λ = smoothing · size², so `smoothing` is dimensionless.
    (lo1, hi1), (lo2, hi2) = model.surface.domain.bounds
    size2 = (hi1 - lo1) ** 2 + (hi2 - lo2) ** 2
    normal = normal + smoothing * size2**2 * roughness
    normal += 1e-14 * normal.diagonal().mean() * torch.eye(basis.size, dtype=xi.dtype)
    return torch.linalg.solve(normal, values.T @ target / len(xi))


def _project(shape: FittedShape, points: torch.Tensor, xi0: torch.Tensor,
             steps: int = 4) -> torch.Tensor:
    """Surface coordinates of the closest points of the fitted surface to `points`
    (`projection.closest_points`)."""
    surface = shape.observation.model.surface
    return closest_points(lambda xi: surface.jets(xi) + shape.displacement_jets(xi),
                          surface.domain.bounds, points, xi0, steps)


def fit_shape(observation: Observation, *, degree: int = 10, smoothing: float = 1e-11,
              icp_iterations: int = 15, grid: int = 64) -> FittedShape:
    """Fit a smooth field of Legendre degree `degree` per coordinate to the observation.

    smoothing: weight of the thin-plate term relative to the mean squared misfit, made
        dimensionless with the parameter domain's diagonal (noisy data want more).
    icp_iterations, grid: for point clouds, closest-point iterations and the resolution of the
        surface grid used to seed each projection.
    """
    model = observation.model
    if observation.xi is not None:
        # Sparse rows of template points leave higher degrees undetermined between them (the
        # thin-plate term does not pick the intended interpolant there): at most one degree
        # per two distinct coordinate values.
        distinct = [len(torch.unique(observation.xi[:, k])) for k in range(2)]
        degree = tuple(max(1, min(degree, (n - 1) // 2)) for n in distinct)
    basis = LegendreBasis(model.surface.domain.bounds, degree)
    roughness = _roughness(model, basis)
    points = observation.points.to(torch.float64)
    if observation.xi is not None:
        xi = observation.xi.to(torch.float64)
        coefficients = _solve(model, basis, roughness, xi, points, smoothing)
        shape = FittedShape(observation, basis, coefficients, float("nan"))
    else:
        shape = FittedShape(observation, basis, torch.zeros(basis.size, 3, dtype=torch.float64),
                            float("nan"))
        seeds = grid_seeds(model.surface.domain, grid, torch.float64)
        for it in range(icp_iterations):
            xi = _project(shape, points, nearest_seeds(seeds, shape.positions(seeds), points))
            shape.coefficients = _solve(model, basis, roughness, xi, points, smoothing)
            log.debug("ICP iteration %d: rms %.3g m", it,
                      float((shape.positions(xi) - points).norm(dim=1).square().mean().sqrt()))
        xi = _project(shape, points, xi)
    shape.rms = float((shape.positions(xi) - points).norm(dim=1).square().mean().sqrt())
    return shape
