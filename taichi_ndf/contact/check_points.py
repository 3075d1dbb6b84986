"""Contact between the samples: a dense check grid, the points that came close, the filter.

The field is continuous, so a state whose quadrature samples are all outside may still cross
an obstacle between them. `ContactPoints` keeps the points of a dense grid (check_resolution²
per surface) that ever came within the activation distance; they are appended to every
sample set with shell weight 0 and a barrier weight (the trapezoidal rule on the grid), and
they alone carry the barrier (the area samples get barrier weight 0): the contact forces are
a fixed grid quadrature, free of the sampling noise. `refresh` evaluates the whole grid after
accepted steps; `step_allowed` is the filter's test on the area samples and the check
points: a step in which one of them could cross an obstacle is rejected. Every minimiser asks
it through the run's `taichi_ndf.contact.hook.ContactHook` (`check`, `feasible`, `accept`).
"""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np
import torch

from taichi_ndf.contact.barrier import ContactTerm
from taichi_ndf.problem.sampling import SurfaceSamples

log = logging.getLogger(__name__)

# Adaptive barrier stiffness (IPC): κ doubles whenever a grid point comes closer than
# ADAPT_BELOW × ĝ, up to ADAPT_LIMIT × its initial value.
ADAPT_BELOW = 0.1
ADAPT_LIMIT = 1024.0


def check_grid(domain, resolution: int, dtype: torch.dtype
               ) -> tuple[torch.Tensor, torch.Tensor]:
    """The check grid of a parameter domain: resolution² points over its rectangle, edges
    included, those inside it (ξ (G, 2)) with their weights (G,): the trapezoidal rule (half
    weight on the edges of the rectangle), scaled so that they add up to its area |Ω|."""
    (lo1, hi1), (lo2, hi2) = domain.bounds
    s = torch.linspace(0, 1, resolution, dtype=dtype)
    g1, g2 = torch.meshgrid(lo1 + (hi1 - lo1) * s, lo2 + (hi2 - lo2) * s, indexing="ij")
    xi = torch.stack((g1.reshape(-1), g2.reshape(-1)), dim=1)
    ends = torch.ones(resolution, dtype=dtype)
    ends[0] = ends[-1] = 0.5
    weight = (ends[:, None] * ends[None, :]).reshape(-1)
    inside = domain.contains(xi)
    return xi[inside], weight[inside] * (domain.area / float(weight[inside].sum()))


def outline_check_grid(outline, bounds, resolution: int, dtype: torch.dtype
                       ) -> tuple[torch.Tensor, torch.Tensor]:
    """The check grid of a polygon panel (`taichi_ndf.problem.outline.Outline`) on its chart
    `bounds` ((x0, x1), (y0, y1)) [m]: the resolution² points of `check_grid` over the chart,
    each weighted by the area of its dual cell (the grid cell centred on it, within the chart)
    inside the outline, so that the weights add up to the outline's area exactly; the points
    whose cell meets the outline are kept, and those whose cell the border cuts are moved onto
    the border's nearest point (ξ (G, 2), weights (G,)): the border carries a point per cell
    it crosses, as a rectangle's edges carry the grid's points. On a rectangle outline these
    are `check_grid`'s points and trapezoidal weights."""
    (lo1, hi1), (lo2, hi2) = bounds
    steps = ((hi1 - lo1) / (resolution - 1), (hi2 - lo2) / (resolution - 1))
    s = np.linspace(0.0, 1.0, resolution)
    g1, g2 = np.meshgrid(lo1 + (hi1 - lo1) * s, lo2 + (hi2 - lo2) * s, indexing="ij")
    xi = np.stack((g1.reshape(-1), g2.reshape(-1)), axis=1)
    cells = [((max(lo1, x - steps[0] / 2), min(hi1, x + steps[0] / 2)),
              (max(lo2, y - steps[1] / 2), min(hi2, y + steps[1] / 2))) for x, y in xi]
    weight = np.array([outline.area_in(cell) for cell in cells])
    whole = np.array([(c[0][1] - c[0][0]) * (c[1][1] - c[1][0]) for c in cells])
    keep = weight > 1e-12 * steps[0] * steps[1]
    cut = keep & (weight < whole * (1 - 1e-12))
    xi[cut] = outline.nearest_on_border(xi[cut])
    return torch.from_numpy(xi[keep]).to(dtype), torch.from_numpy(weight[keep]).to(dtype)


class ContactPoints:
    """The contact term with its dense grid and the check points added so far.

    term: the `ContactTerm`; surface: the reference surface; resolution: grid points per
    coordinate; grid: the grid's ξ (G, 2) and weights (G,) where the surface lays its own
    (several patches: `check_grid` per patch, `minimise.multipatch.JointSurface`), None: the
    surface's rectangle (`check_grid`)."""

    def __init__(self, term: ContactTerm, surface, resolution: int, *,
                 dtype: torch.dtype = torch.float64,
                 grid: tuple[torch.Tensor, torch.Tensor] | None = None):
        self.term = term
        self.initial_stiffness = term.stiffness
        self.surface = surface
        self.grid_xi, self.grid_weight = grid or check_grid(surface.domain, resolution, dtype)
        self.grid_r = surface.jets(self.grid_xi)[:, 0]
        self.active = torch.zeros(len(self.grid_xi), dtype=torch.bool)
        self._samples = None

    @property
    def count(self) -> int:
        return int(self.active.sum())

    def samples(self) -> SurfaceSamples | None:
        """The check points as samples (shell weight 0, their barrier weight), or None."""
        if self._samples is None and self.count:
            xi = self.grid_xi[self.active]
            self._samples = SurfaceSamples(xi, self.surface.jets(xi), xi.new_zeros(len(xi)),
                                           xi.new_zeros(len(xi), 3),
                                           self.grid_weight[self.active])
        return self._samples

    def augment(self, samples: SurfaceSamples) -> SurfaceSamples:
        """`samples` with barrier weight 0, followed by the check points."""
        base = replace(samples, barrier_weight=torch.zeros_like(samples.weight))
        check = self.samples()
        if check is None:
            return base
        return base.joined(check.to(dtype=samples.xi.dtype, device=samples.xi.device))

    def refresh(self, displacement, load_factor: float) -> float:
        """Evaluate the grid (`displacement(xi) -> u (N, 3)` of the current state), add the
        points within the activation distance; returns the smallest gap [m]."""
        u = displacement(self.grid_xi)
        return self.flag(self.point_gaps(self.grid_r.to(u.dtype) + u, load_factor))

    def flag(self, grid_gaps: torch.Tensor, reach: float | torch.Tensor = 0.0) -> float:
        """Add the grid points whose gap (the last len(grid) entries of `grid_gaps`, as
        `filter_positions` orders them) is below the activation distance (plus `reach` [m],
        one number or one per grid point: points that could come within it by the next step),
        and double the barrier stiffness if one came closer than ADAPT_BELOW × ĝ; returns the
        smallest of those gaps [m]."""
        gaps = grid_gaps[-len(self.grid_xi):]
        smallest = float(gaps.min())
        if 0 < smallest < ADAPT_BELOW * self.term.activation \
                and self.term.stiffness < ADAPT_LIMIT * self.initial_stiffness:
            self.term.stiffness *= 2.0
            log.debug("contact: gap %.3g m, barrier stiffness raised to %.4g N/m³", smallest,
                      self.term.stiffness)
        close = (gaps < self.term.activation + reach).cpu()
        new = close & ~self.active
        if bool(new.any()):
            self.active |= close
            self._samples = None
            log.debug("contact: %d check points added (%d in all)", int(new.sum()),
                      self.count)
        return smallest

    def filter_positions(self, displacement, samples: SurfaceSamples) -> torch.Tensor:
        """Positions x = r + u (M, 3) [m] of the points the Adam filter checks: the area
        samples of `samples`, then the whole grid (`displacement(xi) -> u` of a state)."""
        area = samples.weight > 0
        xi = torch.cat((samples.xi[area], self.grid_xi.to(samples.xi.dtype)))
        r = torch.cat((samples.r_jets[area, 0], self.grid_r.to(samples.xi.dtype)))
        return r + displacement(xi)

    @staticmethod
    def checked(samples: SurfaceSamples) -> torch.Tensor:
        """Mask (N,) of the points the Newton filter checks: positive shell or barrier
        weight."""
        keep = samples.weight > 0
        if samples.barrier_weight is not None:
            keep = keep | (samples.barrier_weight > 0)
        return keep

    def point_gaps(self, x: torch.Tensor, load_factor: float) -> torch.Tensor:
        """Each point's smallest gap over the obstacles (N,) [m] (+inf: no obstacle)."""
        gaps = self.term.gaps(x, load_factor)[0]
        if not gaps.shape[1]:
            return gaps.new_full((len(x),), torch.inf)
        return gaps.min(dim=1).values

    def step_allowed(self, start: torch.Tensor, start_gap: torch.Tensor, end: torch.Tensor,
                     load_factor: float, *, both_ends: bool = False,
                     end_gap: torch.Tensor | None = None) -> bool:
        """The filter's test of a step that moves the checked points from `start` to `end`
        (M, 3) [m] (`start_gap` (M,): their gaps at the start): every point outside moves
        by less than its gap — the signed distance is 1-Lipschitz, so it stays outside and
        cannot tunnel through an obstacle — and no point ends deeper inside than the deepest
        stray point started.

        both_ends: a point outside may instead move by less than its gap at the start plus
        its gap at the end: along the straight path between them the gap is at least
        max(g_start − |x − start|, g_end − |x − end|) > 0 (1-Lipschitz again), so it still
        cannot enter or tunnel, but a point at a tiny gap may move away from the obstacle by
        more than that gap (the one-sided test refuses every step of a point left at 2.5 µm
        whose smallest Adam step moves it 20 µm away: docs/contact.md). The SIREN path uses
        it; projected Newton the one-sided test (both_ends on that path moved tablecloth_box's
        spline solve to another equilibrium, Π 11 % higher: benchmarks/RESULTS.md).

        end_gap: the points' gaps at `end` (`point_gaps`) where the caller has them; else
        computed here only where the test needs them: for the points that moved by their
        start gap or more (both_ends), and for all where a point started inside (a torus: 70
        ms per evaluation of sheet_torus's 48² grid)."""
        moved = (end - start).norm(dim=1)
        outside = start_gap > 0
        far = outside & (moved >= start_gap)  # refused, or allowed by their gap at the end
        if bool(far.any()):
            if not both_ends:
                return False
            end_far = end_gap[far] if end_gap is not None else self.point_gaps(end[far],
                                                                              load_factor)
            if bool((moved[far] >= start_gap[far] + end_far.clamp(min=0.0)).any()):
                return False
        if bool(outside.all()):
            return True
        if end_gap is None:
            end_gap = self.point_gaps(end, load_factor)
        return float(end_gap.min()) > float(start_gap.min())

