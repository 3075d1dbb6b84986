"""The two linearisations Newton runs over (`taichi_ndf.minimise.newton.Linearisation`).

`DenseLinearisation`: U = U₀ + J P with a dense Jacobian per component, J (3, N, 6, p), and
parameters P (3, p), component k acting only on u_k — a SIREN's output layer
(`last_layer.output_linearisation`), or any small field written out densely. K is a dense
matrix (3p × 3p, unknowns component × p + parameter) and the damped solve a Cholesky
factorisation of the Jacobi-scaled K + μ I (`damped_step`).

`SplineLinearisation`: a local-support field's coefficients C (n, 3) on an `Assembly` (sparse
J, K in CSR, unknowns coefficient × 3 + component), with held unknowns (gauge freedoms,
coefficients no point reads: `held_unknowns`), the
sparse direct or multigrid solve (`linear_solve`) and the spline's FD step rule (`jet_steps`).
`GridLinearisation` is the one place that builds it: span quadrature → local basis →
`Assembly` → `SplineLinearisation` on one grid, with its held unknowns, linear solver and FD
length, the assembly kept per grid and rebuilt on new points (a contact round's).

Both solve (K + μ D) d = −g with D the diagonal of K (the dense one as D^½ (D^-½ K D^-½ + μ I)
D^½, the same matrix).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import torch

from taichi_ndf.boundary import BoundaryConditions
from taichi_ndf.field.spline import SplineConfig
from taichi_ndf.geometry import ReferenceSurface
from taichi_ndf.minimise.assembly import (
    Assembly,
    LocalBasis,
    gauge_unknowns,
    linearised,
    local_basis_at,
)
from taichi_ndf.minimise.jacobian import ComponentJacobian
from taichi_ndf.minimise.linear_solve import LinearSolver, LinearSolverConfig, damped_solve
from taichi_ndf.objective.couplings import Couplings
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.operator import DisplacementOperator
from taichi_ndf.problem.quadrature import span_quadrature
from taichi_ndf.problem.sampling import SurfaceSamples
from taichi_ndf.shell.hessian import COMPONENTS, JET_SIZE, jet_steps

# Least damping of the dense solve, relative to the mean diagonal of the Jacobi-scaled K:
# nearly collinear features and zero-energy motions (rigid modes) would otherwise take steps
# made of rounding noise.
EIGEN_CUTOFF = 1e-14
# An unknown whose every read (|J| per jet channel) is at most this × the channel's largest
# is held (`unread_unknowns`): K's entries go with |J|², and below √(k ε) — k = 147, the
# unknowns one cubic coefficient's row couples, (2p + 1)² × 3, over which the factorisation
# accumulates rounding — its pivot is rounding noise (float64: 1.8e-7).
READ_FLOOR = float(np.sqrt(147 * np.finfo(np.float64).eps))


def parameter_gradient(jacobian: torch.Tensor, grad_u_jets: torch.Tensor) -> torch.Tensor:
    """dΠ/dP, shape (3, p), from dΠ/du_jets (N, 6, 3) and J (3, N, 6, p)."""
    return torch.einsum("knca,nck->ka", jacobian, grad_u_jets)


def parameter_hessian(jacobian: torch.Tensor, hessians: torch.Tensor) -> torch.Tensor:
    """d²Π/dP², shape (3p, 3p), from J (3, N, 6, p) and the per-point blocks (N, 6, 3, 6, 3):
    exact, since u is affine in P."""
    _, n, channels, p = jacobian.shape
    blocks = {}
    for k in range(COMPONENTS):
        flat_k = jacobian[k].reshape(n * channels, p)
        for m in range(k, COMPONENTS):  # the blocks below the diagonal are transposes
            block = hessians[:, :, k, :, m]  # (N, 6, 6)
            # Σ_d h[n, c, d] J[n, d, a] as six broadcast products: batched 6 × 6 GEMMs are
            # ~50 × slower on the CPU.
            weighted = sum(block[:, :, d, None] * jacobian[m][:, d, None, :]
                           for d in range(channels))
            blocks[k, m] = flat_k.t() @ weighted.reshape(n * channels, p)
            blocks[m, k] = blocks[k, m].t()
    return torch.cat([torch.cat([blocks[k, m] for m in range(COMPONENTS)], dim=1)
                      for k in range(COMPONENTS)], dim=0)


def coupled_parameter_hessian(jacobian: torch.Tensor, couplings: Couplings) -> torch.Tensor:
    """Σ_p A_pᵀ H_p A_p, shape (3p, 3p), of pair blocks H_p (`Couplings`) with J (3, N, 6, p):
    the Hessian of terms that couple pairs of points over the parameters."""
    ends = couplings.endpoint_blocks().to(jacobian.dtype)  # (P, 2, 6, 3, 2, 6, 3)
    first = jacobian[:, couplings.points[:, 0]]
    second = jacobian[:, couplings.points[:, 1]]
    pair = (first, second)
    comps, _, _, p = jacobian.shape
    total = jacobian.new_zeros(comps, p, comps, p)
    for a in range(2):
        for b in range(2):
            total += torch.einsum("kqia,qikjm,mqjb->kamb", pair[a], ends[:, a, :, :, b],
                                  pair[b])
    return total.reshape(comps * p, comps * p)


def _scaled_system(hessian: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The Jacobi scaling s = |diag K|^-½ and the symmetrised scaled matrix s K s."""
    diag = hessian.diagonal().abs()
    scale = 1.0 / torch.sqrt(torch.clamp(diag, min=float(diag.max()) * 1e-30 + 1e-300))
    scaled = scale[:, None] * hessian * scale[None, :]
    return scale, 0.5 * (scaled + scaled.t())


def damped_step(hessian: torch.Tensor, gradient: torch.Tensor, damping: float) -> torch.Tensor:
    """Levenberg–Marquardt step −(K + μ)⁻¹ g on the Jacobi-scaled K, μ = damping × its mean
    diagonal (at least EIGEN_CUTOFF ×), raised until the Cholesky factorisation succeeds
    (negative curvature). gradient: flat (3p,)."""
    scale, scaled = _scaled_system(hessian)
    mu = max(damping, EIGEN_CUTOFF) * float(scaled.diagonal().mean())
    eye = torch.eye(scaled.shape[0], dtype=scaled.dtype, device=scaled.device)
    while True:
        factor, info = torch.linalg.cholesky_ex(scaled + mu * eye)
        if int(info) == 0:
            break
        mu *= 10
    solution = torch.cholesky_solve((scale * gradient)[:, None], factor)[:, 0]
    return -scale * solution


class DenseLinearisation:
    """U(P) = U₀ + Σ_a J[k, :, :, a] P[k, a] per component k (module docstring).

    samples: the points; offset U₀ (N, 6, 3) [m]; jacobian J (3, N, 6, p); origin: the
    parameter values P = 0 stands for (3, p) (e.g. the output layer θ₀ when P is its change;
    zeros when P is absolute), for the FD step rule."""

    def __init__(self, samples: SurfaceSamples, offset: torch.Tensor, jacobian: torch.Tensor,
                 origin: torch.Tensor | None = None):
        self.samples, self.offset, self.jacobian = samples, offset, jacobian
        self.origin = (jacobian.new_zeros(jacobian.shape[0], jacobian.shape[3])
                       if origin is None else origin)

    def displacement(self, parameters: torch.Tensor) -> torch.Tensor:
        return self.offset + torch.einsum("knca,ka->nck", self.jacobian, parameters)

    def gradient(self, grad_u_jets: torch.Tensor) -> torch.Tensor:
        return parameter_gradient(self.jacobian, grad_u_jets)

    def fd_steps(self, u_jets: torch.Tensor, parameters: torch.Tensor,
                 relative: float) -> torch.Tensor:
        """`relative` × each channel's RMS of u, or the RMS a typical change of the
        parameters would make where the displacement vanishes."""
        rms_u = u_jets.pow(2).mean(dim=(0, 2)).sqrt()
        rms_theta = (self.origin + parameters).pow(2).mean().sqrt()
        rms_j = self.jacobian.pow(2).mean(dim=(0, 1, 3)).sqrt()
        scale = torch.maximum(rms_u, rms_j * rms_theta)
        return relative * torch.where(scale > 0, scale, torch.ones_like(scale))

    def hessian(self, blocks, couplings: Couplings | None = None) -> torch.Tensor:
        """K (3p × 3p) from blocks (N, 18, 18) or a function of a slice of points giving
        theirs (asked once for all points: the dense J holds more than the blocks)."""
        if callable(blocks):
            blocks = blocks(slice(0, len(self.samples)))
        n = blocks.shape[0]
        channels = JET_SIZE // COMPONENTS
        matrix = parameter_hessian(self.jacobian,
                                   blocks.reshape(n, channels, COMPONENTS, channels, COMPONENTS))
        if couplings is None:
            return matrix
        return matrix + coupled_parameter_hessian(self.jacobian, couplings)

    def solve(self, matrix: torch.Tensor, gradient: torch.Tensor, damping: float, *,
              require_definite: bool = False) -> tuple[torch.Tensor, float] | None:
        """`damped_step` (its μ raised internally; the damping given is returned); with
        require_definite None unless the Cholesky factorisation at that damping succeeds."""
        flat = gradient.reshape(-1)
        if require_definite:
            scale, scaled = _scaled_system(matrix)
            mu = max(damping, EIGEN_CUTOFF) * float(scaled.diagonal().mean())
            eye = torch.eye(scaled.shape[0], dtype=scaled.dtype, device=scaled.device)
            factor, info = torch.linalg.cholesky_ex(scaled + mu * eye)
            if int(info) != 0:
                return None
            step = -scale * torch.cholesky_solve((scale * flat)[:, None], factor)[:, 0]
        else:
            step = damped_step(matrix, flat, damping)
        return step.reshape(gradient.shape), damping


class SplineLinearisation:
    """A local-support field's coefficients C (n, 3) on an `Assembly` linearised at the load
    factor (`Assembly.at_load`; module docstring).

    fixed: unknowns (coefficient × 3 + component) held at 0 change; solver: the Newton
    systems' solve with `damped_solve`'s contract (`LinearSolver.for_grid`: multigrid on
    large grids; None: `damped_solve`); length: a length of the parameter domain [ξ units]
    for the FD steps (`jet_steps`)."""

    def __init__(self, assembly: Assembly, *, fixed: np.ndarray | None = None,
                 solver: LinearSolver | None = None, length: float = 1.0):
        self.assembly, self.fixed, self.length = assembly, fixed, length
        self._solve = solver or damped_solve

    @property
    def samples(self) -> SurfaceSamples:
        return self.assembly.samples

    def displacement(self, parameters: torch.Tensor) -> torch.Tensor:
        return self.assembly.displacement(parameters)

    def gradient(self, grad_u_jets: torch.Tensor) -> torch.Tensor:
        gradient = self.assembly.gradient(grad_u_jets)
        if self.fixed is not None:
            gradient.reshape(-1)[torch.from_numpy(self.fixed).to(gradient.device)] = 0.0
        return gradient

    def fd_steps(self, u_jets: torch.Tensor, parameters: torch.Tensor,
                 relative: float) -> torch.Tensor:
        return jet_steps(self.samples.r_jets, u_jets, self.length, relative)

    def hessian(self, blocks, couplings: Couplings | None = None) -> sp.csr_matrix:
        """K (CSR) from blocks (N, 18, 18) or a function of a slice of points giving theirs
        (`Assembly.hessian`: chunk by chunk)."""
        return self.assembly.hessian(blocks, couplings)

    def solve(self, matrix: sp.csr_matrix, gradient: torch.Tensor, damping: float, *,
              require_definite: bool = False) -> tuple[torch.Tensor, float] | None:
        rhs = -gradient.reshape(-1).double().cpu().numpy()
        result = self._solve(matrix, rhs, damping, self.fixed, require_definite=require_definite)
        if result is None:
            return None
        step, damping = result
        return torch.from_numpy(step).to(gradient).reshape(gradient.shape), damping


def held_unknowns(grid, boundary: BoundaryConditions | None, basis: LocalBasis,
                  assembly: Assembly | None = None) -> np.ndarray | None:
    """Unknowns held at zero: the gauge of a free pin (`gauge_unknowns`), the coefficients
    a mirrored spline never reads (`SplineField.aliased_coefficients`), which no point
    couples, and with an `assembly` (its J built) the unknowns its points do not read
    (`unread_unknowns`: a held patch's). grid: the `SplineField`; boundary None: no gauge."""
    held = [None if boundary is None else gauge_unknowns(boundary, basis)]
    aliased = grid.aliased_coefficients.numpy()
    if aliased.size:
        held.append((aliased[:, None] * COMPONENTS + np.arange(COMPONENTS)).reshape(-1))
    if assembly is not None:
        held.append(unread_unknowns(assembly))
    held = [h for h in held if h is not None and h.size]
    return np.unique(np.concatenate(held)) if held else None


def unread_unknowns(assembly: Assembly) -> np.ndarray:
    """The unknowns (coefficient × 3 + component, sorted) that the assembly's points read only
    at rounding's scale: in every jet channel the largest |J| over the points at or below
    `READ_FLOOR` × that channel's largest over all unknowns. The vanishing factor of a held
    patch (`Handle.radius`) is 0 on the patch, so a coefficient whose support lies in it
    (or reaches past its rim only where φ·N is ~1e-8 of its peak) moves nothing, and K's row
    of it is zero or rounding: singular for the sensitivity solve (`minimise.sensitivity`)
    and for the dynamics' adjoint. A free pin's coefficients are read at every point."""
    index = assembly.basis.index.reshape(-1)
    held = []
    for c in range(COMPONENTS):
        magnitude = assembly.jacobian.component(c).abs()  # (N, ch, k)
        reach = magnitude.new_zeros(magnitude.shape[1], assembly.n_coefficients)
        for channel in range(magnitude.shape[1]):
            reach[channel].scatter_reduce_(0, index, magnitude[:, channel].reshape(-1), "amax")
        largest = reach.amax(dim=1, keepdim=True)
        relative = torch.where(largest > 0, reach / largest.clamp_min(1e-300), 0.0)
        unread = relative.amax(dim=0) <= READ_FLOOR
        if assembly.basis.pin_index is not None:
            unread[assembly.basis.pin_index] = False
        held.append(torch.nonzero(unread).flatten().cpu().numpy() * COMPONENTS + c)
    return np.sort(np.concatenate(held)).astype(np.int64)


@dataclass(frozen=True)
class PointJacobian:
    """The spline field's displacement jets at fixed points ξ (N, 2), affine in the
    coefficients C (n, 3): U = offset + jacobian.apply(C[index]) (+ the pin's part, the same
    at every point), components along the boundary frame's axes.
    index (N, k) int64; offset (N, 6, 3) [m]; jacobian J (3, N, 6, k) as a
    `ComponentJacobian` (each distinct component stored once); pin_index (k,) and pin (3, N,
    6, k) (an expanded view) with a free pin, else None (`assembly.linearised`)."""

    index: torch.Tensor
    offset: torch.Tensor
    jacobian: ComponentJacobian
    pin_index: torch.Tensor | None
    pin: torch.Tensor | None


class GridLinearisation:
    """The one builder of a spline grid's linearisation (module docstring): span quadrature
    (`quadrature`) → the local basis at the points (`local_basis_at`) → an `Assembly`
    (`assemble`: a new one on given points, kept as the grid's current one) → at a load
    factor a `SplineLinearisation` (`linearisation`) with the grid's held unknowns (`fixed`),
    linear solver and FD length.

    field: the `SplineField` (its grid; its coefficients are not read); boundary: the
    conditions (None: none); length: a length of the parameter domain [ξ units] for the FD
    steps (`jet_steps`); linear: the linear solver's settings (`LinearSolver.for_grid`, one
    solver per grid, so that multigrid reuses its V-cycle between Newton steps and contact
    rounds), None: the direct `damped_solve`."""

    def __init__(self, field, boundary: BoundaryConditions | None, *, length: float = 1.0,
                 linear: LinearSolverConfig | None = None):
        self.field, self.boundary, self.length = field, boundary, length
        self.operator = DisplacementOperator(field, boundary)
        self.solver = None if linear is None else LinearSolver.for_grid(field.config, linear)
        self.assembly: Assembly | None = None
        self._fixed: np.ndarray | None = None
        self._fixed_known = False

    @staticmethod
    def quadrature(surface: ReferenceSurface, config: SplineConfig, loads: Loads | None = None,
                   *, points: int | None = None, dtype: torch.dtype | None = None
                   ) -> SurfaceSamples:
        """The Gauss points of every knot span of the grid `config` (`span_quadrature`: with
        a zero-weight sample per point load; dtype default the runtime's)."""
        return span_quadrature(surface, config, loads, points=points, dtype=dtype)

    def assemble(self, samples: SurfaceSamples) -> Assembly:
        """A new assembly on `samples` (reordered: its `samples`, `order`), the grid's current
        one from now on (a contact round's points replace the last round's; the last one is
        let go first, so that two are not held at once)."""
        self.assembly = None
        basis = local_basis_at(self.operator, samples.xi)
        self.assembly = Assembly(samples, basis, self.field.config.num_coefficients)
        if not self._fixed_known:  # J does not depend on the load factor
            self.assembly.at_load(self.operator, 1.0)
            self._fixed = held_unknowns(self.field, self.boundary, basis, self.assembly)
            self._fixed_known = True
        return self.assembly

    @property
    def fixed(self) -> np.ndarray | None:
        """The unknowns held at zero (`held_unknowns`); known after the first `assemble`."""
        if not self._fixed_known:
            raise RuntimeError("GridLinearisation.fixed before any assemble")
        return self._fixed

    def linearisation(self, load_factor: float, samples: SurfaceSamples | None = None
                      ) -> SplineLinearisation:
        """U = U₀ + J C at load factor t on the current assembly, or on a new one at
        `samples` where given (`assemble`). The linearisations of one assembly share it: the
        last load factor asked holds for all of them (a grid level's load steps run one
        after the other)."""
        if samples is not None:
            self.assemble(samples)
        if self.assembly is None:
            raise RuntimeError("GridLinearisation.linearisation before any assemble")
        self.assembly.at_load(self.operator, load_factor)
        return SplineLinearisation(self.assembly, fixed=self.fixed, solver=self.solver,
                                   length=self.length)

    def at_points(self, xi: torch.Tensor, load_factor: float) -> PointJacobian:
        """The displacement jets at ξ (N, 2) as an affine map of the coefficients, at load
        factor t (`PointJacobian`; e.g. contact's check points, observed points)."""
        basis = local_basis_at(self.operator, xi)
        offset, jacobian, pin = linearised(self.operator, xi, basis, load_factor)
        return PointJacobian(basis.index, offset, jacobian, basis.pin_index, pin)
