"""Exact Kirchhoff–Love kinematics (physics.md §2), valid for arbitrarily large rotations.

Per-sample formulas are Taichi `ti.func`s on small vectors and matrices, used inside the energy
kernel; `strains` is the torch-facing entry point for tests, outputs and the inverse package.

For a surface with jets p (value, p_,1, p_,2, p_,11, p_,12, p_,22):
    covariant basis a_α = p_,α, metric a_αβ = a_α·a_β, √a = |a₁ × a₂|, normal a₃ = a₁×a₂/√a,
    second fundamental form b_αβ = p_,αβ · a₃, contravariant metric a^{αβ} = (a_αβ)⁻¹.
Strains (reference without bar, deformed x = r + u with bar):
    membrane ε_αβ = ½ (ā_αβ − a_αβ)        bending κ_αβ = b_αβ − b̄_αβ
"""

# No `from __future__ import annotations` in Taichi modules: ti.func needs real annotation
# objects (ti.template()), not strings. Vector and matrix types are ti.math's, which follow the
# runtime's default float type; types built here with `float` would freeze f32 at import.

import torch

from taichi_ndf import jets
from taichi_ndf.runtime import ti

vec3 = ti.math.vec3
mat2 = ti.math.mat2


@ti.func
def jet_channel(jet_array: ti.template(), i, c: ti.template()) -> vec3:
    """Channel c of the (N, 6, 3) jets of sample i, as a vector."""
    return vec3(jet_array[i, c, 0], jet_array[i, c, 1], jet_array[i, c, 2])


@ti.func
def surface_geometry(p1: vec3, p2: vec3, p11: vec3, p12: vec3, p22: vec3):
    """Geometry of a surface from its derivative jets.

    Returns (a₁, a₂, a₃, a_αβ, b_αβ, √a): covariant basis, unit normal, metric (mat2),
    second fundamental form (mat2) and area element.
    """
    normal = p1.cross(p2)
    sqrt_a = normal.norm()
    a3 = normal / sqrt_a
    a12 = p1.dot(p2)
    metric = mat2([[p1.dot(p1), a12], [a12, p2.dot(p2)]])
    b12 = p12.dot(a3)
    curvature = mat2([[p11.dot(a3), b12], [b12, p22.dot(a3)]])
    return p1, p2, a3, metric, curvature, sqrt_a


@ti.func
def reference_geometry(r: ti.template(), i):
    """`surface_geometry` of the reference surface at sample i from its jets r (N, 6, 3)."""
    return surface_geometry(jet_channel(r, i, jets.D1), jet_channel(r, i, jets.D2),
                            jet_channel(r, i, jets.D11), jet_channel(r, i, jets.D12),
                            jet_channel(r, i, jets.D22))


@ti.func
def deformed_geometry(r: ti.template(), u: ti.template(), i):
    """`surface_geometry` of the deformed surface x = r + u at sample i."""
    return surface_geometry(
        jet_channel(r, i, jets.D1) + jet_channel(u, i, jets.D1),
        jet_channel(r, i, jets.D2) + jet_channel(u, i, jets.D2),
        jet_channel(r, i, jets.D11) + jet_channel(u, i, jets.D11),
        jet_channel(r, i, jets.D12) + jet_channel(u, i, jets.D12),
        jet_channel(r, i, jets.D22) + jet_channel(u, i, jets.D22),
    )


@ti.func
def contravariant_metric(metric: mat2) -> mat2:
    """a^{αβ}, the inverse of the metric a_αβ."""
    det = metric[0, 0] * metric[1, 1] - metric[0, 1] * metric[1, 0]
    return mat2([[metric[1, 1], -metric[0, 1]], [-metric[1, 0], metric[0, 0]]]) / det


@ti.func
def membrane_strain(reference_metric: mat2, deformed_metric: mat2) -> mat2:
    """Green–Lagrange membrane strain ε_αβ = ½ (ā_αβ − a_αβ) [covariant components]."""
    return 0.5 * (deformed_metric - reference_metric)


@ti.func
def bending_strain(reference_curvature: mat2, deformed_curvature: mat2) -> mat2:
    """Bending strain κ_αβ = b_αβ − b̄_αβ [covariant components]."""
    return reference_curvature - deformed_curvature


@ti.kernel
def _strain_kernel(r: ti.types.ndarray(), u: ti.types.ndarray(), eps: ti.types.ndarray(),
                   kappa: ti.types.ndarray(), sqrt_a: ti.types.ndarray()):
    for i in range(r.shape[0]):
        _, _, _, metric, curvature, area = reference_geometry(r, i)
        _, _, _, metric_bar, curvature_bar, _ = deformed_geometry(r, u, i)
        e = membrane_strain(metric, metric_bar)
        k = bending_strain(curvature, curvature_bar)
        for a, b in ti.static(ti.ndrange(2, 2)):
            eps[i, a, b] = e[a, b]
            kappa[i, a, b] = k[a, b]
        sqrt_a[i] = area


def strains(r_jets: torch.Tensor, u_jets: torch.Tensor):
    """Membrane and bending strains of the displacement u on the reference surface r.

    r_jets: reference surface jets (N, 6, 3) [m]; u_jets: displacement jets (N, 6, 3) [m].
    Returns (eps (N, 2, 2), kappa (N, 2, 2), sqrt_a (N,)): covariant membrane strain ε_αβ
    [m² per unit ξ²], bending strain κ_αβ [m per unit ξ²] and the reference area element √a.
    Not differentiable (no torch autograd); the energy carries its own gradient.
    """
    if r_jets.shape != u_jets.shape or r_jets.dim() != 3 or r_jets.shape[1:] != (6, 3):
        raise ValueError(f"r_jets and u_jets must both be (N, 6, 3), got {tuple(r_jets.shape)} "
                         f"and {tuple(u_jets.shape)}")
    r = r_jets.detach().contiguous()
    u = u_jets.detach().to(r.dtype).contiguous()
    n = r.shape[0]
    eps = r.new_zeros(n, 2, 2)
    kappa = r.new_zeros(n, 2, 2)
    sqrt_a = r.new_zeros(n)
    if n:
        _strain_kernel(r, u, eps, kappa, sqrt_a)
    return eps, kappa, sqrt_a
