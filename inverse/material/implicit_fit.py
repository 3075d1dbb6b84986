"""Bilevel estimate with implicit-function gradients on the last-layer Newton forward model
(`inverse.material.implicit`): one outer fit (`outer_fit.fit`, Levenberg–Marquardt) per
feature basis.

Uncertainty: the Fisher matrix of the implicit Jacobian assumes an exact forward model. The
forward model's own error (its basis: the features) is measured by repeating the estimate with
feature seeds `seeds` (and `widths`); the estimate is the mean over the bases (in z), and the
reported standard error combines in quadrature the Fisher standard error with the standard
deviation of the estimates over the bases (`outer_fit.combine`). An unknown whose combined
relative standard deviation exceeds `identifiability.UNDETERMINED_STD` is undetermined.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from inverse.material.conditioned import to_values
from inverse.material.forward_model import forward_model
from inverse.material.implicit import ImplicitConfig, ImplicitEquilibrium
from inverse.material.observations import Observation
from inverse.material.outer_fit import OuterConfig, OuterResult, combine, fit, start_values
from inverse.material.residual import unknown_scales
from inverse.material.unknowns import Unknown

log = logging.getLogger(__name__)


class ImplicitResult(OuterResult):
    """`OuterResult` of the implicit method: one fit per feature basis, the first reported;
    the forward model's part is the spread of the per-basis estimates."""

    @property
    def spread(self) -> np.ndarray:
        return self.model_errors


def implicit_estimate(observations: list[Observation], unknowns: list[Unknown],
                      config: ImplicitConfig | None = None, *,
                      start: list[float] | None = None,
                      equilibria: list[list[ImplicitEquilibrium]] | None = None
                      ) -> ImplicitResult:
    """Estimate any unknowns of `parse_unknowns` by fitting Newton equilibria, one outer fit
    per feature basis of `config` (module docstring).

    start: start values (default: the first observation's model values).
    equilibria: forward models from an earlier result for the same conditions (one list per
        basis, one per observation): their start solution is reused."""
    config = config or ImplicitConfig()
    if any(obs.free_handles for obs in observations):
        raise ValueError("free handles (held positions as unknowns) need the Newton method")
    t0 = time.perf_counter()
    first_values = start_values(observations, unknowns, start)
    positive = np.array([u.positive for u in unknowns])
    bases = config.bases()
    if equilibria is None:
        equilibria = [[forward_model(config.features(obs.model, width), obs.model, unknowns,
                                     config, seed=seed)
                       for obs in observations] for seed, width in bases]
    elif len(equilibria) != len(bases) or any(len(e) != len(observations) for e in equilibria):
        raise ValueError(f"need one forward model per basis ({len(bases)}) and observation "
                         f"({len(observations)})")
    outer = OuterConfig(config.max_iterations, config.tolerance, config.max_step,
                        config.projection_grid)
    fits = [fit(eqs, observations, unknowns, first_values, outer) for eqs in equilibria]
    zs = np.array([f.z for f in fits])
    z = zs.mean(axis=0)
    norm = np.where(positive, 1.0, unknown_scales(unknowns, np.array(to_values(unknowns, z))))
    spread_std = (zs.std(axis=0, ddof=1) / norm if len(fits) > 1
                  else np.zeros(len(unknowns)))
    labels = [(f.label["seed"], f.label["width"]) for f in fits]
    result = combine(observations, unknowns, z, fits[0], spread_std,
                     "implicit", sum(f.iterations for f in fits),
                     time.perf_counter() - t0)
    notes = []
    if len(fits) > 1:
        notes.append(
            f"standard errors combine in quadrature the Fisher error (exact forward model) and "
            f"the standard deviation of the estimates over {len(fits)} feature bases "
            f"(seed, width) {labels}")
    else:
        notes.append("one feature basis: the standard errors are Fisher errors only and "
                     "ignore the forward model's error")
    for f, (seed, width) in zip(fits, labels, strict=True):
        if not f.converged:
            notes.append(f"basis (seed {seed}, width {width}) stopped at the iteration "
                         f"limit ({f.iterations}) before the step fell below the tolerance")
    estimate = result.estimate
    return ImplicitResult(estimate, fits, equilibria, result.fisher, result.model,
                          ratios=result.ratios, notes=notes + result.notes)
