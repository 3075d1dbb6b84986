"""Held points' positions as unknowns of an observation: the handles' prescribed displacement.

A model's `Handle` moves a point ξ_h of the reference surface by a prescribed displacement
d_h [m] (world components), its slope held (`boundary.constraints.Handle`). Where the held
positions are themselves measured (a video's held corners, reconstructed with an error), they
are unknowns of the estimate: an observation's `free_handles` name its handles (their index
among the model's boundary constraints) whose displacement is d_h + δ_h, δ_h (3,) [m] fitted
per observation beside the shared material unknowns θ (`outer_fit.fit`).

The composition u_c = φ_c N_c + g_c (`boundary.conditions`) carries the handles in g, which
is linear in the displacements: g = Σ_h b_h(ξ) d_h with the blend b_h (jets) of handle h —
the same whether or not another handle prescribes the component (with two points the blend
is Φ_other / (Φ_h + Φ_other) either way). So dU/dδ_{h,c} = b_h e_c at every sample
(`unit_displacements`), exactly, and the implicit-function theorem gives the equilibrium's
sensitivity as for a material unknown: with g(C, δ) = ∂Π/∂C = Jᵀ ∂Π/∂U(U₀(δ) + J C),

    ∂g/∂δ_{h,c} = Jᵀ H (b_h e_c),    dC*/dδ = −K⁻¹ ∂g/∂δ,

H the exact per-sample Hessian blocks of Π with respect to the displacement jets (the blocks
K is assembled from), and the observed positions x(ξ) = X(ξ) + U₀(ξ; δ) + J(ξ) C move by
dx/dδ = b_h(ξ) e_c + J(ξ) dC*/dδ (`SplineEquilibrium.position_sensitivity`).

The reference surface and the held slope stay where the model put them: a handle's point moves,
its tangent plane does not turn (a change of the held point of a few mm turns the line
between two corners by well under a degree, and the sheet leaves a held corner in a boundary
layer of the handle's band: `inverse.sft.hanging.hanging_across`).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from taichi_ndf.boundary import BoundaryConditions
from taichi_ndf.boundary.constraints import Handle

# The normalised coordinate of a handle offset in the outer fit: offsets are counted in this
# fraction of the reference domain's size (√ of its rectangle's area) — the outer step cap
# (`OuterConfig.max_step`, 1) is then 1 % of the sheet per iteration.
OFFSET_SCALE = 0.01


def check_free_handles(boundary: BoundaryConditions, free: tuple[int, ...]) -> tuple[int, ...]:
    """`free` as a tuple of distinct indices of `Handle` constraints of `boundary`; ValueError
    naming the problem otherwise."""
    free = tuple(int(h) for h in free)
    constraints = boundary.constraints
    if len(set(free)) != len(free):
        raise ValueError(f"free_handles lists a handle twice: {free}")
    for h in free:
        if not 0 <= h < len(constraints) or not isinstance(constraints[h], Handle):
            raise ValueError(f"free_handles: constraint {h} of the model is not a Handle "
                             f"(constraints: {[type(c).__name__ for c in constraints]})")
    return free


def displaced(boundary: BoundaryConditions, free: tuple[int, ...],
              offsets: np.ndarray) -> BoundaryConditions:
    """The conditions with handle free[i] moved by its displacement plus offsets[i] (3,) [m]
    (world components); every other constraint as it is."""
    offsets = np.asarray(offsets, dtype=np.float64).reshape(len(free), 3)
    constraints = list(boundary.constraints)
    for h, offset in zip(free, offsets, strict=True):
        handle = constraints[h]
        constraints[h] = dataclasses.replace(
            handle, displacement=tuple(float(v) for v in np.asarray(handle.displacement)
                                       + offset))
    return _rebuilt(boundary, constraints)


def displaced_model(model, free: tuple[int, ...], offsets: np.ndarray):
    """The model (`ShellModel`) with its handles free[i] moved by offsets[i] [m] and held
    there (a fitted observation's handles made known)."""
    return dataclasses.replace(model, boundary=displaced(model.boundary, free, offsets))


def unit_displacements(boundary: BoundaryConditions, free: tuple[int, ...],
                       xi: torch.Tensor) -> torch.Tensor:
    """dU/dδ at ξ (N, 2): jets (N, 6, 3, 3k) [m/m] of the prescribed displacement per unit
    offset of each free handle's coordinate (column 3i + c: handle free[i], world axis c):
    g of the conditions with that handle moved by e_c minus g of the conditions as they are
    (g is linear in a handle's displacement while the constraints prescribing each component
    stay the same; with two handles always: module docstring)."""
    base = boundary.prescribed_displacement(xi, 1.0)
    columns = []
    for i in range(len(free)):
        for c in range(3):
            offsets = np.zeros((len(free), 3))
            offsets[i, c] = 1.0
            moved = displaced(boundary, free, offsets)
            columns.append(moved.prescribed_displacement(xi, 1.0) - base)
    return torch.stack(columns, dim=-1)


def offset_report(fit, observations, labels) -> list[dict]:
    """Per observation (`labels`, e.g. frame numbers) of an outer fit (`ForwardFit`): whether
    its handles were fitted and, if so, their offsets (k, 3) [m] and the offsets' Gauss–Newton
    standard errors [m] (`offset_errors`)."""
    errors = offset_errors(fit) or [None] * len(labels)
    values = fit.local_values or [None] * len(labels)
    out = []
    for label, obs, offset, error in zip(labels, observations, values, errors, strict=True):
        if not obs.free_handles:
            out.append({"frame": label, "fitted": False})
            continue
        offset = offset.reshape(-1, 3)
        out.append({"frame": label, "fitted": True, "offset_m": offset.tolist(),
                    "offset_norm_m": np.linalg.norm(offset, axis=1).tolist(),
                    "standard_error_m": error.reshape(-1, 3).tolist()})
    return out


def offset_errors(fit) -> list[np.ndarray]:
    """Per observation: its local unknowns' Gauss–Newton standard errors (the residual
    variance at the estimate; θ estimated too: the full Jacobian, not θ's profiled one;
    independent residuals assumed); [] without local unknowns."""
    if fit.full_jacobian is None:
        return []
    full = fit.full_jacobian
    p = full.shape[1] - fit.nuisance
    sigma2 = float(fit.residuals @ fit.residuals) / max(len(fit.residuals) - full.shape[1], 1)
    try:
        variance = np.diag(np.linalg.inv(full.T @ full))[p:] * sigma2
    except np.linalg.LinAlgError:
        variance = np.full(fit.nuisance, np.inf)
    ends = np.cumsum([len(v) for v in fit.local_values])
    return np.split(np.sqrt(np.maximum(variance, 0.0)), ends[:-1])


def _rebuilt(boundary: BoundaryConditions, constraints) -> BoundaryConditions:
    return BoundaryConditions(constraints, boundary.domain, surface=boundary.surface,
                              length=boundary.length, frame=boundary.frame)
