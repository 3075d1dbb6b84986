"""The error indicator of a spline solve per knot span, and the next grid it asks for
(equidistribution, issue 33).

Indicator ("density", the default). Two solves of the same model at the same load factor, a
grid G and the grid G′ solved after it (the adaptive loop's next), give per knot span k of G′

    e_k = Σ_{Gauss points of k} w √a |Ψ′ − Ψ|      [J]

the change of the strain energy density Ψ (`EnergyResult.density`) between the two solutions,
integrated over the span (w: parameter-area weight, √a the area element): largest where the
coarser solve was wrong (measured on the napkin, 8² → 16²: largest at the pin, 10³ times
below it at the far corner). The alternative built beside it, "energy_norm" (½ Δᵀ H Δ of the
change Δ of the jets with projected Newton's PSD blocks H), was measured and not chosen: on the
same pair it is 83 J against a change of Π of 0.024 J, largest along the edges — a large
rotation of the hanging sheet between the two solutions costs nothing in Π but much in a
linearised norm (benchmarks/RESULTS.md, "Adaptive refinement"). A strong-form residual needs
fourth derivatives, not defined across the knots of a C² spline.

Next grid (de Boor's equidistribution per direction). The marginal of e per direction,
E_i = Σ_j e_ij, is modelled as E_i = c_i w_i^(q+1): an error density c w^q per unit length with
q the local convergence order, times the span width w_i in ξ. Minimising Σ c w^(q+1) at a
fixed number of spans makes every E_i equal (equidistribution), i.e. the knot density

    ρ_ind ∝ c^(1/(q+1)) = E_i^(1/(q+1)) / w_i     on span i,

tabulated at the span centres. Half the spans stay uniform (UNIFORM_SHARE, the share the
features grading keeps uniform: `spline_grid.GRADED_SHARE`), ρ = ½ mean(ρ_ind) + ½ ρ_ind:
measured on the napkin, the indicator's own density alone (a floor of ¼ of its mean) coarsened
the far field where the next solution's folds were (benchmarks/RESULTS.md). And no span of the
next grid is wider than the span of this grid it lies in (`no_coarser`: the next grid is
nowhere coarser than this one). Known weakness (measured, benchmarks/RESULTS.md): |ΔΨ| is
largest where Ψ is, so on a smooth problem it grades towards the most strained region, not
the worst resolved: the square plate's 64² equidistributed grid (denser at the centre, 2.45
against 1.0 units of ξ at the hinged edges) gave Π −1020.06 J against −1021.38 on the 32² one
and −1021.46 on uniform 64², and w 0.25 % off against 0.02 % (`no_coarser` did not change it).
The next grid has
`growth` × the spans per direction, their knots graded by ρ (`taichi_ndf.field.grading`, a
tabulated density); a direction whose indicator is zero everywhere stays uniform.
"""

from __future__ import annotations

import dataclasses
import logging

import torch

from taichi_ndf.field import SplineConfig, SplineField
from taichi_ndf.field.grading import Grading
from taichi_ndf.minimise.assembly import displacement_at
from taichi_ndf.objective import Objective
from taichi_ndf.problem.operator import DisplacementOperator
from taichi_ndf.problem.sampling import SurfaceSamples
from taichi_ndf.shell.hessian import jet_steps

log = logging.getLogger(__name__)

INDICATORS = ("energy_norm", "density")
CHUNK = 32768  # points per chunk of Hessian blocks (N, 18, 18): 85 MB in float64
UNIFORM_SHARE = 0.5  # the share of the spans kept uniform (spline_grid.GRADED_SHARE's rule)


def span_edges(config: SplineConfig) -> tuple[torch.Tensor, torch.Tensor]:
    """The knots of each direction in ξ (n_d + 1,) float64: uniform in η, mapped back
    through a graded direction's map."""
    edges = []
    for (lo, hi), n, graded in zip(config.domain, config.spans, config.graded_maps(),
                                   strict=True):
        eta = torch.linspace(lo, hi, n + 1, dtype=torch.float64)
        x = eta if graded is None else graded.inverse(eta)
        x[0], x[-1] = lo, hi
        edges.append(x)
    return edges[0], edges[1]


def span_index(config: SplineConfig, xi: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The knot span (i1, i2) (N,) int64 of each point ξ (N, 2) of the grid `config`."""
    out = []
    for d, ((lo, hi), n, graded) in enumerate(zip(config.domain, config.spans,
                                                  config.graded_maps(), strict=True)):
        x = xi[:, d].to(torch.float64)
        eta = x if graded is None else graded.jets(x)[0]
        out.append(torch.floor((eta - lo) / ((hi - lo) / n)).long().clamp(0, n - 1))
    return out[0], out[1]


def energy_density(objective: Objective, samples: SurfaceSamples, field: SplineField,
                   boundary, load_factor: float) -> torch.Tensor:
    """Ψ √a w (N,) [J]: the strain energy of each sample of `samples` under `field`'s
    solution (the boundary conditions composed)."""
    operator = DisplacementOperator(field, boundary)
    u = displacement_at(operator, samples.xi, field.coefficients, load_factor)
    result = objective.shell.result(samples, u, load_factor, grad=False)
    return (result.density * result.sqrt_a * samples.weight).double()


def energy_norm(objective: Objective, samples: SurfaceSamples, fine: SplineField,
                coarse: SplineField, boundary, load_factor: float, *, length: float = 1.0,
                fd_step: float = 1e-5) -> torch.Tensor:
    """½ Δᵀ H Δ (N,) [J] per sample: the energy norm of the change Δ of the displacement jets
    from `coarse`'s solution to `fine`'s, with H the positive semi-definite per-point Hessian
    blocks of Π at fine's (projected Newton's, `Objective.hessian_blocks(psd=True)`), in
    chunks of CHUNK points."""
    u_fine = displacement_at(DisplacementOperator(fine, boundary), samples.xi,
                             fine.coefficients, load_factor)
    u_coarse = displacement_at(DisplacementOperator(coarse, boundary), samples.xi,
                               coarse.coefficients.to(fine.coefficients.dtype), load_factor)
    steps = jet_steps(samples.r_jets, u_fine, length, fd_step)
    out = []
    for lo in range(0, len(samples), CHUNK):
        part = slice(lo, min(lo + CHUNK, len(samples)))
        chunk = _slice(samples, part)
        blocks = objective.hessian_blocks(chunk, u_fine[part], load_factor, steps=steps,
                                          psd=True)
        n = blocks.shape[0]
        d = (u_fine[part] - u_coarse[part]).reshape(n, -1)
        out.append(0.5 * torch.einsum("ni,nij,nj->n", d, blocks.reshape(n, d.shape[1], -1), d))
    return torch.cat(out).double()


def _slice(samples: SurfaceSamples, part: slice) -> SurfaceSamples:
    return dataclasses.replace(samples, **{
        f.name: getattr(samples, f.name)[part] for f in dataclasses.fields(samples)
        if getattr(samples, f.name) is not None})


def span_indicator(objective: Objective, samples: SurfaceSamples, fine: SplineField,
                   coarse: SplineField, boundary, load_factor: float, *,
                   kind: str = "energy_norm", length: float = 1.0) -> torch.Tensor:
    """e (n1, n2) [J] per knot span of `fine`'s grid (module docstring) over `samples`
    (fine's Gauss points): kind "energy_norm" (½ ΔᵀHΔ of the change between the solutions
    of `coarse` and `fine`) or "density" (|ΔΨ| √a w)."""
    if kind == "energy_norm":
        change = energy_norm(objective, samples, fine, coarse, boundary, load_factor,
                             length=length)
    elif kind == "density":
        change = (energy_density(objective, samples, fine, boundary, load_factor)
                  - energy_density(objective, samples, coarse, boundary, load_factor)).abs()
    else:
        raise ValueError(f"indicator kind must be one of {INDICATORS}, got {kind!r}")
    i1, i2 = span_index(fine.config, samples.xi)
    n1, n2 = fine.config.spans
    e = torch.zeros(n1 * n2, dtype=torch.float64)
    e.index_add_(0, (i1 * n2 + i2).cpu(), change.cpu())
    return e.view(n1, n2)


def knot_density(marginal: torch.Tensor, edges: torch.Tensor, order: float
                 ) -> torch.Tensor | None:
    """ρ per span (n,) from the indicator's marginal E (n,) and the knots (n + 1,) in ξ
    (module docstring); None where E is zero everywhere (no information: stay uniform)."""
    if not bool((marginal > 0).any()):
        return None
    widths = edges[1:] - edges[:-1]
    rho = marginal.clamp_min(0.0) ** (1.0 / (order + 1.0)) / widths
    mean = float((rho * widths).sum() / widths.sum())
    # half the spans uniform, half by the indicator (as the features grading's share)
    return (1.0 - UNIFORM_SHARE) * rho + UNIFORM_SHARE * mean


def no_coarser(rho: torch.Tensor, widths: torch.Tensor, spans: int) -> torch.Tensor:
    """ρ raised where the next grid's `spans` spans would be wider than this grid's
    (`widths`): a span's width under ρ is ∫ρ / (spans ρ), so ρ_i ≥ ∫ρ / (spans w_i), raised
    by fixed-point iteration (∫ρ grows; it converges since Σ w_i / (spans w_i) = n / spans
    < 1)."""
    for _ in range(100):
        least = float((rho * widths).sum()) / (spans * widths)
        if bool((rho >= least * (1 - 1e-9)).all()):
            break
        rho = torch.maximum(rho, least)
    return rho


def equidistributed(config: SplineConfig, indicator: torch.Tensor, *, growth: int,
                    order: float) -> SplineConfig:
    """The next grid: `growth` × the spans of `config` per direction, its knots graded by the
    equidistributing density of `indicator` (n1, n2) on `config`'s spans (module docstring)."""
    if indicator.shape != tuple(config.spans):
        raise ValueError(f"indicator shape {tuple(indicator.shape)} is not the grid's spans "
                         f"{config.spans}")
    grading = []
    for d, edges in enumerate(span_edges(config)):
        marginal = indicator.sum(dim=1 - d)
        rho = knot_density(marginal, edges, order)
        if rho is None:
            grading.append(None)
            continue
        rho = no_coarser(rho, edges[1:] - edges[:-1], growth * config.spans[d])
        lo, hi = config.domain[d]
        centres = (edges[1:] + edges[:-1]) / 2
        grading.append(Grading((), hi - lo, 0.0, density=tuple(rho.tolist()),
                               at=tuple(centres.tolist())))
        log.info("direction %d: knot density %.3g … %.3g (span widths %.3g … %.3g of ξ)",
                 d + 1, float(rho.min()), float(rho.max()),
                 float((edges[1:] - edges[:-1]).min()), float((edges[1:] - edges[:-1]).max()))
    spans = tuple(growth * n for n in config.spans)
    return dataclasses.replace(config, spans=spans, grading=tuple(grading))

