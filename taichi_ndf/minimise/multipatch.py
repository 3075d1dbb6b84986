"""Several spline patches in one Newton: the block-diagonal join of their linearisations, with
pair couplings between points of different patches (the seams of issue 30's panels).

Patch i has its own spline grid, boundary conditions and points (a `GridLinearisation` and
its samples); its coefficients C_i (n_i, 3) are rows o_i … o_i + n_i of the joint parameters
P (Σ n_i, 3) and its points rows r_i … of the joint samples. U(P) = (U_1(C_1), U_2(C_2), …),
so Jᵀ, the per-point Hessian K = Σ Jᵀ H J and the held unknowns are each patch's, side by side.
A term that couples two points (`Couplings`: a seam between patches) adds Σ_p A_pᵀ H_p A_p,
A_p the Jacobian of both points' jets over the coefficients of their patches, from each
patch's `GridLinearisation.at_points` (the local basis at the two points): a sparse
product Sᵀ diag(H_p) S, S (P·36, 3 Σ n_i). Not supported (refused): a free pin or a tilted
boundary frame in a patch (the pin's coefficients and the frame's rotation of the blocks are
the single-patch `Assembly`'s business).

Contact (`MultiPatchGrid`): the contact rounds take one linearisation builder that maps points
to displacements and assembles on a round's points; over several patches that builder is
`MultiPatchGrid`, whose points live in a joint chart (the patches' rectangles side by side
along ξ¹), so the check grid, the check points and the step test see one surface
(`JointSurface`, its check grid laid over each patch, edges included) as on one patch.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np
import scipy.sparse as sp
import torch

from taichi_ndf.contact.check_points import check_grid, outline_check_grid
from taichi_ndf.geometry.domain import ParameterDomain
from taichi_ndf.minimise.jacobian import ComponentJacobian
from taichi_ndf.minimise.linear_solve import damped_solve
from taichi_ndf.minimise.linearisation import (
    GridLinearisation,
    PointJacobian,
    SplineLinearisation,
)
from taichi_ndf.minimise.pair_hessian import scattered
from taichi_ndf.objective.couplings import PAIR_SIZE, Couplings
from taichi_ndf.problem.outline import OutlinePlane
from taichi_ndf.problem.sampling import SurfaceSamples
from taichi_ndf.shell.hessian import COMPONENTS, JET_SIZE, jet_steps


class MultiPatchLinearisation:
    """The patches `grids` (each assembled on its points) at load factor t, joined (module
    docstring); length: the FD steps' domain length [ξ units] (`jet_steps`)."""

    def __init__(self, grids: Sequence[GridLinearisation], load_factor: float, *,
                 length: float = 1.0):
        for grid in grids:
            if grid.boundary is not None and grid.boundary.frame is not None:
                raise ValueError("a multi-patch linearisation takes no boundary frame")
        self.grids = list(grids)
        self.load_factor = float(load_factor)
        self.length = length
        self.parts: list[SplineLinearisation] = [g.linearisation(load_factor) for g in grids]
        sizes = [p.assembly.n_coefficients for p in self.parts]
        counts = [len(p.samples.xi) for p in self.parts]
        self.coefficient_offsets = np.concatenate(([0], np.cumsum(sizes))).tolist()
        self.row_offsets = np.concatenate(([0], np.cumsum(counts))).tolist()
        self.samples = self.parts[0].samples
        for part in self.parts[1:]:
            self.samples = self.samples.joined(part.samples)
        held = [None if p.fixed is None else p.fixed + COMPONENTS * o
                for p, o in zip(self.parts, self.coefficient_offsets, strict=False)]
        held = [h for h in held if h is not None]
        self.fixed = np.concatenate(held) if held else None
        self.size = COMPONENTS * self.coefficient_offsets[-1]

    def rows(self, patch: int) -> slice:
        """The rows of patch `patch`'s points in `samples`."""
        return slice(self.row_offsets[patch], self.row_offsets[patch + 1])

    def _coefficients(self, parameters: torch.Tensor, patch: int) -> torch.Tensor:
        return parameters[self.coefficient_offsets[patch]:self.coefficient_offsets[patch + 1]]

    def displacement(self, parameters: torch.Tensor) -> torch.Tensor:
        return torch.cat([p.displacement(self._coefficients(parameters, i))
                          for i, p in enumerate(self.parts)])

    def gradient(self, grad_u_jets: torch.Tensor) -> torch.Tensor:
        return torch.cat([p.gradient(grad_u_jets[self.rows(i)])
                          for i, p in enumerate(self.parts)])

    def fd_steps(self, u_jets: torch.Tensor, parameters: torch.Tensor,
                 relative: float) -> torch.Tensor:
        return jet_steps(self.samples.r_jets, u_jets, self.length, relative)

    def hessian(self, blocks: torch.Tensor, couplings: Couplings | None = None
                ) -> sp.csr_matrix:
        matrix = sp.block_diag([p.hessian(blocks[self.rows(i)])
                                for i, p in enumerate(self.parts)], format="csr")
        if couplings is None or not len(couplings):
            return matrix
        return (matrix + self.coupled_hessian(couplings)).tocsr()

    def coupled_hessian(self, couplings: Couplings) -> sp.csr_matrix:
        """Σ_p A_pᵀ H_p A_p (3 Σ n_i square, CSR) of pair blocks whose points are rows of
        `samples` (in any patches)."""
        count = len(couplings)
        points = couplings.points.reshape(-1).cpu()  # (2P,): pair p's ends at 2p, 2p + 1
        patch = np.searchsorted(self.row_offsets, points.numpy(), side="right") - 1
        rows, cols, vals = [], [], []
        for i, grid in enumerate(self.grids):
            ends = np.nonzero(patch == i)[0]
            if not ends.size:
                continue
            xi = self.samples.xi[points[ends]]
            at = grid.at_points(xi, self.load_factor)  # index (M, k), jacobian (3, M, 6, k)
            if at.pin is not None:
                raise ValueError("a multi-patch linearisation takes no free pin")
            k = at.index.shape[1]
            jacobian = at.jacobian.dense().double().cpu().numpy()
            index = at.index.cpu().numpy() + self.coefficient_offsets[i]
            # row (end e of pair p) 18 e' + 3 j + c with e' = 2p + side; column 3 C + c
            end = torch.as_tensor(ends).numpy()
            for c in range(COMPONENTS):
                shape = (len(ends), JET_SIZE // COMPONENTS, k)
                rows.append((JET_SIZE * end[:, None, None]
                             + COMPONENTS * np.arange(shape[1])[None, :, None] + c
                             + np.zeros(shape, dtype=np.int64)).ravel())
                cols.append((COMPONENTS * index[:, None, :] + c
                             + np.zeros(shape, dtype=np.int64)).ravel())
                vals.append(jacobian[c].ravel())
        jac = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                            shape=(count * PAIR_SIZE, self.size))
        return scattered(jac, couplings.blocks)

    def solve(self, matrix: sp.csr_matrix, gradient: torch.Tensor, damping: float, *,
              require_definite: bool = False) -> tuple[torch.Tensor, float] | None:
        rhs = -gradient.reshape(-1).double().cpu().numpy()
        result = damped_solve(matrix, rhs, damping, self.fixed,
                              require_definite=require_definite)
        if result is None:
            return None
        step, damping = result
        return torch.from_numpy(step).to(gradient).reshape(gradient.shape), damping



class JointSurface:
    """The patches' reference surfaces as one surface over the joint chart of a
    `MultiPatchGrid` (the patches' parameter rectangles side by side along ξ¹): `domain` (the
    union of the shifted rectangles, its area the patches' together) and `jets(ξ)` (each
    point's patch's jets at its own ξ). What the contact's check grid is laid over
    (`ContactPoints`)."""

    def __init__(self, chart: MultiPatchGrid):
        self.chart = chart
        self.domain = ParameterDomain(chart.bounds, inside=chart.contains,
                                      mask_area=sum(s.domain.area for s in chart.surfaces))

    def check_grid(self, resolution: int, dtype: torch.dtype
                   ) -> tuple[torch.Tensor, torch.Tensor]:
        """Contact's check grid: resolution² points over each patch (its edges, the seams',
        included), in the joint chart, with their weights (`contact.check_points.check_grid`;
        a polygon panel's points inside its outline and on its border, `outline_check_grid`)."""
        parts = [check_grid(s.domain, resolution, dtype) if not isinstance(s, OutlinePlane)
                 else outline_check_grid(s.outline, s.bounds, resolution, dtype)
                 for s in self.chart.surfaces]
        return (torch.cat([xi + xi.new_tensor([shift, 0.0]) for (xi, _), shift in
                           zip(parts, self.chart.shifts, strict=True)]),
                torch.cat([w for _, w in parts]))

    def jets(self, xi: torch.Tensor) -> torch.Tensor:
        """Reference jets (N, 6, 3) [m] at joint ξ (N, 2)."""
        out = xi.new_zeros(len(xi), JET_SIZE // COMPONENTS, COMPONENTS)
        for i, rows in self.chart.split(xi):
            out[rows] = self.chart.surfaces[i].jets(self.chart.local(xi[rows], i))
        return out


class MultiPatchGrid:
    """The patches' linearisation builders (`GridLinearisation`, one per patch, on its
    `surfaces[i]`) as one builder over a joint chart, for contact's rounds
    (`contact.newton_contact.ContactMinimiser` takes it as it takes one grid): a point of
    patch i at its ξ is the point ξ + (shift_i, 0) of the joint chart, the patches'
    rectangles side by side along ξ¹ with a gap of GAP × the widest between them.
    `at_points(ξ, t)` (the affine map of the coefficients at joint ξ, every patch's
    coefficients in one (Σ n_i, 3) block), `linearisation(t, samples)` (each patch assembled
    on its samples, joined: a `MultiPatchLinearisation`), `surface` (a `JointSurface`) and
    `joint(samples, i)` (patch i's samples in the joint chart). length: the FD steps' domain
    length of its linearisations (`MultiPatchLinearisation`'s); join(grids, t): the joined
    linearisation of the assembled grids (default `MultiPatchLinearisation`; a garment's
    flat-cut panels: its held edges clamped, `discretise.held_edges.HeldEdges`). Not
    supported (refused): a free pin; patches whose splines have different degrees."""

    GAP = 0.1

    def __init__(self, grids: Sequence[GridLinearisation], surfaces: Sequence, *,
                 length: float = 1.0, join=None):
        self.grids, self.surfaces, self.length = list(grids), list(surfaces), length
        self.join = join or (lambda grids, t: MultiPatchLinearisation(grids, t,
                                                                       length=self.length))
        bounds = [s.domain.bounds for s in self.surfaces]
        gap = self.GAP * max(hi - lo for (lo, hi), _ in bounds)
        starts, shifts = [0.0], []
        for (lo, hi), _ in bounds:
            shifts.append(starts[-1] - lo)
            starts.append(starts[-1] + (hi - lo) + gap)
        self.shifts, self.starts = shifts, starts[:-1]
        self.bounds = ((0.0, starts[-1] - gap),
                       (min(b[1][0] for b in bounds), max(b[1][1] for b in bounds)))
        sizes = [g.field.config.num_coefficients for g in self.grids]
        self.coefficient_offsets = np.concatenate(([0], np.cumsum(sizes))).tolist()
        self.surface = JointSurface(self)

    def patch_of(self, xi: torch.Tensor) -> torch.Tensor:
        """Each joint point's patch (N,) int64 (by its ξ¹)."""
        starts = torch.tensor(self.starts, dtype=xi.dtype, device=xi.device)
        return torch.searchsorted(starts, xi[:, 0].contiguous(), right=True) - 1

    def split(self, xi: torch.Tensor):
        """(patch, rows) of the joint points `xi` in each patch that has some."""
        patch = self.patch_of(xi)
        for i in range(len(self.grids)):
            rows = torch.nonzero(patch == i)[:, 0]
            if len(rows):
                yield i, rows

    def local(self, xi: torch.Tensor, patch: int, *, clamp: bool = True) -> torch.Tensor:
        """Joint ξ (N, 2) of patch `patch`'s points as its own ξ; clamp: onto its rectangle
        (the shift and back round by an ulp: a point on an edge, a seam's, stays on it)."""
        own = xi - xi.new_tensor([self.shifts[patch], 0.0])
        if not clamp:
            return own
        (lo1, hi1), (lo2, hi2) = self.surfaces[patch].domain.bounds
        return torch.maximum(torch.minimum(own, own.new_tensor([hi1, hi2])),
                             own.new_tensor([lo1, lo2]))

    def joint(self, samples: SurfaceSamples, patch: int) -> SurfaceSamples:
        """Patch `patch`'s samples with their ξ in the joint chart."""
        return replace(samples, xi=samples.xi + samples.xi.new_tensor([self.shifts[patch],
                                                                       0.0]))

    def contains(self, xi: torch.Tensor) -> torch.Tensor:
        """Whether each joint ξ (N, 2) is a point of a patch (N,) bool."""
        inside = torch.zeros(len(xi), dtype=torch.bool, device=xi.device)
        patch = self.patch_of(xi).clamp(min=0)
        for i, surface in enumerate(self.surfaces):
            rows = patch == i
            inside[rows] = surface.domain.contains(self.local(xi[rows], i, clamp=False))
        return inside

    def at_points(self, xi: torch.Tensor, load_factor: float) -> PointJacobian:
        """The displacement jets at joint ξ (N, 2) as an affine map of all patches'
        coefficients (`GridLinearisation.at_points`, indices offset to the joint block)."""
        order, index, offset, jacobian = [], [], [], []
        for i, rows in self.split(xi):
            at = self.grids[i].at_points(self.local(xi[rows], i), load_factor)
            if at.pin is not None:
                raise ValueError("contact on several patches takes no free pin")
            order.append(rows)
            index.append(at.index + self.coefficient_offsets[i])
            offset.append(at.offset)
            jacobian.append(at.jacobian.dense())
        if len({j.shape[-1] for j in jacobian}) > 1:
            raise ValueError("contact on several patches needs one spline degree for all")
        back = torch.argsort(torch.cat(order))
        return PointJacobian(torch.cat(index)[back], torch.cat(offset)[back],
                             ComponentJacobian.of(torch.cat(jacobian, dim=1)[:, back]),
                             None, None)

    def linearisation(self, load_factor: float, samples: SurfaceSamples
                      ) -> MultiPatchLinearisation:
        """Each patch assembled on its points among `samples` (joint ξ; at their own ξ), and
        the patches joined at load factor t by `join` (its `samples`: each patch's,
        reordered, at their own ξ)."""
        for i, rows in self.split(samples.xi):
            part = SurfaceSamples(*(None if v is None else v[rows] for v in (
                samples.xi, samples.r_jets, samples.weight, samples.point_force,
                samples.barrier_weight)))
            self.grids[i].assemble(replace(part, xi=self.local(part.xi, i)))
        return self.join(self.grids, load_factor)
