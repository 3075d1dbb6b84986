"""Quadrature samples of a reference surface for the Monte-Carlo energy estimate.

Π ≈ Σ_i w_i √a_i (Ψ_i − f·u_i) − Σ_k P_k·u(ξ_k): area samples are stratified and jittered in
the parameter domain with equal weights w = |Ω| / M (M area samples), so the sum estimates the
integral in joules; the energy multiplies by √a itself, so the weights never contain it
(uniform in parameter space, weighted by √a once). Each point load adds one sample of weight 0
that carries its force, unscaled: the objective multiplies it by the load factor
(`taichi_ndf.objective.ShellEnergyTerm`); a line load adds its Gauss nodes the same way
(`taichi_ndf.problem.line_loads`), before the point-load samples.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from taichi_ndf.geometry import ReferenceSurface
from taichi_ndf.problem import line_loads
from taichi_ndf.problem.loads import Loads
from taichi_ndf.runtime import current


@dataclass
class SurfaceSamples:
    """Sample points of a surface with their quadrature data.

    xi: surface coordinates, shape (N, 2).
    r_jets: reference surface jets, shape (N, 6, 3) [m].
    weight: parameter-area quadrature weight, shape (N,): |Ω|/M for the M area samples, 0 for
        point-load samples.
    point_force: concentrated force [N], shape (N, 3): P_k at point-load samples, 0 elsewhere;
        at load factor 1 (the energy term scales it).
    barrier_weight: quadrature weight of the contact barrier (N,) [m² of parameter domain], or
        None: `weight` (the contact check points carry one and a shell weight of 0).
    """

    xi: torch.Tensor
    r_jets: torch.Tensor
    weight: torch.Tensor
    point_force: torch.Tensor
    barrier_weight: torch.Tensor | None = None

    def __len__(self) -> int:
        return self.xi.shape[0]

    def to(self, *, dtype: torch.dtype | None = None,
           device: torch.device | str | None = None) -> SurfaceSamples:
        """The same samples with tensors converted to `dtype` / moved to `device`."""
        return SurfaceSamples(*(None if t is None else t.to(dtype=dtype, device=device)
                                for t in (self.xi, self.r_jets, self.weight, self.point_force,
                                          self.barrier_weight)))

    def joined(self, other: SurfaceSamples) -> SurfaceSamples:
        """These samples followed by `other` (barrier weights: each set's own, or its
        `weight`)."""
        barrier = None
        if self.barrier_weight is not None or other.barrier_weight is not None:
            barrier = torch.cat([s.weight if s.barrier_weight is None else s.barrier_weight
                                 for s in (self, other)])
        return SurfaceSamples(torch.cat((self.xi, other.xi)),
                              torch.cat((self.r_jets, other.r_jets)),
                              torch.cat((self.weight, other.weight)),
                              torch.cat((self.point_force, other.point_force)), barrier)

    def with_point_force(self, point_force: torch.Tensor) -> SurfaceSamples:
        """The same samples carrying other point forces (N, 3) [N]."""
        if point_force.shape != self.point_force.shape:
            raise ValueError(f"point_force must have shape {tuple(self.point_force.shape)}, "
                             f"got {tuple(point_force.shape)}")
        return SurfaceSamples(self.xi, self.r_jets, self.weight, point_force, self.barrier_weight)


def stratified_uniform(n: int, low: float, high: float, generator: torch.Generator, *,
                       dtype: torch.dtype,
                       device: torch.device | str | None = None) -> torch.Tensor:
    """n stratified jittered values in [low, high] (one per stratum of width (high − low)/n),
    in random order, so that several such draws are independent of each other and of the
    spatial strata."""
    strata = torch.randperm(n, generator=generator).to(dtype)
    jitter = torch.rand(n, generator=generator, dtype=dtype)
    return (low + (strata + jitter) / n * (high - low)).to(device)


def sobol(dim: int, n: int, seed: int, dtype: torch.dtype) -> torch.Tensor:
    """n points (n, dim) of a scrambled Sobol sequence in the unit cube [0, 1)^dim."""
    return torch.quasirandom.SobolEngine(dim, scramble=True, seed=seed).draw(n).to(dtype)


def unit_to_domain(domain, unit: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Points of the unit square (n, 2) mapped affinely to the domain's rectangle: those
    inside the domain (M, 2) and the mask (n,) of the kept ones (a masked domain drops some)."""
    (lo1, hi1), (lo2, hi2) = domain.bounds
    xi = torch.stack((lo1 + (hi1 - lo1) * unit[:, 0], lo2 + (hi2 - lo2) * unit[:, 1]), dim=1)
    inside = domain.contains(xi)
    return xi[inside], inside


def sample_surface(surface: ReferenceSurface, n: int, loads: Loads | None = None,
                   generator: torch.Generator | None = None, *,
                   dtype: torch.dtype | None = None,
                   device: torch.device | str | None = None) -> SurfaceSamples:
    """n stratified jittered area samples of the surface's domain (fewer with a masked domain:
    the candidates outside the mask are dropped), plus one zero-weight sample per line-load
    quadrature node and per point load.

    dtype/device default to the runtime's (`taichi_ndf.current()`).
    """
    if dtype is None or device is None:
        runtime = current()
        dtype = dtype or runtime.dtype
        device = device or runtime.device
    domain = surface.domain
    xi = domain.sample(n, generator, dtype=dtype, device=device)
    # |Ω| / M rather than |rectangle| / n: with a mask, the number M of samples kept
    # fluctuates, and dividing by it removes that noise from the estimate.
    weight = torch.full((xi.shape[0],), domain.area / xi.shape[0], dtype=dtype, device=device)
    if loads is not None and (loads.point_loads or loads.line_loads):
        loads.check_domain(domain)
    return with_point_loads(surface, xi, weight, loads)


def with_point_loads(surface: ReferenceSurface, xi: torch.Tensor, weight: torch.Tensor,
                     loads: Loads | None) -> SurfaceSamples:
    """Area samples ξ (N, 2) with quadrature weights (N,) [m² of parameter domain], followed by
    one zero-weight sample per line-load quadrature node of `loads` carrying its share of the
    line force, then one per point load (in their order, last) carrying its force."""
    force = torch.zeros(xi.shape[0], 3, dtype=xi.dtype, device=xi.device)
    if loads is not None and loads.line_loads:
        line_xi, line_force = line_loads.quadrature(surface, loads.line_loads, dtype=xi.dtype,
                                                    device=xi.device)
        xi = torch.cat((xi, line_xi))
        weight = torch.cat((weight, weight.new_zeros(line_xi.shape[0])))
        force = torch.cat((force, line_force))
    if loads is not None and loads.point_loads:
        point_xi = torch.tensor([p.xi for p in loads.point_loads], dtype=xi.dtype,
                                device=xi.device)
        point_force = torch.tensor([p.force for p in loads.point_loads], dtype=xi.dtype,
                                   device=xi.device)
        xi = torch.cat((xi, point_xi))
        weight = torch.cat((weight, weight.new_zeros(point_xi.shape[0])))
        force = torch.cat((force, point_force))
    return SurfaceSamples(xi=xi, r_jets=surface.jets(xi), weight=weight, point_force=force)
