"""Derivatives of a minimiser with respect to parameters: one factorisation of the exact K.

At a minimiser C*(θ) of Π(C; θ) the gradient g(C*, θ) vanishes; the implicit-function theorem
gives dC*/dθ_j = −K⁻¹ ∂g/∂θ_j with K = d²Π/dC² at C* — of the EXACT per-point Hessian blocks
(not projected: the projection is a device of the minimiser's steps, not a property of the
minimum). K is assembled once (`SplineLinearisation.hessian`), factorised once (SuperLU in
symmetric mode, as `linear_solve`), and every right-hand side is solved with that factor. Its
pivots tell whether K is positive definite: if it is not, C* is not a strict local minimum (an
unstable or neutral equilibrium) and the derivatives describe a saddle; the caller must say so.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import torch

from taichi_ndf.minimise.linear_solve import _positive_pivots as positive_pivots
from taichi_ndf.minimise.linearisation import SplineLinearisation
from taichi_ndf.minimise.newton import coupled_blocks, point_blocks
from taichi_ndf.shell.hessian import Potential


def exact_hessian(linearisation: SplineLinearisation, potential: Potential,
                  coefficients: torch.Tensor, *, fd_step: float = 1e-5) -> sp.csr_matrix:
    """K = Σ Jᵀ H J (3n × 3n, CSR) of the exact, unprojected per-point (and pair) blocks at
    `coefficients` (n, 3); the linearisation at the potential's load factor
    (`GridLinearisation.linearisation`; its FD length and held unknowns: K is over every
    unknown), fd_step as `NewtonConfig` (Newton's own blocks: `point_blocks`)."""
    return exact_blocks(linearisation, potential, coefficients, fd_step=fd_step)[0]


def exact_blocks(linearisation: SplineLinearisation, potential: Potential,
                 coefficients: torch.Tensor, *, fd_step: float = 1e-5
                 ) -> tuple[sp.csr_matrix, torch.Tensor]:
    """`exact_hessian`'s K and the exact per-point blocks H (N, 18, 18) it is assembled from
    (at the linearisation's samples: products H v with displacement jets v off the field's
    span, e.g. a boundary's)."""
    u = linearisation.displacement(coefficients)
    blocks = point_blocks(linearisation, potential, coefficients, u, fd_step)
    return (linearisation.hessian(blocks, coupled_blocks(potential, linearisation.samples, u)),
            blocks)


@dataclass(frozen=True)
class Sensitivity:
    """dC*/dθ (n, 3, p) and whether K was positive definite (a stable equilibrium)."""

    derivative: torch.Tensor
    definite: bool


def sensitivity(matrix: sp.csr_matrix, gradient_derivatives: torch.Tensor,
                fixed: np.ndarray | None = None) -> Sensitivity:
    """dC*/dθ = −K⁻¹ ∂g/∂θ for every column of ∂g/∂θ (n, 3, p) with ONE factorisation of K
    (`matrix`, 3n × 3n, unknowns coefficient × 3 + component); unknowns in `fixed` (gauge
    freedoms) held at zero. Raises RuntimeError when K is singular."""
    n, components, p = gradient_derivatives.shape
    size = matrix.shape[0]
    free = np.ones(size, dtype=bool)
    if fixed is not None:
        free[fixed] = False
    reduced = matrix[free][:, free].tocsc()
    try:
        factor = spla.splu(reduced, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                           options={"SymmetricMode": True})
    except RuntimeError as err:
        raise RuntimeError(f"the equilibrium's Hessian K is singular: {err}") from None
    rhs = gradient_derivatives.reshape(size, p).double().cpu().numpy()
    out = np.zeros((size, p))
    out[free] = -factor.solve(np.ascontiguousarray(rhs[free]))
    if not np.all(np.isfinite(out)):
        raise RuntimeError("the equilibrium's Hessian K is singular (non-finite solution)")
    derivative = torch.from_numpy(out).to(gradient_derivatives).reshape(n, components, p)
    return Sensitivity(derivative, positive_pivots(factor))
