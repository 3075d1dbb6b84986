"""The Taichi side of the constitutive laws (`taichi_ndf.shell.materials`, physics.md §3): the
stiffness terms T_k of each law, Ψ = Σ_k S_k T_k for the law's kernel stiffness S. Each law
takes the strains ε, κ and the reference basis a₁, a₂, unit normal a₃ and metric a_αβ at the
sample, and its packed parameters (`Material.law_parameters`).
"""

# No `from __future__ import annotations`: ti.func needs real annotation objects.

from taichi_ndf.runtime import ti
from taichi_ndf.shell.kinematics import contravariant_metric, mat2, vec3

vec4 = ti.math.vec4

# Series terms per η_k in the kernel (shorter series are padded with μ = 0, α = 1).
MAX_SERIES_TERMS = 3
KERNEL_STIFFNESS = 4  # width of the per-sample stiffness array the kernels read


@ti.func
def strain_energy_density(t: vec4, stiffness: ti.template(), i) -> float:
    """Ψ = Σ_k S_k T_k of sample i from the law's terms t and the kernel stiffness (N, 4)."""
    return (stiffness[i, 0] * t[0] + stiffness[i, 1] * t[1] + stiffness[i, 2] * t[2]
            + stiffness[i, 3] * t[3])


@ti.func
def _isotropic_quadratic(strain: mat2, ainv: mat2, nu) -> float:
    """e:H:e = ν (a^{αβ} e_αβ)² + (1 − ν) a^{αγ} a^{βδ} e_αβ e_γδ for symmetric e."""
    mixed = ainv @ strain
    trace = mixed[0, 0] + mixed[1, 1]
    square = mixed @ mixed
    return nu * trace * trace + (1.0 - nu) * (square[0, 0] + square[1, 1])


@ti.func
def linear_isotropic_terms(eps: mat2, kappa: mat2, a1: vec3, a2: vec3, a3: vec3, metric: mat2,
                           params: ti.template()) -> vec4:
    """(½ ε:H:ε, ½ κ:H:κ, 0, 0): Ψ = D T₀ + B T₁. params: [ν]."""
    ainv = contravariant_metric(metric)
    nu = params[0]
    return vec4(0.5 * _isotropic_quadratic(eps, ainv, nu),
                0.5 * _isotropic_quadratic(kappa, ainv, nu), 0.0, 0.0)


@ti.func
def material_frame_transform(a1: vec3, a2: vec3, a3: vec3, metric: mat2) -> mat2:
    """T with T_iα = d_i · a^α (warp d₁ = a₁/|a₁|, weft d₂ = a₃ × d₁, contravariant basis
    a^α = a^{αβ} a_β), so that the material-frame strain components are T e Tᵀ."""
    ainv = contravariant_metric(metric)
    up1 = ainv[0, 0] * a1 + ainv[0, 1] * a2
    up2 = ainv[1, 0] * a1 + ainv[1, 1] * a2
    d1 = a1.normalized()
    d2 = a3.cross(d1)
    return mat2([[d1.dot(up1), d1.dot(up2)], [d2.dot(up1), d2.dot(up2)]])


@ti.func
def _eta(params: ti.template(), k: ti.template(), x):
    """η_k(x), η_k′(x), η_k″(x) of series k from the packed Clyde parameters."""
    value = 0.0
    first = 0.0
    second = 0.0
    for j in ti.static(range(MAX_SERIES_TERMS)):
        mu = params[4 + k * MAX_SERIES_TERMS + j]
        alpha = params[4 + (4 + k) * MAX_SERIES_TERMS + j]
        p = ti.pow(x + 1.0, alpha - 2.0)
        second += mu * (alpha - 1.0) * p
        first += mu * p * (x + 1.0)
        value += mu / alpha * (p * (x + 1.0) * (x + 1.0) - 1.0)
    return value, first, second


@ti.func
def _fabric_terms(e11, e22, e12, params: ti.template(), nonlinear: ti.template()) -> vec4:
    """Membrane terms (½η₁(E₁₁²), η₂(E₁₁E₂₂), ½η₃(E₂₂²), η₄(E₁₂²)) per unit stiffness."""
    terms = vec4(0.5 * e11 * e11, e11 * e22, 0.5 * e22 * e22, e12 * e12)
    if ti.static(nonlinear):
        # Second-order Taylor expansion at the nearest point c of the measured box.
        c11 = ti.min(ti.max(e11, 0.0), params[1])
        c22 = ti.min(ti.max(e22, 0.0), params[2])
        c12 = ti.min(ti.max(e12, -params[3]), params[3])
        d11 = e11 - c11
        d22 = e22 - c22
        d12 = e12 - c12
        v1, f1, s1 = _eta(params, 0, c11 * c11)
        v2, f2, s2 = _eta(params, 1, c11 * c22)
        v3, f3, s3 = _eta(params, 2, c22 * c22)
        v4, f4, s4 = _eta(params, 3, c12 * c12)
        t1 = 0.5 * v1 + c11 * f1 * d11 + 0.5 * (f1 + 2.0 * c11 * c11 * s1) * d11 * d11
        t2 = (v2 + c22 * f2 * d11 + c11 * f2 * d22
              + 0.5 * (c22 * c22 * s2 * d11 * d11 + c11 * c11 * s2 * d22 * d22)
              + (f2 + c11 * c22 * s2) * d11 * d22)
        t3 = 0.5 * v3 + c22 * f3 * d22 + 0.5 * (f3 + 2.0 * c22 * c22 * s3) * d22 * d22
        t4 = v4 + 2.0 * c12 * f4 * d12 + (f4 + 2.0 * c12 * c12 * s4) * d12 * d12
        terms = vec4(t1, t2, t3, t4)
    return terms


@ti.func
def _woven_terms(eps: mat2, kappa: mat2, a1: vec3, a2: vec3, a3: vec3, metric: mat2,
                 params: ti.template(), nonlinear: ti.template(), weft_index: ti.template()
                 ) -> vec4:
    """Simpson's rule through the thickness: (T(−h/2) + 4 T(0) + T(+h/2)) / 6, where the
    material-frame bending strain K = T κ Tᵀ enters as K_ij √(h_i h_j) with the warp and weft
    thicknesses h₁ = params[0], h₂ = params[weft_index] (so that the warp and weft bending
    stiffness are a11 h₁²/12 and a22 h₂²/12; h₁ = h₂ is the plain through-thickness integral).

    Unrolled on purpose: a runtime loop over the three points compiles faster but gave wrong
    reverse-mode gradients (measured, Taichi 1.7.4).
    """
    t = material_frame_transform(a1, a2, a3, metric)
    h1 = params[0]
    h2 = params[weft_index]
    middle = t @ eps @ t.transpose()
    k = t @ kappa @ t.transpose()
    h12 = ti.sqrt(h1 * h2)
    half = 0.5 * mat2([[h1 * k[0, 0], h12 * k[0, 1]], [h12 * k[1, 0], h2 * k[1, 1]]])
    lower = middle - half
    upper = middle + half
    return (_fabric_terms(lower[0, 0], lower[1, 1], lower[0, 1], params, nonlinear)
            + 4.0 * _fabric_terms(middle[0, 0], middle[1, 1], middle[0, 1], params, nonlinear)
            + _fabric_terms(upper[0, 0], upper[1, 1], upper[0, 1], params, nonlinear)) / 6.0


@ti.func
def orthotropic_terms(eps: mat2, kappa: mat2, a1: vec3, a2: vec3, a3: vec3, metric: mat2,
                      params: ti.template()) -> vec4:
    """Orthotropic StVK terms; params: [h₁ (warp), h₂ (weft)]."""
    return _woven_terms(eps, kappa, a1, a2, a3, metric, params, False, 1)


@ti.func
def clyde_terms(eps: mat2, kappa: mat2, a1: vec3, a2: vec3, a3: vec3, metric: mat2,
                params: ti.template()) -> vec4:
    """Clyde terms; params: [h, E11max, E22max, E12max, μ (4×3), α (4×3)] (h₁ = h₂ = h)."""
    return _woven_terms(eps, kappa, a1, a2, a3, metric, params, True, 0)


LAW_TERMS = {
    "linear_isotropic": linear_isotropic_terms,
    "orthotropic": orthotropic_terms,
    "clyde": clyde_terms,
}
