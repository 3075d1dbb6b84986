"""Total potential energy Π of the shell and its gradient (physics.md §4).

    Π = Σ_i w_i √a_i (Ψ_i − λ_i f_i·u_i) − Σ_i λ_i P_i·u_i,     f_i = ρ_A g + b + p a₃(ξ_i)

over the samples of a `SurfaceSamples` set (area samples with weight w, point-load samples with
weight 0 and force P); λ_i is a per-sample load factor, 1 unless given (a pseudo-time field
draws one per sample). One Taichi kernel per constitutive law computes the per-sample terms;
Taichi reverse-mode autodiff of that kernel gives dΠ/du_jets.
"""

# No `from __future__ import annotations`: this module defines Taichi kernels.

import functools
from collections.abc import Callable
from dataclasses import dataclass

import torch

from taichi_ndf import jets
from taichi_ndf.geometry import ReferenceSurface
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.sampling import SurfaceSamples, sample_surface
from taichi_ndf.runtime import ti
from taichi_ndf.shell.kinematics import (
    bending_strain,
    deformed_geometry,
    jet_channel,
    membrane_strain,
    reference_geometry,
    strains,
    vec3,
)
from taichi_ndf.shell.law_terms import KERNEL_STIFFNESS, LAW_TERMS, strain_energy_density
from taichi_ndf.shell.materials import Material


@functools.cache
def _energy_kernel(law: str):
    """The per-sample energy kernel of one constitutive law (compiled on first use)."""
    law_terms = LAW_TERMS[law]

    @ti.kernel
    def energy(r: ti.types.ndarray(), u: ti.types.ndarray(), weight: ti.types.ndarray(),
               point_force: ti.types.ndarray(), stiffness: ti.types.ndarray(),
               params: ti.types.ndarray(), load: ti.types.ndarray(),
               load_factor: ti.types.ndarray(), internal: ti.types.ndarray(),
               external: ti.types.ndarray(),
               density: ti.types.ndarray(), sqrt_a: ti.types.ndarray(),
               terms: ti.types.ndarray()):
        for i in range(r.shape[0]):
            u0 = jet_channel(u, i, jets.VALUE)
            lam = load_factor[i]
            work = lam * u0.dot(vec3(point_force[i, 0], point_force[i, 1], point_force[i, 2]))
            w = weight[i]
            # Point-load samples (w = 0) may sit where √a = 0: never evaluate Ψ there.
            if w != 0.0:
                a1, a2, a3, metric, curvature, area_element = reference_geometry(r, i)
                _, _, _, metric_bar, curvature_bar, _ = deformed_geometry(r, u, i)
                t = law_terms(membrane_strain(metric, metric_bar),
                              bending_strain(curvature, curvature_bar),
                              a1, a2, a3, metric, params)
                psi = strain_energy_density(t, stiffness, i)
                f = lam * (vec3(load[0], load[1], load[2]) + load[3] * a3)
                area = w * area_element
                internal[i] = area * psi
                work += area * f.dot(u0)
                density[i] = psi
                sqrt_a[i] = area_element
                for k in ti.static(range(KERNEL_STIFFNESS)):
                    terms[i, k] = area * t[k]
            external[i] = -work

    return energy


def law_inputs(material: Material, n: int, stiffness: torch.Tensor | None, dtype, device
               ) -> tuple[torch.Tensor, torch.Tensor]:
    """The law's kernel stiffness (n, 4) and packed parameters for n samples.

    stiffness: per-sample stiffness (n, K) in the order of `material.stiffness_names`, or None
    (the material's values at every sample)."""
    if stiffness is None:
        stiffness = torch.tensor(material.stiffness, dtype=dtype, device=device).expand(n, -1)
    elif stiffness.shape != (n, len(material.stiffness_names)):
        raise ValueError(f"stiffness must have shape ({n}, {len(material.stiffness_names)}) "
                         f"for {material.stiffness_names}, got {tuple(stiffness.shape)}")
    kernel_stiffness = material.law_stiffness(stiffness.to(dtype)).contiguous()
    params = torch.tensor(material.law_parameters(), dtype=dtype, device=device)
    return kernel_stiffness, params


@dataclass
class EnergyResult:
    """Π and its parts on a sample set.

    total = internal + external [J]; internal = Σ w √a Ψ; external = −Σ w √a f·u − Σ P·u.
    density: strain energy density Ψ per sample [J/m²] (0 at point-load samples), shape (N,).
    sqrt_a: reference area element per sample (0 at point-load samples), shape (N,).
    stiffness_terms: E_k with internal = Σ_k s_k E_k for the material's stiffness values s_k
        (order of `material.stiffness_names`; uniform stiffness only) — Π is linear in them.
    grad_u_jets: dΠ/du_jets, shape (N, 6, 3) [J/m per unit ξ^order], or None.
    """

    total: float
    internal: float
    external: float
    density: torch.Tensor
    sqrt_a: torch.Tensor
    stiffness_terms: tuple[float, ...]
    grad_u_jets: torch.Tensor | None


class ShellEnergy:
    """Potential energy of a shell of a given material under given loads."""

    def __init__(self, material: Material, loads: Loads):
        if not isinstance(material, Material):
            raise TypeError(f"material must be a taichi_ndf material, got {type(material)}")
        if not isinstance(loads, Loads):
            raise TypeError(f"loads must be a taichi_ndf.problem.loads.Loads, got {type(loads)}")
        self.material = material
        self.loads = loads

    def evaluate(self, samples: SurfaceSamples, u_jets: torch.Tensor, *, grad: bool = True,
                 stiffness: torch.Tensor | None = None,
                 load_factor: torch.Tensor | None = None) -> EnergyResult:
        """Π of the displacement jets u_jets (N, 6, 3) [m] at the samples.

        grad: also compute dΠ/du_jets (Taichi reverse-mode autodiff).
        stiffness: optional per-sample stiffness (N, K) in the order of
            `material.stiffness_names` (e.g. for a material-conditioned field); default: the
            material's values at every sample.
        load_factor: optional per-sample factor (N,) on the external work of that sample (its
            distributed load and its point force), e.g. the pseudo-time t of a sample of a
            pseudo-time field; default: 1 at every sample (the loads as given).
        """
        n = len(samples)
        if u_jets.shape != (n, jets.CHANNELS, 3):
            raise ValueError(f"u_jets must have shape ({n}, 6, 3), got {tuple(u_jets.shape)}")
        r = samples.r_jets.contiguous()
        dtype, device = r.dtype, r.device
        material = self.material
        kernel_stiffness, params = law_inputs(material, n, stiffness, dtype, device)
        if load_factor is None:
            load_factor = torch.ones(n, dtype=dtype, device=device)
        elif load_factor.shape != (n,):
            raise ValueError(f"load_factor must have shape ({n},), got "
                             f"{tuple(load_factor.shape)}")
        load_factor = load_factor.detach().to(dtype=dtype, device=device).contiguous()
        load = torch.tensor([*self.loads.distributed_force(material.areal_density),
                             self.loads.pressure], dtype=dtype, device=device)
        u = u_jets.detach().to(dtype).contiguous().requires_grad_(grad)
        internal = torch.zeros(n, dtype=dtype, device=device, requires_grad=grad)
        external = torch.zeros(n, dtype=dtype, device=device, requires_grad=grad)
        if grad:  # set before the forward launch, which would otherwise allocate them too
            u.grad = torch.zeros_like(u)
            internal.grad = torch.ones_like(internal)
            external.grad = torch.ones_like(external)
        density = torch.zeros(n, dtype=dtype, device=device)
        sqrt_a = torch.zeros(n, dtype=dtype, device=device)
        terms = torch.zeros(n, KERNEL_STIFFNESS, dtype=dtype, device=device)
        args = (r, u, samples.weight.contiguous(), samples.point_force.contiguous(),
                kernel_stiffness, params, load, load_factor, internal, external, density, sqrt_a,
                terms)
        kernel = _energy_kernel(material.law)
        if n:
            kernel(*args)
            if grad:
                kernel.grad(*args)
        internal_total = float(internal.detach().sum())
        external_total = float(external.detach().sum())
        return EnergyResult(
            total=internal_total + external_total,
            internal=internal_total,
            external=external_total,
            density=density,
            sqrt_a=sqrt_a,
            stiffness_terms=self._stiffness_terms(terms),
            grad_u_jets=u.grad if grad else None,
        )

    def _stiffness_terms(self, terms: torch.Tensor) -> tuple[float, ...]:
        """Per-parameter energies E_k with internal = Σ_k s_k E_k (uniform stiffness)."""
        unit = torch.eye(len(self.material.stiffness_names), dtype=terms.dtype,
                         device=terms.device)
        per_parameter = self.material.law_stiffness(unit)  # (K, 4): kernel stiffness of s_k = 1
        return tuple(float(v) for v in terms.sum(dim=0) @ per_parameter.T)


def function_jets(fn: Callable[[torch.Tensor], torch.Tensor], xi: torch.Tensor) -> torch.Tensor:
    """Jets (N, 6, C) of a smooth torch function ξ (N, 2) -> (N, C), by torch autograd.

    For analytic displacement (or position) fields in examples and tests; the function must be
    twice differentiable with torch operations.
    """
    xi = xi.detach().clone().requires_grad_(True)
    value = fn(xi)
    if value.dim() != 2 or value.shape[0] != xi.shape[0]:
        raise ValueError(f"fn must map ξ (N, 2) to (N, C), got shape {tuple(value.shape)}")
    out = xi.new_zeros(xi.shape[0], jets.CHANNELS, value.shape[1])
    out[:, jets.VALUE] = value.detach()
    for c in range(value.shape[1]):
        if not value.requires_grad:
            break
        (first,) = torch.autograd.grad(value[:, c].sum(), xi, create_graph=True,
                                       allow_unused=True, materialize_grads=True)
        out[:, jets.D1, c] = first[:, 0].detach()
        out[:, jets.D2, c] = first[:, 1].detach()
        if first.requires_grad:
            (d1,) = torch.autograd.grad(first[:, 0].sum(), xi, retain_graph=True,
                                        allow_unused=True, materialize_grads=True)
            (d2,) = torch.autograd.grad(first[:, 1].sum(), xi, retain_graph=True,
                                        allow_unused=True, materialize_grads=True)
            out[:, jets.D11, c] = d1[:, 0]
            out[:, jets.D12, c] = d1[:, 1]
            out[:, jets.D22, c] = d2[:, 1]
    return out


@dataclass
class PotentialEnergy:
    """Π of an explicit displacement field and the fields it is made of.

    total, internal, external: Π and its parts [J] (see `EnergyResult`).
    samples: the samples used.
    displacement: u at the samples, shape (N, 3) [m].
    membrane_strain: ε_αβ, shape (N, 2, 2); bending_strain: κ_αβ, shape (N, 2, 2)
        (covariant components in the surface coordinates).
    density: Ψ [J/m²], shape (N,) (0 at point-load samples).
    """

    total: float
    internal: float
    external: float
    samples: SurfaceSamples
    displacement: torch.Tensor
    membrane_strain: torch.Tensor
    bending_strain: torch.Tensor
    density: torch.Tensor


def potential_energy(
    surface: ReferenceSurface,
    material: Material,
    loads: Loads,
    displacement: Callable[[torch.Tensor], torch.Tensor] | torch.Tensor,
    *,
    samples: SurfaceSamples | None = None,
    n: int = 16384,
    generator: torch.Generator | None = None,
) -> PotentialEnergy:
    """Evaluate Π, strains and energy density of a given displacement, without a solver.

    displacement: one of
        - a function ξ (N, 2) -> displacement jets (N, 6, 3) [m] (channels u, u_,1, u_,2,
          u_,11, u_,12, u_,22), e.g. a field's jets with boundary conditions applied;
        - a function ξ (N, 2) -> displacement u (N, 3) [m] written with torch operations, whose
          derivatives are taken by autograd (`function_jets`);
        - a tensor of jets (N, 6, 3) at the given `samples`.
    samples: where to evaluate; default: `sample_surface(surface, n, loads, generator)`.
    """
    if samples is None:
        if not callable(displacement):
            raise ValueError("displacement jets given as a tensor need the samples they belong to")
        samples = sample_surface(surface, n, loads, generator)
    if callable(displacement):
        u_jets = displacement(samples.xi)
        if u_jets.dim() == 2:
            u_jets = function_jets(displacement, samples.xi)
    else:
        u_jets = displacement
    u_jets = u_jets.detach().to(samples.r_jets.dtype)
    result = ShellEnergy(material, loads).evaluate(samples, u_jets, grad=False)
    eps, kappa, _ = strains(samples.r_jets, u_jets)
    return PotentialEnergy(
        total=result.total,
        internal=result.internal,
        external=result.external,
        samples=samples,
        displacement=u_jets[:, jets.VALUE],
        membrane_strain=eps,
        bending_strain=kappa,
        density=result.density,
    )
