"""Gradient and sparse Hessian of Π over the coefficients of a local-support field.

A spline field's raw displacement at a point is u_c = Σ_a B_a(ξ) c[i_a, c] over the k = (p+1)²
coefficients i_a acting there (`field.local_basis(ξ)`: index (N, k), basis jets (N, 6, k)). The
boundary composition u = φ N + g is pointwise and affine in N, so at the fixed quadrature points

    U_q = G_q + J_q · C_q      (C_q: the 3k coefficients acting at q),

with J_q and G_q (the prescribed part) from the displacement operator
(`DisplacementOperator.local_jacobian`, `.prescribed`; J stored once per distinct component
and built once per assembly: `minimise.jacobian`), J_q per component along the boundary
frame's axes (the world axes unless the boundary has a `frame`: then U_q = G_q + Fᵀ J_q C_q and
the gradient and Hessian blocks are turned to the frame, `operator.to_frame`,
`.blocks_to_frame`; the coefficients are the frame components). A free pin
(u = N(ξ) − N(ξ₀)) makes every point also depend on the k coefficients acting at the pin ξ₀
(a "shared" set, the same for all points). Then

    g = Σ_q J_qᵀ ∂e_q/∂U_q,     K = Σ_q J_qᵀ H_q J_q

exactly (U is affine in the coefficients). The point-local part of K is scattered into a CSR
pattern computed once per grid, chunk by chunk of points (blocks asked per chunk and dropped
after its scatter: `Assembly.hessian`); the couplings through the
shared pin set are summed densely (3n × 3k) and added as a sparse block. A term that joins
two points (`taichi_ndf.objective.couplings`: a seam's stitches) adds A_pᵀ H_p A_p per pair,
A_p the Jacobian of both points' jets, scattered as a sparse matrix of its own.

Unknowns are ordered coefficient × 3 + component.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import torch

from taichi_ndf import jets
from taichi_ndf.boundary import BoundaryConditions
from taichi_ndf.boundary.constraints import COMPONENTS as COMPONENTS_XYZ
from taichi_ndf.minimise.group_pattern import MIRRORED, batch_slots, csr_pattern, pair_scatter
from taichi_ndf.minimise.jacobian import ComponentJacobian, component_jacobian
from taichi_ndf.minimise.pair_hessian import coupled_hessian, touched_channels
from taichi_ndf.minimise.pair_hessian import dofs as _dofs
from taichi_ndf.minimise.pair_hessian import weighted as _weighted
from taichi_ndf.minimise.span_products import (
    pair_entries,
    pair_sums,
    span_displacement,
    span_pullback,
)
from taichi_ndf.objective.couplings import Couplings
from taichi_ndf.problem.operator import DisplacementOperator
from taichi_ndf.problem.sampling import SurfaceSamples
from taichi_ndf.shell.hessian import COMPONENTS

# Points per batch of the Hessian products (bounds the (chunk, 3k, 3k) temporaries).
CHUNK = 4096
# Points per chunk of per-point blocks built, scattered and let go (`Assembly.hessian`): ~21 MB
# of float64 blocks, and the strain Hessian's temporaries of as many points.
POINT_CHUNK = 8192


@dataclass(frozen=True)
class LocalBasis:
    """A local basis at N points: index (N, k) int64 of the coefficients acting at each point
    and their jets (N, 6, k); with a free pin also at the pin: pin_index (k,), pin_jets (6, k)."""

    index: torch.Tensor
    jets: torch.Tensor
    pin_index: torch.Tensor | None = None
    pin_jets: torch.Tensor | None = None


def local_basis_at(operator: DisplacementOperator, xi: torch.Tensor) -> LocalBasis:
    """The local basis (`field.local_basis`) of the operator's field at ξ (N, 2), and at a
    free pin."""
    index, basis = operator.field.local_basis(operator.evaluation_points(xi))
    if not operator.free_pin:
        return LocalBasis(index, basis)
    return LocalBasis(index[:-1], basis[:-1], index[-1], basis[-1])


def jacobians(operator: DisplacementOperator, xi: torch.Tensor, basis: LocalBasis
              ) -> tuple[ComponentJacobian, torch.Tensor | None]:
    """J at ξ (N, 2) (`ComponentJacobian`: J[c, q, :, a] = ∂u_c(ξ_q)/∂C[index[q, a], c]) and
    the pin's Jacobian (3, N, 6, k), the same at every point (an expanded view; None without
    a free pin); neither depends on the load factor."""
    xi = xi.to(basis.jets.dtype)
    jacobian, pin = component_jacobian(operator, xi, basis.jets, basis.pin_jets)
    return jacobian, None if pin is None else pin[:, None].expand(-1, xi.shape[0], -1, -1)


def linearised(operator: DisplacementOperator, xi: torch.Tensor, basis: LocalBasis,
               load_factor: float
               ) -> tuple[torch.Tensor, ComponentJacobian, torch.Tensor | None]:
    """U = offset + Σ_a J[:, :, :, a] C[a] at ξ (N, 2) and load factor t, from the operator:
    offset (N, 6, 3) [m] the prescribed displacement (`operator.prescribed`), J and the pin's
    (`jacobians`)."""
    offset = operator.prescribed(xi.to(basis.jets.dtype), t=load_factor, dtype=basis.jets.dtype)
    return (offset, *jacobians(operator, xi, basis))


def _pin_displacement(pin_jacobian: torch.Tensor, pin_coefficients: torch.Tensor
                      ) -> torch.Tensor:
    """The pin's part of U (1, 6, 3), the same at every point: pin Jacobian (3, N, 6, k) (an
    expanded view), the pin's coefficients (k, 3)."""
    return torch.einsum("cja,ac->jc", pin_jacobian[:, 0], pin_coefficients)[None]


class Assembly:
    """Π's coefficient-space gradient and Hessian on fixed samples (module docstring).

    samples: the quadrature points; basis: the local basis there (`local_basis_at`);
    n_coefficients: coefficients of the field (unknowns: 3 × that).
    Call `at_load(operator, load_factor)` before use (the prescribed part depends on t).
    Points acting on the same coefficients (the Gauss points of one knot span) are summed
    before the scatter, so the sparse pattern has one (3k)² block per span; `samples` holds
    the points in the assembly's own order (use it, not the samples passed in): its point j is
    the given point `order[j]`.
    """

    def __init__(self, samples: SurfaceSamples, basis: LocalBasis, n_coefficients: int):
        if basis.index.shape[0] != len(samples):
            raise ValueError(f"basis has {basis.index.shape[0]} points for {len(samples)} "
                             "samples")
        # The points are reordered: the first m points of every group of points acting on the
        # same coefficients (m: the smallest group; the Gauss points of a span), group by group,
        # are contracted in one GEMM per group; the others (point-load samples, contact's check
        # points, SfT's data points) follow, sorted by group, and are summed per group in
        # batches of their own (`_extra_batches`).
        groups, group = torch.unique(basis.index, dim=0, return_inverse=True)
        counts = torch.bincount(group)
        order = torch.argsort(group, stable=True)
        rank = torch.arange(len(order)) - torch.repeat_interleave(
            torch.cumsum(counts, 0) - counts, counts)
        regular = rank < int(counts.min())
        order = torch.cat((order[regular], order[~regular]))
        self._per_group = int(counts.min())
        self._extra = slice(len(groups) * self._per_group, len(order))
        self._group = group[order]
        self.order = order
        self.samples = SurfaceSamples(*(None if t is None else t[order] for t in (
            samples.xi, samples.r_jets, samples.weight, samples.point_force,
            samples.barrier_weight)))
        self.basis = basis = LocalBasis(basis.index[order], basis.jets[order], basis.pin_index,
                                        basis.pin_jets)
        self.n_coefficients = int(n_coefficients)
        self.size = COMPONENTS * self.n_coefficients
        device = basis.jets.device  # index tensors live with the data; K is built on the CPU
        self.point_dofs = torch.from_numpy(_dofs(basis.index).ravel().astype(  # (N 3k): int32
            np.int32 if self.size < 2 ** 31 else np.int64)).to(device)  # where 3n allows
        self.pin_dofs = None if basis.pin_index is None else _dofs(basis.pin_index)
        group_dofs = _dofs(groups)  # (G, 3k)
        self._group_dofs = torch.from_numpy(group_dofs.ravel()).to(device)
        # K's point-local part is summed per group and component pair as (3, 3, G, k, k)
        # (`_pair_sums`): the unknowns of entry [c, d, g, a, b] are (dof[g, a, c],
        # dof[g, b, d]); `_scatter` is its position in K's CSR data (`csr_pattern`).
        self._scatter, self._columns, self._row_starts = csr_pattern(
            groups.cpu().numpy().astype(np.int64), self.n_coefficients)
        self._groups = groups.shape[0]
        self._group_index = groups
        self._upper, self._lower = pair_scatter(self._scatter, self._groups, groups.shape[1])
        self._scatter = None  # held as _upper and _lower
        self.offset = self.jacobian = self.pin_jacobian = self._operator = None

    def at_load(self, operator: DisplacementOperator, load_factor: float) -> Assembly:
        """Linearise the composition at load factor t (see `linearised`; J is built for the
        first operator given and kept: it does not depend on t)."""
        dtype = self.basis.jets.dtype
        self.offset = operator.prescribed(self.samples.xi.to(dtype), t=load_factor, dtype=dtype)
        if operator is self._operator:
            return self
        self.jacobian = self.pin_jacobian = None  # let the last one go first
        self.jacobian, self.pin_jacobian = jacobians(operator, self.samples.xi, self.basis)
        self._operator = operator  # its boundary frame turns the per-component parts
        if self.pin_jacobian is not None:
            # the same at every point (an expanded view): read point 0
            used = self.pin_jacobian[:, 0].abs().amax(dim=(0, 2)) > 0
            self._pin_channels = torch.nonzero(used).flatten()
        return self

    def displacement(self, coefficients: torch.Tensor) -> torch.Tensor:
        """Displacement jets U (N, 6, 3) [m] of coefficients (n, 3)."""
        u = span_displacement(self.jacobian, coefficients[self._group_index],
                              self._per_group)
        if self._extra.stop > self._extra.start:
            rows = self._extra
            u[rows] = self.jacobian.rows(rows).apply(coefficients[self.basis.index[rows]])
        if self.pin_jacobian is not None:
            u = u + _pin_displacement(self.pin_jacobian, coefficients[self.basis.pin_index])
        return self.offset + self._operator.to_world(u)

    def gradient(self, grad_u_jets: torch.Tensor) -> torch.Tensor:
        """dΠ/dC (n, 3) from dΠ/dU (N, 6, 3)."""
        grad_u_jets = self._operator.to_frame(grad_u_jets)
        out = grad_u_jets.new_zeros(self.size)
        spans = span_pullback(self.jacobian, grad_u_jets, self._groups, self._per_group)
        out.index_add_(0, self._group_dofs, spans.reshape(-1))
        if self._extra.stop > self._extra.start:
            rows, k = self._extra, self.jacobian.shape[3]
            local = self.jacobian.rows(rows).apply_transpose(grad_u_jets[rows])
            out.index_add_(0, self.point_dofs[rows.start * COMPONENTS * k:], local.reshape(-1))
        if self.pin_jacobian is not None:
            # the pin's Jacobian is the same at every point: sum the gradient first
            pin = torch.einsum("cja,jc->ac", self.pin_jacobian[:, 0], grad_u_jets.sum(0))
            out.index_add_(0, torch.from_numpy(self.pin_dofs).to(out.device), pin.reshape(-1))
        return out.reshape(-1, COMPONENTS)

    def _group_sums(self, left: ComponentJacobian, blocks: torch.Tensor, right: torch.Tensor,
                    m: int) -> torch.Tensor:
        """Σ over the points q of each group of m consecutive points of L_qᵀ H_q R_q, shape
        (g, 3k, 3k), Jacobians L (3, g m, cl, k), R (3, g m, cr, k) (a tensor) on channel
        subsets and blocks (g m, cl, 3, cr, 3) on the same channels."""
        k, channels = left.shape[3], left.shape[2]
        width = k * COMPONENTS
        count = blocks.shape[0] // m
        summed = blocks.new_empty(count, k, COMPONENTS, width)
        step = max(1, CHUNK // m)
        for start in range(0, count, step):
            here = slice(start, min(count, start + step))
            points = slice(here.start * m, here.stop * m)
            weighted = _weighted(blocks[points], right[:, points]).reshape(
                -1, m * channels, COMPONENTS, width)
            for c in range(COMPONENTS):
                lhs = left.component(c)[points].reshape(-1, m * channels, k)
                summed[here, :, c] = torch.bmm(lhs.transpose(1, 2), weighted[:, :, c])
        return summed.reshape(count, width, width)

    def _pair_sums(self, data: np.ndarray, jacobian: ComponentJacobian, blocks: torch.Tensor,
                   used: torch.Tensor, groups: np.ndarray, m: int) -> None:
        """Adds to K's CSR data (float64) the point-local part of points that come in batches
        of m consecutive points, batch i acting on the coefficients of group `groups[i]`
        (`span_products.pair_sums`: blocks (n, 6, 3, 6, 3) on the channels `used`, J at those
        points on them), scattered per run of batches in order; the pairs d < c as the
        transposes of c < d. Batches of one group add up (`np.add.at`)."""
        step, entries = max(1, CHUNK // m), pair_entries(used.cpu()).to(blocks.device)
        flat = blocks.reshape(blocks.shape[0], -1)
        for start in range(0, len(groups), step):
            g = groups[start:start + step]
            p = slice(start * m, (start + len(g)) * m)
            out = pair_sums(jacobian.rows(p), flat[p], entries, m).double().cpu().numpy()
            np.add.at(data, self._upper[g].ravel(), out.ravel())  # copies, contiguous: np.add.at
            np.add.at(data, self._lower[g].ravel(), out[:, :, MIRRORED].ravel())  # 5× a view's

    def hessian(self, blocks: torch.Tensor | Callable[[slice], torch.Tensor],
                couplings: Couplings | None = None, *, chunk: int | None = None
                ) -> sp.csr_matrix:
        """K = Σ Jᵀ H J (3n × 3n, CSR, float64) from per-point blocks H (N, 18, 18) (index
        channel × 3 + component), plus the pair blocks of terms that couple points
        (`coupled_hessian`; their points in this assembly's order). blocks: a tensor, or a
        function of a slice of points (this assembly's order) giving their blocks (n, 18, 18):
        asked once per chunk of about `chunk` points (default `POINT_CHUNK`) in order, each
        chunk let go after its scatter, so that the blocks of all points are never held."""
        blocks_of = blocks if callable(blocks) else blocks.__getitem__
        matrix = self._point_hessian(blocks_of, POINT_CHUNK if chunk is None else chunk)
        return matrix if couplings is None else (matrix + self.coupled_hessian(couplings)).tocsr()

    def coupled_hessian(self, couplings: Couplings) -> sp.csr_matrix:
        """Σ_p A_pᵀ H_p A_p (3n × 3n, CSR, float64) of pair blocks H_p (`Couplings`), A_p the
        Jacobian of both points' jets over the coefficients acting at either (and the pin's),
        over the channels the pair blocks touch (`pair_hessian.coupled_hessian`)."""
        return coupled_hessian(self, couplings)

    def _chunks(self, chunk: int) -> list[list[tuple[slice, slice | None]]]:
        """The chunks of points, each a list of (points, groups): the regular points by whole
        groups, about `chunk` points a chunk; the extra points (groups None) with the last
        chunk (asked together: a PSD screen sees them beside shell blocks, as all at once)."""
        step, m = max(1, chunk // self._per_group), self._per_group
        chunks = [[(slice(g * m, min(self._groups, g + step) * m),
                    slice(g, min(self._groups, g + step)))]
                  for g in range(0, self._groups, step)]
        if self._extra.stop > self._extra.start:
            chunks[-1].append((self._extra, None))
        return chunks

    def _extra_batches(self, blocks: torch.Tensor):
        """The extra points (beyond each group's first m; contact's check points, SfT's data
        points) as batches of equal size s per group, for the grouped products of the regular
        points: yields (rows (b s,) of the extra points, their blocks (b s, 18, 18) with zero
        blocks where a group's last batch is short, the batches' groups (b,), s). blocks: the
        extra points' (n, 18, 18). The points whose blocks touch the value channel only (the
        data terms' and the contact barrier's) are batched apart from the others, so that
        their products run on that channel alone."""
        groups = self._group[self._extra]
        shaped = blocks.reshape(-1, jets.CHANNELS, COMPONENTS, jets.CHANNELS, COMPONENTS)
        value_only = ~(shaped[:, 1:].flatten(1).ne(0).any(1)
                       | shaped[:, :1, :, 1:].flatten(1).ne(0).any(1))
        for kind in (value_only, ~value_only):
            rows = torch.nonzero(kind).flatten()
            if rows.numel() == 0:
                continue
            slots, ids, size = batch_slots(groups[rows])
            padded = blocks.new_zeros(len(ids) * size, *blocks.shape[1:])
            padded[slots] = blocks[rows]
            index = rows.new_full((len(ids) * size,), int(rows[0]))  # short batches: any row,
            index[slots] = rows  # with zero blocks
            yield index, padded, ids, size

    def _add_points(self, data: np.ndarray, pin: list, jacobian: ComponentJacobian,
                    blocks: torch.Tensor, groups: np.ndarray, m: int) -> None:
        """Adds the part of K of points that come in batches of m consecutive points, batch i
        acting on the coefficients of group `groups[i]`: to K's CSR data, and through a free
        pin to `pin` ([Σ J_localᵀ H J_pin, the pin–pin block], None until some block reaches
        the pin's channels). jacobian: J at the points; blocks (n, 18, 18) there."""
        blocks = self._operator.blocks_to_frame(blocks).reshape(
            -1, jets.CHANNELS, COMPONENTS, jets.CHANNELS, COMPONENTS)
        # Only the channels some block touches enter (the shell energy's blocks have no value
        # channel: 5² of the 6² channel pairs, and no coupling through a free pin's value).
        used = touched_channels(blocks)
        full = blocks
        if used.numel() < jets.CHANNELS:
            lo, hi = int(used[0]), int(used[-1]) + 1
            if hi - lo == used.numel():  # a range of channels: views, no copies
                blocks, jacobian = blocks[:, lo:hi, :, lo:hi], jacobian.channels(slice(lo, hi))
            else:
                blocks = blocks[:, used][:, :, :, used]
                jacobian = jacobian.channels(used)
        self._pair_sums(data, jacobian, full, used, groups, m)
        if self.pin_jacobian is None:
            return
        # the pin's Jacobian lives on few channels (the value): only those enter
        ch = torch.nonzero(torch.isin(used, self._pin_channels)).flatten()
        if ch.numel() == 0:
            return
        width = self.jacobian.shape[3] * COMPONENTS
        # the same at every point (an expanded view)
        pin_jac = self.pin_jacobian[:, :1, used[ch]].expand(-1, blocks.shape[0], -1, -1)
        cross = self._group_sums(jacobian, blocks[:, :, :, ch], pin_jac, m)
        pin_pin = self._group_sums(ComponentJacobian(list(pin_jac), (0, 1, 2)),
                                   blocks[:, ch][:, :, :, ch], pin_jac, m).sum(dim=0)
        if pin[0] is None:
            pin[0], pin[1] = blocks.new_zeros(self.size, width), 0.0
        rows = self._group_dofs.reshape(self._groups, width)[torch.from_numpy(groups)]
        pin[0].index_add_(0, rows.reshape(-1), cross.reshape(-1, width))
        pin[1] = pin[1] + pin_pin

    def _point_hessian(self, blocks_of: Callable[[slice], torch.Tensor], chunk: int
                       ) -> sp.csr_matrix:
        """Σ Jᵀ H J of the per-point blocks H (`hessian`), chunk by chunk of points."""
        data, width = np.zeros(len(self._columns)), self.jacobian.shape[3] * COMPONENTS
        pin = [None, None]  # Σ J_localᵀ H J_pin (3n × 3k) and the pin–pin block, if any
        for parts in self._chunks(chunk):
            first = parts[0][0].start
            fetched = blocks_of(slice(first, parts[-1][0].stop))
            for points, groups in parts:
                here = fetched[points.start - first:points.stop - first]
                if groups is not None:
                    self._add_points(data, pin, self.jacobian.rows(points), here,
                                     np.arange(groups.start, groups.stop), self._per_group)
                    continue
                for rows, padded, ids, size in self._extra_batches(here):
                    self._add_points(data, pin, self.jacobian.rows(points.start + rows),
                                     padded, ids, size)
            fetched = None
        dense, pin_pin = pin
        matrix = sp.csr_matrix((data, self._columns, self._row_starts),
                               shape=(self.size, self.size))
        if dense is None:
            return matrix
        # Couplings through the pin's coefficients: Σ J_localᵀ H J_pin at the rows of the
        # points' unknowns and the pin's columns, its transpose, and the pin–pin block.
        dense = dense.double().cpu().numpy()
        rows = np.flatnonzero(np.abs(dense).sum(axis=1))
        coupling = sp.csr_matrix(
            (dense[rows].ravel(), (np.repeat(rows, width), np.tile(self.pin_dofs, len(rows)))),
            shape=(self.size, self.size))
        pin_block = sp.csr_matrix(
            (pin_pin.double().cpu().numpy().ravel(),
             (np.repeat(self.pin_dofs, width), np.tile(self.pin_dofs, width))),
            shape=(self.size, self.size))
        return (matrix + coupling + coupling.T + pin_block).tocsr()


def displacement_at(operator: DisplacementOperator, xi: torch.Tensor,
                    coefficients: torch.Tensor, load_factor: float) -> torch.Tensor:
    """Displacement jets (N, 6, 3) [m] at ξ (N, 2) of the operator's field with `coefficients`
    (n, 3) in place of its own, at load factor t (e.g. at probe points)."""
    basis = local_basis_at(operator, xi)
    offset, jacobian, pin_jacobian = linearised(operator, xi, basis, load_factor)
    u = jacobian.apply(coefficients[basis.index])
    if pin_jacobian is not None:
        u = u + _pin_displacement(pin_jacobian, coefficients[basis.pin_index])
    return offset + operator.to_world(u)


def gauge_unknowns(boundary: BoundaryConditions, basis: LocalBasis) -> np.ndarray | None:
    """Unknowns to hold so that K is regular: with a free pin (u = N(ξ) − N(ξ₀)) adding a
    constant to every coefficient of a held component changes nothing (the B-splines sum to
    1), so one coefficient per held component is held: the pin's largest. None otherwise."""
    if boundary.free_pin is None:
        return None
    coefficient = int(basis.pin_index[int(torch.argmax(basis.pin_jets[jets.VALUE]))])
    held = [COMPONENTS_XYZ.index(c) for c in boundary.free_pin.components]
    return np.array([coefficient * COMPONENTS + c for c in held], dtype=np.int64)
