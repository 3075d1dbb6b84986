"""Per-point Hessian blocks of the shell's strain energy through its strains.

At a sample the strain energy E = w √a Ψ(s) depends on the displacement jets U (6 channels × 3
components) only through the six strains s = (ε₁₁, ε₁₂, ε₂₂, κ₁₁, κ₁₂, κ₂₂) (physics.md §2–3;
every law reads the reference geometry, which U does not change). So

    d²E/dU² = Jᵀ (d²E/ds²) J + Σ_s (dE/ds) d²s/dU²,       J = ds/dU (6 × 18),

a Gauss–Newton part and a stress part. The kinematic derivatives are exact (below); dE/ds is
the Taichi-autodiff gradient of a kernel that evaluates the law on given strains (the same
`LAW_TERMS` and `strain_energy_density` as the energy kernel), and d²E/ds² (6 × 6) central
differences of that gradient — exact up to rounding for the quadratic laws (linear isotropic,
orthotropic StVK), truncation ~step² for the Clyde law. 13 launches of a kernel without
geometry derivatives replace the 36 full energy gradients of `sample_hessians`. The external
loads are linear in U (the pressure follows the reference normal) and add nothing.

Kinematics (x = r + u, x_α its tangents, x_αβ second derivatives, m = x₁ × x₂, ℓ = |m|,
n = m/ℓ, P = I − n nᵀ, [a]× the cross-product matrix):
    ε_αβ = ½ (x_α·x_β − a_αβ):  dε₁₁/dx₁ = x₁, dε₂₂/dx₂ = x₂, dε₁₂/dx₁ = ½ x₂, dε₁₂/dx₂ = ½ x₁;
        d²ε₁₁/dx₁² = d²ε₂₂/dx₂² = I, d²ε₁₂/dx₁dx₂ = ½ I.
    κ_αβ = b_αβ − x_αβ·n, with v = x_αβ and g = P v/ℓ:
        dκ/dx_αβ = −n, dκ/dx₁ = −x₂ × g, dκ/dx₂ = −g × x₁;
        dn/dx₁ = −(P/ℓ)[x₂]×, dn/dx₂ = (P/ℓ)[x₁]× (the mixed x_αβ–x_γ second derivatives);
        d²(v·n)/dx_a dx_b = M_aᵀ F M_b (+ −[g]× for (x₁, x₂), +[g]× for (x₂, x₁)),
        M₁ = −[x₂]×, M₂ = [x₁]×, F = (−v nᵀ − n vᵀ − (v·n) I + 3 (v·n) n nᵀ)/ℓ².
The stress part of the bending strains uses v = V = Σ_αβ (dE/dκ_αβ) x_αβ at once.
"""

# No `from __future__ import annotations`: this module defines Taichi kernels.

import functools

import taichi as ti
import torch

from taichi_ndf import jets
from taichi_ndf.sampling import SurfaceSamples
from taichi_ndf.shell.energy import law_inputs
from taichi_ndf.shell.kinematics import mat2, reference_geometry, strains
from taichi_ndf.shell.law_terms import LAW_TERMS, strain_energy_density
from taichi_ndf.shell.materials import Material

STRAINS = 6  # ε₁₁, ε₁₂, ε₂₂, κ₁₁, κ₁₂, κ₂₂
BENDING_CHANNELS = (jets.D11, jets.D12, jets.D22)


@functools.cache
def _law_kernel(law: str):
    """E_i = w_i √a_i Ψ(s_i) of one constitutive law at given strains s (N, 6) (compiled on
    first use); its reverse-mode gradient is dE_i/ds_i."""
    law_terms = LAW_TERMS[law]

    @ti.kernel
    def energy_of_strains(r: ti.types.ndarray(), strain: ti.types.ndarray(),
                          weight: ti.types.ndarray(), stiffness: ti.types.ndarray(),
                          params: ti.types.ndarray(), energy: ti.types.ndarray()):
        for i in range(r.shape[0]):
            a1, a2, a3, metric, _, area_element = reference_geometry(r, i)
            eps = mat2([[strain[i, 0], strain[i, 1]], [strain[i, 1], strain[i, 2]]])
            kappa = mat2([[strain[i, 3], strain[i, 4]], [strain[i, 4], strain[i, 5]]])
            t = law_terms(eps, kappa, a1, a2, a3, metric, params)
            energy[i] = weight[i] * area_element * strain_energy_density(t, stiffness, i)

    return energy_of_strains


def _strain_gradient(kernel, r, strain, weight, stiffness, params) -> torch.Tensor:
    """dE/ds (N, 6) at strains s (N, 6) (Taichi reverse mode)."""
    s = strain.contiguous().requires_grad_(True)
    energy = torch.zeros(s.shape[0], dtype=s.dtype, device=s.device, requires_grad=True)
    s.grad = torch.zeros_like(s)
    energy.grad = torch.ones_like(energy)
    args = (r, s, weight, stiffness, params, energy)
    kernel(*args)
    kernel.grad(*args)
    return s.grad


def _cross_matrix(a: torch.Tensor) -> torch.Tensor:
    """[a]× (N, 3, 3) with [a]× b = a × b, for a (N, 3)."""
    zero = torch.zeros_like(a[:, 0])
    return torch.stack((torch.stack((zero, -a[:, 2], a[:, 1]), -1),
                        torch.stack((a[:, 2], zero, -a[:, 0]), -1),
                        torch.stack((-a[:, 1], a[:, 0], zero), -1)), 1)


def _strain_jacobian(x: torch.Tensor, n: torch.Tensor, length: torch.Tensor) -> torch.Tensor:
    """J = ds/dU (N, 6 strains, 6 channels, 3) at deformed jets x (N, 6, 3) with unit normal
    n (N, 3) and ℓ = |x₁ × x₂| (N,) (module docstring)."""
    x1, x2 = x[:, jets.D1], x[:, jets.D2]
    jac = x.new_zeros(x.shape[0], STRAINS, jets.CHANNELS, 3)
    jac[:, 0, jets.D1] = x1
    jac[:, 1, jets.D1] = 0.5 * x2
    jac[:, 1, jets.D2] = 0.5 * x1
    jac[:, 2, jets.D2] = x2
    for b, channel in enumerate(BENDING_CHANNELS):
        v = x[:, channel]
        g = (v - (v * n).sum(1, keepdim=True) * n) / length[:, None]
        jac[:, 3 + b, channel] = -n
        jac[:, 3 + b, jets.D1] = -torch.linalg.cross(x2, g)
        jac[:, 3 + b, jets.D2] = -torch.linalg.cross(g, x1)
    return jac


def _stress_part(x: torch.Tensor, n: torch.Tensor, length: torch.Tensor,
                 stress: torch.Tensor) -> torch.Tensor:
    """Σ_s (dE/ds) d²s/dU², shape (N, 6, 3, 6, 3), for stress = dE/ds (N, 6)."""
    count = x.shape[0]
    out = x.new_zeros(count, jets.CHANNELS, 3, jets.CHANNELS, 3)
    eye = torch.eye(3, dtype=x.dtype, device=x.device)
    d1, d2 = jets.D1, jets.D2
    out[:, d1, :, d1] += stress[:, 0, None, None] * eye
    out[:, d2, :, d2] += stress[:, 2, None, None] * eye
    out[:, d1, :, d2] += 0.5 * stress[:, 1, None, None] * eye
    out[:, d2, :, d1] += 0.5 * stress[:, 1, None, None] * eye
    x1, x2 = x[:, d1], x[:, d2]
    projector = eye - n[:, :, None] * n[:, None, :]
    inv = (1.0 / length)[:, None, None]
    dn = {d1: -inv * projector @ _cross_matrix(x2), d2: inv * projector @ _cross_matrix(x1)}
    moments = stress[:, 3:]
    v = torch.zeros_like(x1)
    for b, channel in enumerate(BENDING_CHANNELS):
        m = moments[:, b, None, None]
        v = v + moments[:, b, None] * x[:, channel]
        for a in (d1, d2):
            out[:, channel, :, a] -= m * dn[a]
            out[:, a, :, channel] -= m * dn[a].transpose(1, 2)
    vn = (v * n).sum(1)[:, None, None]
    outer = v[:, :, None] * n[:, None, :]
    f = (-outer - outer.transpose(1, 2) - vn * eye
         + 3.0 * vn * n[:, :, None] * n[:, None, :]) * inv * inv
    g = (v - vn[:, :, 0] * n) / length[:, None]
    mm = {d1: -_cross_matrix(x2), d2: _cross_matrix(x1)}
    gx = _cross_matrix(g)
    for a in (d1, d2):
        for b in (d1, d2):
            second = mm[a].transpose(1, 2) @ f @ mm[b]
            if a != b:
                second = second + (-gx if a == d1 else gx)
            out[:, a, :, b] -= second
    return out


def strain_energy_hessians(material: Material, samples: SurfaceSamples, u_jets: torch.Tensor,
                           *, steps: torch.Tensor, stiffness: torch.Tensor | None = None
                           ) -> torch.Tensor:
    """Per-point Hessian blocks d²E/dU² (N, 6, 3, 6, 3) of the strain energy (module
    docstring), symmetrised; zero at point-load samples (weight 0).

    steps: the jet channels' central-difference steps (6,) (`jet_steps`); the strain steps
    are the strain changes they cause: δε = the tangent step × the RMS tangent length,
    δκ = the largest second-derivative step. stiffness: per-sample stiffness (N, K) or None.
    """
    count = len(samples)
    r_all = samples.r_jets
    dtype, device = r_all.dtype, r_all.device
    kernel_stiffness, params = law_inputs(material, count, stiffness, dtype, device)
    active = torch.nonzero(samples.weight != 0).flatten()
    out = r_all.new_zeros(count, jets.CHANNELS, 3, jets.CHANNELS, 3)
    if active.numel() == 0:
        return out
    r = r_all[active].contiguous()
    u = u_jets.detach().to(dtype)[active]
    x = r + u
    eps, kappa, _ = strains(r, u)
    strain = torch.stack((eps[:, 0, 0], eps[:, 0, 1], eps[:, 1, 1],
                          kappa[:, 0, 0], kappa[:, 0, 1], kappa[:, 1, 1]), dim=1)
    weight = samples.weight[active].contiguous()
    kstiff = kernel_stiffness[active].contiguous()
    kernel = _law_kernel(material.law)
    stress = _strain_gradient(kernel, r, strain, weight, kstiff, params)
    tangent = float(x[:, jets.D1:jets.D2 + 1].pow(2).sum(2).mean().sqrt())
    delta_e = float(steps[jets.D1:jets.D2 + 1].max()) * tangent
    delta_k = float(steps[jets.D11:].max())
    stiffness_s = strain.new_empty(strain.shape[0], STRAINS, STRAINS)
    for j in range(STRAINS):
        delta = delta_e if j < 3 else delta_k
        shifted = strain.clone()
        shifted[:, j] += delta
        plus = _strain_gradient(kernel, r, shifted, weight, kstiff, params)
        shifted[:, j] -= 2 * delta
        minus = _strain_gradient(kernel, r, shifted, weight, kstiff, params)
        stiffness_s[:, :, j] = (plus - minus) / (2 * delta)
    stiffness_s = 0.5 * (stiffness_s + stiffness_s.transpose(1, 2))
    normal = torch.linalg.cross(x[:, jets.D1], x[:, jets.D2])
    length = normal.norm(dim=1)
    n = normal / length[:, None]
    jac = _strain_jacobian(x, n, length).reshape(-1, STRAINS, jets.CHANNELS * 3)
    blocks = (jac.transpose(1, 2) @ stiffness_s @ jac).reshape(
        -1, jets.CHANNELS, 3, jets.CHANNELS, 3) + _stress_part(x, n, length, stress)
    out[active] = 0.5 * (blocks + blocks.permute(0, 3, 4, 1, 2))
    return out
