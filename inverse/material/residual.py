"""Equilibrium-residual ("virtual fields") estimate of material parameters and loads.

An observed equilibrium u makes the first variation of Π vanish for every admissible virtual
displacement δu. Π is linear in the unknowns θ (see `unknowns`), so

    Σ_j θ_j δT_j(u)[δu] = −δΠ_known(u)[δu]     for all δu,

one linear least-squares problem A θ = b with a row per virtual displacement and a column per
unknown — no inner solve. u is a smooth field fitted to the observed shape (`shape_fit`);
the virtual displacements are δu = φ ∘ P_j e_c, the Legendre polynomials of degree ≤
`virtual_degree` per coordinate and component through the boundary conditions' vanishing
factor φ (admissible by construction). Low degrees integrate the fit's errors in the second
derivatives instead of amplifying them. Several observations stack their rows.

The estimate is only as good as the premise that the fitted shape is an equilibrium of the
model. The relative residual |Aθ − b| / |b| at the least-squares θ measures how far it is from
one: above `MAX_RELATIVE_RESIDUAL` (0.05) every unknown is reported undetermined, with the
reason in `Estimate.notes`. Measured on heavy-elastica strips (noise-free, B from 10× too
stiff; fit degree 8 / virtual degree 2, and the defaults 10 / 5 of the command line): the
tests' strip (D = 100 N/m, D/B = 4e4 m⁻²) 0.016 / 0.026 with B −2.4 % / +0.4 %;
`calibration.strip_case` (D/B = 4e5 m⁻²) 0.091 / 0.032 with −16 % / −3.7 %; the same with
D = 3000 N/m (nearly inextensible: membrane strain ~1e-4, below what the shape fit resolves,
so the membrane forces the equations rely on are fitting error) 0.99 / 0.35 with −105 % /
−36 %, which the Fisher analysis alone reports as determined.

If nothing known sets the scale (all loads and stiffness values unknown, b = 0), θ is
determined only up to a common factor; the first positive unknown is then held at the scene's
value and only ratios are reported as determined.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from inverse.material.basis import LegendreBasis
from inverse.material.identifiability import Identifiability, analyse
from inverse.material.observations import Observation
from inverse.material.shape_fit import FittedShape, fit_shape
from inverse.material.unknowns import Unknown, residual_samples, term_gradients
from taichi_ndf.problem.operator import DisplacementOperator

log = logging.getLogger(__name__)

# Relative equilibrium residual above which the observation is not treated as an equilibrium
# of the model: every unknown undetermined (module docstring).
MAX_RELATIVE_RESIDUAL = 0.05


@dataclass(frozen=True)
class ResidualConfig:
    """fit_degree: Legendre degree of the fitted shape per coordinate (more resolves finer
    folds, fewer smooths noise); virtual_degree: degree of the virtual displacements;
    samples: Gauss quadrature points per observation (about)."""

    fit_degree: int = 10
    virtual_degree: int = 5
    samples: int = 4096

    def __post_init__(self):
        for name in ("fit_degree", "virtual_degree"):
            if not 1 <= getattr(self, name) <= 40:
                raise ValueError(f"{name} must be in 1..40, got {getattr(self, name)}")
        if self.samples < 64:
            raise ValueError(f"samples must be >= 64, got {self.samples}")


@dataclass
class Estimate:
    """Result of an estimate.

    unknowns, values: the unknowns and their estimates (same order); a value is meaningful
        only where `identifiability.determined` says so.
    standard_errors: absolute standard errors (same units), inf where undetermined.
    misfit: relative residual |Aθ − b| / |b| (residual method) or the rms point distance [m]
        (bilevel).
    gauge: name of the unknown held fixed when only ratios are determined, else None.
    notes: reasons an unknown is undetermined beyond the Fisher analysis (residual method).
    residuals: the fitted shape's residuals [m] at the estimate (the goodness-of-fit test,
        `goodness`); None for the residual method, which fits no equilibrium shape.
    """

    unknowns: list[Unknown]
    values: np.ndarray
    standard_errors: np.ndarray
    identifiability: Identifiability
    misfit: float
    iterations: int
    time: float
    method: str
    gauge: str | None = None
    shapes: list[FittedShape] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    residuals: np.ndarray | None = None

    def value(self, name: str) -> float:
        return float(self.values[[u.name for u in self.unknowns].index(name)])

    def is_determined(self, name: str) -> bool:
        return self.identifiability.determined[[u.name for u in self.unknowns].index(name)]


def equilibrium_system(shape: FittedShape, unknowns: list[Unknown],
                       config: ResidualConfig) -> tuple[np.ndarray, np.ndarray]:
    """Rows A (R, p) and b (R,) of the virtual-work equations of one fitted shape [J]."""
    model = shape.observation.model
    samples = residual_samples(model, config.samples)
    u_jets = shape.displacement_jets(samples.xi)
    columns, rest = term_gradients(model, unknowns, samples, u_jets)
    virtual = LegendreBasis(model.surface.domain.bounds, config.virtual_degree).jets(samples.xi)

    composition = DisplacementOperator(None, model.boundary)

    def rows(grad_u: torch.Tensor) -> torch.Tensor:
        grad_raw = composition.raw_gradient(samples.xi, grad_u)
        return torch.einsum("nck,ncj->kj", grad_raw, virtual).reshape(-1)

    a = torch.stack([rows(c) for c in columns], dim=1)
    return a.numpy(), -rows(rest).numpy()


def unknown_scales(unknowns: list[Unknown], values: np.ndarray) -> np.ndarray:
    """Scale of each unknown's normalised coordinate: |θ| (log) or |vector group|."""
    scale = np.empty(len(unknowns))
    for j, u in enumerate(unknowns):
        if u.positive:
            scale[j] = abs(values[j])
        else:
            group = [i for i, w in enumerate(unknowns) if (w.kind, w.key) == (u.kind, u.key)]
            scale[j] = np.linalg.norm(values[group])
    return np.where(scale > 0, scale, 1.0)


def residual_estimate(observations: list[Observation], unknowns: list[Unknown],
                      config: ResidualConfig = ResidualConfig()) -> Estimate:
    """Estimate the unknowns from observed equilibrium shapes (see module docstring)."""
    for obs in observations:
        DisplacementOperator(None, obs.model.boundary).refuse_free_pin(
            "the residual method", ": its virtual displacements are not made to vanish there; "
            "use --method implicit or rotation = 'held'")
    start = time.perf_counter()
    shapes, blocks_a, blocks_b = [], [], []
    for obs in observations:
        shape = fit_shape(obs, degree=config.fit_degree)
        log.info("fitted shape: rms %.3g m (%.3g of the size)", shape.rms, shape.rms / obs.size)
        a, b = equilibrium_system(shape, unknowns, config)
        shapes.append(shape)
        blocks_a.append(a)
        blocks_b.append(b)
    a, b = np.concatenate(blocks_a), np.concatenate(blocks_b)
    names = [u.name for u in unknowns]
    positive = [u.positive for u in unknowns]
    gauge = None
    if not np.any(b):
        gauge = next((j for j, u in enumerate(unknowns) if u.positive), None)
        if gauge is None or len(unknowns) < 2:
            raise ValueError(f"nothing known sets the scale of {names}: add a known load or "
                             f"stiffness")
        held = unknowns[gauge].value(observations[0].model)
        free = [j for j in range(len(unknowns)) if j != gauge]
        sol, *_ = np.linalg.lstsq(a[:, free], -a[:, gauge] * held, rcond=None)
        values = np.empty(len(unknowns))
        values[gauge], values[free] = held, sol
    else:
        norms = np.linalg.norm(a, axis=0)
        norms = np.where(norms > 0, norms, 1.0)
        sol, *_ = np.linalg.lstsq(a / norms, b, rcond=None)
        values = sol / norms
    residual = a @ values - b
    dof = max(len(b) - len(unknowns) + (gauge is not None), 1)
    sigma2 = float(residual @ residual) / dof
    scale = unknown_scales(unknowns, values)
    ident = analyse(a * scale, sigma2, names, positive)
    if gauge is not None:
        # Only ratios are determined: the common factor was fixed by hand, not by the data.
        ident.determined = [False] * len(unknowns)
    for j, u in enumerate(unknowns):
        if u.positive and values[j] <= 0:
            ident.determined[j] = False
    reference = np.linalg.norm(b) if np.any(b) else np.linalg.norm(a @ values)
    misfit = float(np.linalg.norm(residual) / max(reference, 1e-300))
    notes = []
    if not misfit <= MAX_RELATIVE_RESIDUAL:
        ident.determined = [False] * len(unknowns)
        notes.append(f"the observation is not an equilibrium of the model: relative "
                     f"equilibrium residual {misfit:.3g} > {MAX_RELATIVE_RESIDUAL:g} (the fitted "
                     f"shape's strains, e.g. a nearly inextensible sheet's membrane strain, are "
                     f"not resolved, or the model's conditions differ); every unknown is "
                     f"undetermined: use --method newton")
    errors = np.where(ident.determined, ident.std * scale, np.inf)
    elapsed = time.perf_counter() - start
    log.info("residual estimate: %s (misfit %.3g, %.2f s)",
             dict(zip(names, values.tolist(), strict=True)), misfit, elapsed)
    return Estimate(unknowns, values, errors, ident, misfit, 1, elapsed, "residual",
                    gauge=names[gauge] if gauge is not None else None, shapes=shapes,
                    notes=notes)


def bending_length(estimate: Estimate, model) -> tuple[float, float] | None:
    """(c, standard error) of the bending length c = (B / (ρ_A |g|))^{1/3} [m] when the
    estimate determines B (or B/ρ_A); None otherwise."""
    names = [u.name for u in estimate.unknowns]
    if "bending_stiffness" not in names:
        return None
    j = names.index("bending_stiffness")
    b = estimate.values[j]
    rho = (estimate.value("areal_density") if "areal_density" in names
           else model.material.areal_density)
    g = math.dist(model.loads.gravity, (0.0, 0.0, 0.0))
    ratio_determined = estimate.identifiability.determined[j] or (
        estimate.gauge is not None and len(names) == 2 and "areal_density" in names)
    if b <= 0 or rho <= 0 or g == 0 or not ratio_determined:
        return None
    c = (b / (rho * g)) ** (1.0 / 3.0)
    return c, c * float(estimate.identifiability.std[j]) / 3.0
