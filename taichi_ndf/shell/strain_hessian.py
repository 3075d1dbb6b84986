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

import torch

from taichi_ndf import jets
from taichi_ndf.problem.sampling import SurfaceSamples
from taichi_ndf.runtime import ti
from taichi_ndf.shell.energy import law_inputs
from taichi_ndf.shell.kinematics import jet_channel, mat2, reference_geometry, strains, vec3
from taichi_ndf.shell.law_terms import LAW_TERMS, strain_energy_density
from taichi_ndf.shell.materials import Material

mat3 = ti.math.mat3
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


@ti.func
def _cross_matrix(a: vec3) -> mat3:
    """[a]× with [a]× b = a × b."""
    return mat3([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


@ti.func
def _add_block(out: ti.template(), i, row: ti.template(), col: ti.template(), block: mat3):
    for k, m in ti.static(ti.ndrange(3, 3)):
        out[i, row, k, col, m] += block[k, m]


@ti.kernel
def _strain_derivatives(x: ti.types.ndarray(), stress: ti.types.ndarray(),
                        jac: ti.types.ndarray(), second: ti.types.ndarray(),
                        stress_part: ti.template()):
    """At deformed jets x (N, 6, 3) and stress = dE/ds (N, 6) (module docstring): J = ds/dU
    into jac (N, 6 strains, 6 channels, 3), zero on entry; with stress_part, Σ_s (dE/ds)
    d²s/dU² added to second (N, 6, 3, 6, 3) instead."""
    for i in range(x.shape[0]):
        x1 = jet_channel(x, i, jets.D1)
        x2 = jet_channel(x, i, jets.D2)
        normal = x1.cross(x2)
        length = normal.norm()
        n = normal / length
        projector = ti.Matrix.identity(float, 3) - n.outer_product(n)
        if ti.static(not stress_part):
            for k in ti.static(range(3)):
                jac[i, 0, jets.D1, k] = x1[k]
                jac[i, 1, jets.D1, k] = 0.5 * x2[k]
                jac[i, 1, jets.D2, k] = 0.5 * x1[k]
                jac[i, 2, jets.D2, k] = x2[k]
        dn1 = -(projector @ _cross_matrix(x2)) / length  # dn/dx₁
        dn2 = (projector @ _cross_matrix(x1)) / length  # dn/dx₂
        v_sum = vec3(0.0, 0.0, 0.0)
        for b in ti.static(range(3)):
            channel = ti.static(BENDING_CHANNELS[b])
            v = jet_channel(x, i, channel)
            g = (v - v.dot(n) * n) / length
            d1 = -x2.cross(g)
            d2 = -g.cross(x1)
            if ti.static(not stress_part):
                for k in ti.static(range(3)):
                    jac[i, 3 + b, channel, k] = -n[k]
                    jac[i, 3 + b, jets.D1, k] = d1[k]
                    jac[i, 3 + b, jets.D2, k] = d2[k]
            moment = stress[i, 3 + b]
            v_sum += moment * v
            if ti.static(stress_part):
                _add_block(second, i, channel, jets.D1, -moment * dn1)
                _add_block(second, i, channel, jets.D2, -moment * dn2)
                _add_block(second, i, jets.D1, channel, -moment * dn1.transpose())
                _add_block(second, i, jets.D2, channel, -moment * dn2.transpose())
        if ti.static(stress_part):
            vn = v_sum.dot(n)
            outer = v_sum.outer_product(n)
            eye = ti.Matrix.identity(float, 3)
            f = (-outer - outer.transpose() - vn * eye + 3.0 * vn * n.outer_product(n)) / (
                length * length)
            gx = _cross_matrix((v_sum - vn * n) / length)
            m1 = -_cross_matrix(x2)
            m2 = _cross_matrix(x1)
            _add_block(second, i, jets.D1, jets.D1, stress[i, 0] * eye - m1.transpose() @ f @ m1)
            _add_block(second, i, jets.D2, jets.D2, stress[i, 2] * eye - m2.transpose() @ f @ m2)
            _add_block(second, i, jets.D1, jets.D2,
                       0.5 * stress[i, 1] * eye - m1.transpose() @ f @ m2 + gx)
            _add_block(second, i, jets.D2, jets.D1,
                       0.5 * stress[i, 1] * eye - m2.transpose() @ f @ m1 - gx)


def strain_energy_hessians(material: Material, samples: SurfaceSamples, u_jets: torch.Tensor,
                           *, steps: torch.Tensor, stiffness: torch.Tensor | None = None
                           ) -> torch.Tensor:
    """Per-point Hessian blocks d²E/dU² (N, 6, 3, 6, 3) of the strain energy (module
    docstring), symmetric; zero at point-load samples (weight 0).

    steps: the jet channels' central-difference steps (6,) (`jet_steps`); the strain steps
    are the strain changes they cause: δε = the tangent step × the RMS tangent length,
    δκ = the largest second-derivative step. stiffness: per-sample stiffness (N, K) or None.
    """
    count = len(samples)
    r_all = samples.r_jets
    dtype, device = r_all.dtype, r_all.device
    kernel_stiffness, params = law_inputs(material, count, stiffness, dtype, device)
    active = torch.nonzero(samples.weight != 0).flatten()
    everywhere = active.numel() == count
    if everywhere:
        active = slice(None)
    elif active.numel() == 0:
        return r_all.new_zeros(count, jets.CHANNELS, 3, jets.CHANNELS, 3)
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
    # J first; then the stress part is added to the Gauss–Newton part Jᵀ (d²E/ds²) J in place.
    x = x.contiguous()
    stress = stress.contiguous()
    jac = x.new_zeros(x.shape[0], STRAINS, jets.CHANNELS, 3)
    _strain_derivatives(x, stress, jac, jac, False)
    flat = jac.reshape(-1, STRAINS, jets.CHANNELS * 3)
    blocks = (flat.transpose(1, 2) @ stiffness_s @ flat).reshape(
        -1, jets.CHANNELS, 3, jets.CHANNELS, 3)
    _strain_derivatives(x, stress, jac, blocks, True)
    if everywhere:
        return blocks
    out = r_all.new_zeros(count, jets.CHANNELS, 3, jets.CHANNELS, 3)
    out[active] = blocks
    return out
