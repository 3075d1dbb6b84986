"""Per-point Hessian blocks of the shell's strain energy through its strains.

At a sample the strain energy E = w √a Ψ(s) depends on the displacement jets U (6 channels × 3
components) only through the six strains s = (ε₁₁, ε₁₂, ε₂₂, κ₁₁, κ₁₂, κ₂₂) (physics.md §2–3;
every law reads the reference geometry, which U does not change). So

    d²E/dU² = Jᵀ (d²E/ds²) J + Σ_s (dE/ds) d²s/dU²,       J = ds/dU (6 × 18),

a Gauss–Newton part and a stress part. The kinematic derivatives are exact (below); dE/ds is
the Taichi-autodiff gradient of a kernel that evaluates the law on given strains (the same
`LAW_TERMS` and `strain_energy_density` as the energy kernel), and d²E/ds² (6 × 6) differences
of that gradient: for the quadratic laws (`QUADRATIC_LAWS`), whose gradient is affine in s,
one-sided differences with unit steps (`_affine_law_hessian`, exact up to rounding); with the
material's own stiffness at s = 0, the same at every state, so computed once per sample set,
chunk of rows and material and kept while the sample set lives, for the last material asked
(`_quadratic_law_hessian`: Newton's later iterates launch the law kernel once, for dE/ds),
with a per-sample stiffness at
the state; for the Clyde law central differences at two steps, Richardson-extrapolated
(`_law_hessian`: 25 launches; truncation ~step⁴) — in place of the 36 full energy gradients of
`sample_hessians`. The external
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

Positive semi-definite by construction (`psd`, projected Newton's "strain" treatment): the
law Hessian's negative eigenvalues clamped (a batched 6 × 6 `eigh`), the membrane stress part
Σ_αβ (dE/dε_αβ) d²ε_αβ/dU² = S ⊗ I₃ on (x₁, x₂) with the 2 × 2 stress S = [[σ₁₁, ½σ₁₂],
[½σ₁₂, σ₂₂]] clamped to S₊ (tension-field: compressive membrane stress dropped), and the
bending stress part (moments × d²κ/dU², small in a thin shell) left out: no per-block screen
or 18 × 18 eigen-decomposition.

The membrane strains are quadratic in U, so a step ΔU changes them by exactly
ε(U + ΔU) − ε(U) = (dε/dU) ΔU + ε₂, ε₂_αβ = ½ ΔU_,α·ΔU_,β (sym.): the second-order stretch that
a straight Newton step puts into a nearly inextensible sheet. `membrane_second_order_gradient`
pulls the stress it causes, Δσ = dE/dε(s + ε₂) − dE/dε(s), back through dε/dU at U — the
residual of Newton's second-order correction (`taichi_ndf.minimise.line_search`).
"""

# No `from __future__ import annotations`: this module defines Taichi kernels.

import functools

import torch
from torch.utils.weak import WeakIdKeyDictionary

from taichi_ndf import jets
from taichi_ndf.problem.sampling import SurfaceSamples
from taichi_ndf.runtime import ti
from taichi_ndf.shell.energy import law_inputs
from taichi_ndf.shell.kinematics import jet_channel, mat2, reference_geometry, strains, vec3
from taichi_ndf.shell.law_terms import LAW_TERMS, strain_energy_density
from taichi_ndf.shell.materials import Material

mat3 = ti.math.mat3
STRAINS = 6  # ε₁₁, ε₁₂, ε₂₂, κ₁₁, κ₁₂, κ₂₂
CHUNK = 4096  # points per batched product Jᵀ (S J): its temporaries are the chunk's
BENDING_CHANNELS = (jets.D11, jets.D12, jets.D22)
# Laws whose Ψ is a quadratic form in the strains (law_terms.py: linear isotropic, orthotropic
# StVK): their law gradient is affine in s.
QUADRATIC_LAWS = frozenset({"linear_isotropic", "orthotropic"})
# Their law Hessians d²E/ds² per sample set (held weakly by its reference jets r_jets: the entry
# goes with them): {rows: (material, the samples' weights, (n, 6, 6))}, the last material asked
# for each chunk of rows only (`_quadratic_law_hessian`).
_QUADRATIC_LAW_HESSIANS = WeakIdKeyDictionary()


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


def _strain_gradient(kernel, r, strain, *, weight, stiffness, params) -> torch.Tensor:
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


def _law_hessian(gradient, strain: torch.Tensor, delta_e: float, delta_k: float
                 ) -> torch.Tensor:
    """d²E/ds² (N, 6, 6), symmetrised, of a law that is not quadratic (the Clyde law) from its
    gradient dE/ds (`gradient(s)` at strains s (N, 6)) with steps δε (membrane) and δκ
    (bending): central differences at δ and δ/2, Richardson-extrapolated (truncation ~δ⁴, 24
    evaluations)."""
    out = strain.new_empty(strain.shape[0], STRAINS, STRAINS)
    for j in range(STRAINS):
        delta = delta_e if j < 3 else delta_k

        def central(h, j=j):
            shifted = strain.clone()
            shifted[:, j] += h
            plus = gradient(shifted)
            shifted[:, j] -= 2 * h
            return (plus - gradient(shifted)) / (2 * h)

        out[:, :, j] = (4 * central(0.5 * delta) - central(delta)) / 3
    return 0.5 * (out + out.transpose(1, 2))


def _affine_law_hessian(gradient, strain: torch.Tensor, stress: torch.Tensor) -> torch.Tensor:
    """A quadratic law's d²E/ds² (N, 6, 6), symmetrised, from its gradient dE/ds (`gradient(s)`
    at strains s (N, 6); stress: its value at `strain`): the gradient is affine in s, so
    one-sided differences with unit steps (a unit membrane strain, a curvature of 1/m) are exact
    up to rounding (6 evaluations)."""
    out = strain.new_empty(strain.shape[0], STRAINS, STRAINS)
    for j in range(STRAINS):
        shifted = strain.clone()
        shifted[:, j] += 1.0
        out[:, :, j] = gradient(shifted) - stress
    return 0.5 * (out + out.transpose(1, 2))


def _quadratic_law_hessian(material: Material, samples: SurfaceSamples, rows: slice | None,
                           gradient, count: int) -> torch.Tensor:
    """A quadratic law's d²E/ds² (count, 6, 6) at the `count` points of weight ≠ 0 among
    `rows` of `samples` (`gradient`: its law gradient at those points): differences at rest,
    s = 0 (`_affine_law_hessian`: the same numbers whatever the state), computed on the first
    ask for this sample set (its r_jets), rows, weights and material, then kept with the
    sample set (`_QUADRATIC_LAW_HESSIANS`) and returned as it is. One material per sample set
    and rows: another material's ask replaces it (a material fit's many materials are not
    accumulated; Newton's iterates ask with one). Only for the material's own stiffness (a
    per-sample stiffness: at the state, every time)."""
    kept = _QUADRATIC_LAW_HESSIANS.setdefault(samples.r_jets, {})
    key = None if rows is None else (rows.start, rows.stop)
    held, weights, hessian = kept.get(key, (None, None, None))
    if weights is not samples.weight or held != material:
        rest = samples.r_jets.new_zeros(count, STRAINS)
        hessian = _affine_law_hessian(gradient, rest, gradient(rest))
        kept[key] = (material, samples.weight, hessian)
    return hessian


def _clamped(matrices: torch.Tensor) -> torch.Tensor:
    """Symmetric matrices (N, m, m) with their negative eigenvalues set to 0: 2 × 2 in closed
    form, larger ones by `eigh` of those a batched Cholesky (shifted by 1e-12 of the mean
    diagonal) finds indefinite."""
    if matrices.shape[1] == 2:
        a, b, c = matrices[:, 0, 0], matrices[:, 0, 1], matrices[:, 1, 1]
        mean, radius = 0.5 * (a + c), torch.sqrt((0.5 * (a - c))**2 + b * b)
        high, low = mean + radius, mean - radius
        eye = torch.eye(2, dtype=matrices.dtype, device=matrices.device)
        # one positive eigenvalue: high × the projector (A − low I)/(high − low) on its vector
        rank_one = (high / (high - low).clamp_min(torch.finfo(matrices.dtype).tiny))[
            :, None, None] * (matrices - low[:, None, None] * eye)
        out = torch.where((low < 0)[:, None, None], rank_one, matrices)
        return torch.where((high <= 0)[:, None, None], torch.zeros_like(matrices), out)
    diagonal = matrices.diagonal(dim1=1, dim2=2)
    shift = 1e-12 * diagonal.abs().mean(dim=1).clamp_min(torch.finfo(matrices.dtype).tiny)
    _, info = torch.linalg.cholesky_ex(matrices + shift[:, None, None] * torch.eye(
        matrices.shape[1], dtype=matrices.dtype, device=matrices.device))
    bad = torch.nonzero(info != 0).flatten()
    if bad.numel() == 0:
        return matrices
    values, vectors = torch.linalg.eigh(matrices[bad])
    out = matrices.clone()
    out[bad] = (vectors * values.clamp_min(0.0)[:, None, :]) @ vectors.transpose(1, 2)
    return out


def _strain_vector(r: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """The six strains s (N, 6) = (ε₁₁, ε₁₂, ε₂₂, κ₁₁, κ₁₂, κ₂₂) at jets r, u (N, 6, 3)."""
    eps, kappa, _ = strains(r, u)
    return torch.stack((eps[:, 0, 0], eps[:, 0, 1], eps[:, 1, 1],
                        kappa[:, 0, 0], kappa[:, 0, 1], kappa[:, 1, 1]), dim=1)


def membrane_second_order_gradient(material: Material, samples: SurfaceSamples,
                                   u_jets: torch.Tensor, step_jets: torch.Tensor, *,
                                   stiffness: torch.Tensor | None = None) -> torch.Tensor:
    """dE/dU (N, 6, 3) [J per unit of the jets] of the membrane stress that a step's
    second-order membrane strain causes (module docstring): Σ_αβ Δσ_αβ dε_αβ/dU at U = u_jets,
    Δσ = dE/dε(s + ε₂) − dE/dε(s) (bending strains unchanged), ε₂_αβ = ½ ΔU_,α·ΔU_,β of the
    step ΔU = step_jets (N, 6, 3) [m]; zero at point-load samples (weight 0). stiffness:
    per-sample stiffness (N, K) or None."""
    r_all = samples.r_jets
    out = torch.zeros_like(r_all)
    active = torch.nonzero(samples.weight != 0).flatten()
    if active.numel() == 0:
        return out
    r = r_all[active].contiguous()
    u = u_jets.detach().to(r.dtype)[active]
    du = step_jets.detach().to(r.dtype)[active]
    strain = _strain_vector(r, u)
    d1, d2 = du[:, jets.D1], du[:, jets.D2]
    second = torch.zeros_like(strain)
    second[:, 0], second[:, 1], second[:, 2] = (
        0.5 * (d1 * d1).sum(1), 0.5 * (d1 * d2).sum(1), 0.5 * (d2 * d2).sum(1))
    kernel_stiffness, params = law_inputs(material, len(samples), stiffness, r.dtype, r.device)
    gradient = functools.partial(_strain_gradient, _law_kernel(material.law), r,
                                 weight=samples.weight[active].contiguous(),
                                 stiffness=kernel_stiffness[active].contiguous(), params=params)
    stress = gradient((strain + second).contiguous()) - gradient(strain)
    x = r + u
    x1, x2 = x[:, jets.D1], x[:, jets.D2]  # dε₁₁/dx₁ = x₁, dε₁₂/dx_α = ½ x_β, dε₂₂/dx₂ = x₂
    out[active, jets.D1] = stress[:, 0, None] * x1 + 0.5 * stress[:, 1, None] * x2
    out[active, jets.D2] = 0.5 * stress[:, 1, None] * x1 + stress[:, 2, None] * x2
    return out


def tangent_length(samples: SurfaceSamples, u_jets: torch.Tensor) -> float:
    """The RMS length [m] of the deformed tangents x_,1, x_,2 over the samples of weight ≠ 0
    (0 where none): the scale of the membrane strain steps (`strain_energy_hessians`)."""
    active = torch.nonzero(samples.weight != 0).flatten()
    if active.numel() == 0:
        return 0.0
    if int(active[-1]) == active.numel() - 1:
        active = slice(0, active.numel())
    x = samples.r_jets[active].contiguous() + u_jets.detach().to(samples.r_jets.dtype)[active]
    return float(x[:, jets.D1:jets.D2 + 1].pow(2).sum(2).mean().sqrt())


def strain_energy_hessians(material: Material, samples: SurfaceSamples, u_jets: torch.Tensor,
                           *, steps: torch.Tensor, stiffness: torch.Tensor | None = None,
                           psd: bool = False, rows: slice | None = None,
                           tangent: float | None = None) -> torch.Tensor:
    """Per-point Hessian blocks d²E/dU² (N, 6, 3, 6, 3) of the strain energy (module
    docstring), symmetric; zero at point-load samples (weight 0).

    steps: the jet channels' central-difference steps (6,) (`jet_steps`); the strain steps
    are the strain changes they cause: δε = the tangent step × the RMS tangent length (over
    all the samples), δκ = the largest second-derivative step. stiffness: per-sample
    stiffness (N, K) or None. psd: the positive semi-definite blocks of the strain treatment
    instead (module docstring). rows: only the blocks of these samples (n, 6, 3, 6, 3) (a
    chunk), the same as those rows of all samples' blocks. tangent: the RMS tangent length
    [m] of all the samples (`tangent_length`), computed here where None; a caller that asks
    chunk by chunk of rows at one U computes it once and passes it to every chunk (it costs
    a pass over all samples: per chunk, O(N² / chunk)).
    """
    if tangent is None:
        tangent = tangent_length(samples, u_jets)  # of all samples, also for a chunk of rows
    whole = samples
    if rows is not None:
        samples = SurfaceSamples(*(None if t is None else t[rows] for t in (
            samples.xi, samples.r_jets, samples.weight, samples.point_force,
            samples.barrier_weight)))
        u_jets = u_jets[rows]
        stiffness = None if stiffness is None else stiffness[rows]
    count = len(samples)
    r_all = samples.r_jets
    dtype, device = r_all.dtype, r_all.device
    kernel_stiffness, params = law_inputs(material, count, stiffness, dtype, device)
    active = torch.nonzero(samples.weight != 0).flatten()
    if active.numel() == 0:
        return r_all.new_zeros(count, jets.CHANNELS, 3, jets.CHANNELS, 3)
    if int(active[-1]) == active.numel() - 1:  # the first points (the assembly's order puts
        active = slice(0, active.numel())  # point loads last): views, blocks written in place
    r = r_all[active].contiguous()
    u = u_jets.detach().to(dtype)[active]
    x = r + u
    strain = _strain_vector(r, u)
    weight = samples.weight[active].contiguous()
    kstiff = kernel_stiffness[active].contiguous()
    kernel = _law_kernel(material.law)
    stress = _strain_gradient(kernel, r, strain, weight=weight, stiffness=kstiff, params=params)
    gradient = functools.partial(_strain_gradient, kernel, r, weight=weight, stiffness=kstiff,
                                 params=params)
    if material.law not in QUADRATIC_LAWS:
        delta_e = float(steps[jets.D1:jets.D2 + 1].max()) * tangent
        delta_k = float(steps[jets.D11:].max())
        stiffness_s = _law_hessian(gradient, strain, delta_e, delta_k)
    elif stiffness is None:  # the material's own stiffness: the same at every state
        stiffness_s = _quadratic_law_hessian(material, whole, rows, gradient, strain.shape[0])
    else:  # a per-sample stiffness: at this state
        stiffness_s = _affine_law_hessian(gradient, strain, stress)
    if psd:
        stiffness_s = _clamped(stiffness_s)
    # J first; then the stress part is added to the Gauss–Newton part Jᵀ (d²E/ds²) J in place.
    x = x.contiguous()
    stress = stress.contiguous()
    jac = x.new_zeros(x.shape[0], STRAINS, jets.CHANNELS, 3)
    _strain_derivatives(x, stress, jac, jac, False)
    flat = jac.reshape(-1, STRAINS, jets.CHANNELS * 3)
    out = r_all.new_zeros(count, jets.CHANNELS, 3, jets.CHANNELS, 3)
    blocks = out[active] if isinstance(active, slice) else out.new_empty(x.shape[0],
                                                                         *out.shape[1:])
    square = blocks.view(-1, jets.CHANNELS * 3, jets.CHANNELS * 3)
    # S J first, then a contiguous Jᵀ: 17 against 32 ms as Jᵀ S J (12 544 points, loaded core)
    for start in range(0, flat.shape[0], CHUNK):
        c = slice(start, start + CHUNK)
        torch.bmm(flat[c].transpose(1, 2).contiguous(), torch.bmm(stiffness_s[c], flat[c]),
                  out=square[c])
    if psd:
        membrane = torch.stack((stress[:, 0], 0.5 * stress[:, 1], 0.5 * stress[:, 1],
                                stress[:, 2]), dim=1).reshape(-1, 2, 2)
        eye = torch.eye(3, dtype=dtype, device=device)
        tangents = slice(jets.D1, jets.D2 + 1)
        blocks[:, tangents, :, tangents, :] += _clamped(membrane)[:, :, None, :, None] * eye[
            None, None, :, None, :]
    else:
        _strain_derivatives(x, stress, jac, blocks, True)
    if not isinstance(active, slice):
        out[active] = blocks
    return out
