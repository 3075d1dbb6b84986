"""Self-contact: the IPC log-barrier between points of the cloth itself (issue 30).

Points: the samples with positive shell weight (a spline's Gauss points), each with its area A
= w √a [m²], and the chart's edge points (`taichi_ndf.contact.self_pairs.edge_points`: the
outermost Gauss points projected onto the free edges, sharing those points' areas; samples of
shell, barrier and point-load weight 0 at the edge points' ξ, which the contact rounds add). A
pair (a, b) is a candidate when the two points are far apart on the surface — their rest
distance |r_a − r_b| is at least the exclusion radius ρ [m], so that neighbours do not repel
(on a garment the distance where the panels start: `SelfContactTerm.rest_at`) —
and close in space: gap g = |x_a − x_b| − o < ĝ (x = r + u, o the offset [m],
ĝ the activation distance [m]). The energy is the double area integral of the obstacle
contact's barrier b (`taichi_ndf.contact.barrier.barrier`, Li et al. 2020), by the samples'
product quadrature:

    Π_s = κ Σ_{a<b candidate} A_a A_b b(g_ab),    κ [N/m⁵].

Every candidate pair is found afresh at each evaluation (scipy's cKDTree over x, radius o +
ĝ): b = 0 beyond ĝ, so the sum over the pairs found is the sum over all pairs, and the value,
gradient and Hessian are those of one function of the positions (no stale candidate list).

Stiffness rule: a flat layer of areal load q [N/m²] resting on a parallel layer at
mid-surface distance D = o + g is carried by the pressure p(g) = 2π κ D b(g) (the double
integral over the lower plane in closed form); `taichi_ndf.contact.self_pairs.default_stiffness`
carries q at g = ĝ/2.

Resolution (why the offset): the barrier acts between samples only. A sample can pass through
the other layer only through a cell of its sample lattice, whose points lie within the cell's
half-diagonal (`hole_radius`) of a corner sample, plus the sag of the surface over the cell.
The offset must exceed both, so that a pair distance that never falls below o (the barrier is
unbounded there and the step test keeps every gap positive: `taichi_ndf.contact.self_step`)
means no sample went through the other layer: o ≥ hole radius of the coarsest grid (checked
where a scene is read; `taichi_ndf.contact.self_pairs.hole_radius`). Layers come to rest
about o + ĝ/2 apart. Settings: `taichi_ndf.contact.self_pairs.SelfContactConfig`.
"""

from __future__ import annotations

import torch

from taichi_ndf import jets
from taichi_ndf.contact.barrier import area_element, barrier
from taichi_ndf.contact.self_pairs import EdgePoints, SelfContactConfig, candidate_pairs
from taichi_ndf.objective.couplings import PAIR_SIZE, Couplings
from taichi_ndf.problem.sampling import SurfaceSamples


class SelfContactTerm:
    """κ Σ A_a A_b b(g_ab) over the candidate pairs of the samples with shell weight (module
    docstring); the `Term` protocol of `taichi_ndf.objective`, with `coupled_hessian`.

    edges: the `EdgePoints` of the grid in use (set by the contact rounds per load step), None:
    the Gauss points alone; rest_at(ξ, r) -> (M, 3) [m]: the positions the exclusion radius
    is measured at for points at ξ (M, 2) with reference positions r (M, 3) (a garment's:
    where its panels start, `taichi_ndf.discretise.panel_contact.StartPositions`), None:
    r, the rest shape."""

    def __init__(self, config: SelfContactConfig, edges: EdgePoints | None = None,
                 rest_at=None):
        self.config = config
        self.edges = edges
        self.rest_at = rest_at

    def rest(self, xi: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
        """The positions (M, 3) [m] the exclusion is measured at (`rest_at`) of points at ξ
        (M, 2) with reference positions r (M, 3)."""
        return r if self.rest_at is None else self.rest_at(xi, r)

    def points(self, samples: SurfaceSamples) -> tuple[torch.Tensor, torch.Tensor]:
        """The self-contact points as rows of the samples (M,) int64 and their areas (M,)
        [m²]: the Gauss points (shell weight > 0), then the edge points found among the
        samples of zero weight (module docstring)."""
        element = area_element(samples)
        gauss = torch.nonzero(samples.weight > 0).reshape(-1)
        area = samples.weight[gauss] * element[gauss]
        if self.edges is None:
            return gauss, area
        free = (samples.weight == 0) & (samples.point_force == 0).all(dim=1)
        if samples.barrier_weight is not None:
            free = free & (samples.barrier_weight == 0)
        candidates = torch.nonzero(free).reshape(-1)
        edge_xi = self.edges.xi.to(samples.xi)
        hit, which = (samples.xi[candidates][:, None, :] == edge_xi[None]).all(dim=2).nonzero(
            as_tuple=True)
        rows = candidates[hit]
        edge_area = self.edges.weight.to(area)[which] * element[rows]
        return torch.cat((gauss, rows)), torch.cat((
            area / self.edges.shares(samples.xi[gauss]), edge_area))

    def pairs(self, samples: SurfaceSamples, u_jets: torch.Tensor
              ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Candidate pairs as rows of the samples (P, 2) int64, their separations x_a − x_b
        (P, 3) [m] and the weights κ A_a A_b (P,) [N/m]."""
        rows, point_area = self.points(samples)
        r = samples.r_jets[rows, jets.VALUE]
        x = r + u_jets[rows, jets.VALUE]
        rest = self.rest(samples.xi[rows], r)
        config = self.config
        local = candidate_pairs(x.detach().cpu().numpy(), config.offset + config.activation,
                                rest.detach().cpu().numpy(), config.exclusion)
        local = torch.from_numpy(local).to(rows.device)
        pairs = rows[local]
        area = point_area.to(u_jets.dtype)
        weight = config.stiffness * area[local[:, 0]] * area[local[:, 1]]
        xv = samples.r_jets[:, jets.VALUE] + u_jets[:, jets.VALUE]
        return pairs, xv[pairs[:, 0]] - xv[pairs[:, 1]], weight

    def _barrier(self, separation: torch.Tensor):
        distance = separation.norm(dim=1)
        b, db, ddb = barrier(distance - self.config.offset, self.config.activation)
        return distance, b, db, ddb

    def evaluate(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                 load_factor: float | torch.Tensor = 1.0, *, grad: bool = True
                 ) -> tuple[float, torch.Tensor | None]:
        """Π_s [J] and dΠ_s/du_jets (N, 6, 3) (value channel only)."""
        pairs, separation, weight = self.pairs(samples, u_jets)
        distance, b, db, _ = self._barrier(separation)
        value = float((weight * b).sum())
        if not grad:
            return value, None
        force = (weight * db / distance)[:, None] * separation  # dΠ/dx_a, −dΠ/dx_b
        gradient = torch.zeros_like(u_jets)
        gradient[:, jets.VALUE].index_add_(0, pairs[:, 0], force)
        gradient[:, jets.VALUE].index_add_(0, pairs[:, 1], -force)
        return value, gradient

    def coupled_hessian(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                        load_factor: float | torch.Tensor = 1.0) -> Couplings:
        """The pair blocks (exact, not projected): H = κ A_a A_b (b'' n nᵀ + b'/d (I − n nᵀ))
        on the value channels, [[H, −H], [−H, H]] over the two points (n = (x_a − x_b)/d);
        indefinite where b' < 0, so Newton projects them (`Couplings.projected`)."""
        pairs, separation, weight = self.pairs(samples, u_jets)
        distance, _, db, ddb = self._barrier(separation)
        n = separation / distance[:, None]
        outer = n[:, :, None] * n[:, None, :]
        eye = torch.eye(3, dtype=u_jets.dtype, device=u_jets.device)
        block = weight[:, None, None] * (ddb[:, None, None] * outer
                                         + (db / distance)[:, None, None] * (eye - outer))
        count = len(pairs)
        blocks = u_jets.new_zeros(count, 2, jets.CHANNELS, 3, 2, jets.CHANNELS, 3)
        for a in range(2):
            for b in range(2):
                blocks[:, a, jets.VALUE, :, b, jets.VALUE, :] = block if a == b else -block
        return Couplings(pairs, blocks.reshape(count, PAIR_SIZE, PAIR_SIZE))
