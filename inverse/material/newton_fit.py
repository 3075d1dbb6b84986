"""Estimate on the spline + projected-Newton forward model, with a discretisation error bar.

The outer fit (`outer_fit.fit`: Levenberg–Marquardt with implicit-function Jacobians) runs on
the forward model `spline_equilibrium.SplineEquilibrium` of two grids, h and h/2 (the grid
rule's, or the given spans, and its dyadic refinement): first on h from the start values, then
on h/2 from the estimate of h, the first solve of h/2 from the coarse equilibrium prolonged
exactly. The estimate is the fine grid's. The grids are the levels of the one continuation loop
(`taichi_ndf.minimise.continuation.solve_over`), one step per level (the fit of every
observation at the full load): `enter_level` refines the grids, `start` builds the level's
equilibria and solves them from the coarser level's prolonged solution, `solve` fits; each
level is a progress stage "newton estimate, grid level".

Standard error (`outer_fit.combine`): the noise part is the Fisher / Gauss–Newton standard
error of the fine fit (its Jacobian, the residual variance at the estimate; with `clustered`
the larger of it and the cluster-robust error, one cluster per observation); the forward
model's part is the difference of the two grids' estimates |z_{h/2} − z_h| (normalised
coordinates), an over-estimate of the fine grid's error for any convergence order ≥ 1 in the
asymptotic range. They are combined in quadrature. With free handles (`Observation.free_handles`,
the held points as unknowns) the coarse grid is refitted with the handles held where the fine
grid put them, and the difference is taken from that fit (`_coarse_at_fine_handles`).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from inverse.material.conditioned import to_values
from inverse.material.handles import displaced_model
from inverse.material.observations import Observation
from inverse.material.outer_fit import (
    ForwardFit,
    OuterConfig,
    OuterResult,
    combine,
    fit,
    start_values,
)
from inverse.material.residual import unknown_scales
from inverse.material.spline_equilibrium import SplineEquilibrium, SplineModelConfig
from inverse.material.unknowns import Unknown
from taichi_ndf.minimise.continuation import Stages, Step, solve_over

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class NewtonEstimateConfig:
    """model: the spline forward model (coarse grid, degree, band, load steps);
    outer: the Levenberg–Marquardt settings; levels: grids fitted, each refining the previous
    (≥ 2: the last two give the discretisation part; 1: Fisher errors only, flagged);
    start_from_observations: the first grid's first solve starts from the least-squares fit
    of each observation's points (`SplineEquilibrium.fitted_state`; needs correspondence)
    instead of going from the undeformed state through the load steps: the equilibrium
    branch next to the observed shape, and fewer Newton steps; clustered: the noise part of
    the standard error is the larger of the Fisher and the cluster-robust error with one
    cluster per observation (`outer_fit.clustered_std`: residuals correlated within an
    observation, as a reconstruction's smooth error and its held corners make them)."""

    model: SplineModelConfig = field(default_factory=SplineModelConfig)
    outer: OuterConfig = field(default_factory=OuterConfig)
    levels: int = 2
    start_from_observations: bool = False
    clustered: bool = False

    def __post_init__(self):
        if isinstance(self.levels, bool) or not isinstance(self.levels, int) or \
                not 1 <= self.levels <= 4:
            raise ValueError(f"levels must be an integer in 1..4, got {self.levels!r}")


class NewtonResult(OuterResult):
    """`OuterResult` of the Newton method: one fit per grid, the finest reported; the forward
    model's part is the discretisation error (the difference of the last two grids)."""

    coarse_at_fine_handles: ForwardFit | None = None  # with free handles: the grid check's fit

    @property
    def discretisation(self) -> np.ndarray:
        return self.model_errors


def newton_estimate(observations: list[Observation], unknowns: list[Unknown],
                    config: NewtonEstimateConfig | None = None, *,
                    start: list[float] | None = None) -> NewtonResult:
    """Estimate any unknowns of `parse_unknowns` by fitting spline equilibria on `levels`
    grids (module docstring). start: start values (default: the first observation's model
    values)."""
    config = config or NewtonEstimateConfig()
    t0 = time.perf_counter()
    values = start_values(observations, unknowns, start)
    names = [u.name for u in unknowns]
    positive = np.array([u.positive for u in unknowns])
    grids = [config.model.grid(obs.model) for obs in observations]
    fits: list[ForwardFit] = []

    def enter_level(level: int) -> None:  # each grid after the first refines the previous
        nonlocal grids
        if level:
            grids = [g.refined() for g in grids]

    def start(_step: Step, _previous, coarser: list[SplineEquilibrium] | None
              ) -> list[SplineEquilibrium]:  # the level's equilibria, each solved at its start
        eqs = [SplineEquilibrium(obs.model, unknowns, config.model, grid,
                                 free_handles=obs.free_handles)
               for obs, grid in zip(observations, grids, strict=True)]
        if coarser is not None:  # where the coarser grid ended: its estimate, its solution
            for eq, coarse in zip(eqs, coarser, strict=True):  # prolonged
                eq.set_local(coarse.local_values())  # the free handles where it put them
                prolonged = torch.sparse.mm(coarse.field.prolongation(), coarse.coefficients)
                eq.solve(values, start=prolonged)
        elif config.start_from_observations:
            for eq, obs in zip(eqs, observations, strict=True):
                if obs.xi is None:
                    raise ValueError("start_from_observations needs observations with "
                                     "correspondence (xi)")
                eq.solve(values, start=eq.fitted_state(obs.xi, obs.points))
        return eqs

    def solve(_step: Step, eqs: list[SplineEquilibrium]) -> list[SplineEquilibrium]:
        nonlocal values  # the next grid starts from this grid's estimate
        fits.append(fit(eqs, observations, unknowns, values, config.outer))
        values = fits[-1].values
        log.info("newton estimate on %s: %s (%d outer iterations, %.1f s)", fits[-1].label,
                 dict(zip(names, values.tolist(), strict=True)), fits[-1].iterations,
                 fits[-1].time)
        return eqs

    # one step per grid level: the fit of every observation at the full load
    equilibria = [level[0] for level in solve_over(
        Stages(solve, start, enter_level), (1.0,), levels=config.levels,
        stage="newton estimate, grid level")]
    z = fits[-1].z
    norm = np.where(positive, 1.0, unknown_scales(unknowns, np.array(to_values(unknowns, z))))
    notes = []
    coarse = None
    if len(fits) > 1 and any(o.free_handles for o in observations):
        coarse = _coarse_at_fine_handles(observations, unknowns, config, equilibria, fits)
        notes.append(f"the coarse grid {coarse.label['spans']} refitted with the free handles "
                     f"held where the fine grid put them (its own fit moved them to absorb its "
                     f"error at the handles): B there {coarse.values.tolist()}")
    if len(fits) > 1:
        discretisation = np.abs(fits[-1].z - (coarse or fits[-2]).z) / norm
        notes.append(f"standard errors combine in quadrature the Fisher error (exact forward "
                     f"model) and the difference of the estimates on the grids "
                     f"{fits[-2].label['spans']} and {fits[-1].label['spans']} (discretisation)")
    else:
        discretisation = np.zeros(len(unknowns))
        notes.append("one grid: the standard errors are Fisher errors only and ignore the "
                     "discretisation error")
    for f in fits:
        if not f.converged:
            notes.append(f"grid {f.label['spans']} stopped at the iteration limit "
                         f"({f.iterations}) before the step fell below the tolerance")
        if not f.solves_converged:
            notes.append(f"grid {f.label['spans']}: {f.unconverged_solves} equilibrium solves "
                         "stopped at Newton's iteration limit before the tolerance (the fit's "
                         "'converged' is false)")
        if not f.stable:
            notes.append(f"grid {f.label['spans']}: the fitted equilibrium is unstable (its "
                         "Hessian K is not positive definite): the estimate describes a "
                         "saddle of the energy, not a state the sheet would rest in")
    clusters = None
    if config.clustered:
        ends = np.cumsum([o.components * len(o.points) for o in observations])
        clusters = [np.arange(a, b) for a, b in zip(np.r_[0, ends[:-1]], ends, strict=True)]
    result = combine(observations, unknowns, z, fits[-1], discretisation, "newton",
                     sum(f.iterations for f in fits), time.perf_counter() - t0,
                     clusters=clusters)
    estimate = result.estimate
    out = NewtonResult(estimate, fits, equilibria, result.fisher, result.model,
                       ratios=result.ratios, notes=notes + result.notes,
                       reported=len(fits) - 1)
    out.coarse_at_fine_handles = coarse
    return out


def _coarse_at_fine_handles(observations, unknowns, config, equilibria, fits) -> ForwardFit:
    """The next-to-last grid's fit with every free handle held where the last grid put it:
    the grid difference of the material at the same held points. Fitted on the coarse grid
    too, the handles absorb its error at the held points (a sharp feature: measured on a
    noise-free hanging sheet, 0.3–0.4 mm and B +24 % on 7 × 7 against −0.9 % on 14 × 14),
    which is not the fine grid's discretisation error."""
    held = [Observation(displaced_model(o.model, o.free_handles,
                                        eq.local_values().reshape(-1, 3)),
                        o.points, o.xi, o.rows) if o.free_handles else o
            for o, eq in zip(observations, equilibria[-1], strict=True)]
    eqs = []
    for obs, coarse in zip(held, equilibria[-2], strict=True):
        eq = SplineEquilibrium(obs.model, unknowns, config.model, coarse.field.config)
        eq.solve(fits[-1].values, start=coarse.coefficients)
        eqs.append(eq)
    return fit(eqs, held, unknowns, fits[-1].values, config.outer)
