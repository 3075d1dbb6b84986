"""Energy terms of the objective: the shell's potential energy, the end moment's work, the
stitches of a seam (a term whose Hessian couples pairs of points) and an elastic foundation."""

from __future__ import annotations

import math

import torch

from taichi_ndf import jets
from taichi_ndf.objective.couplings import Couplings
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.sampling import SurfaceSamples
from taichi_ndf.shell.energy import EnergyResult, ShellEnergy
from taichi_ndf.shell.strain_hessian import (
    membrane_second_order_gradient,
    strain_energy_hessians,
    tangent_length,
)


class ShellEnergyTerm:
    """Strain energy and the work of the distributed loads and point forces at a load factor
    (physics.md §4; `ShellEnergy`): the loads and the samples' point forces (carried unscaled,
    `taichi_ndf.problem.sampling`) are scaled by a number, or each sample's work by its own factor
    (N,) for a pseudo-time field. The one place the load factor multiplies the loads.

    stiffness: optional per-sample stiffness (N, K) of a material-conditioned field (fixed
    samples) or None (the material's values)."""

    def __init__(self, material, loads: Loads, *, stiffness: torch.Tensor | None = None):
        self.material = material
        self.loads = loads
        self.stiffness = stiffness

    def result(self, samples: SurfaceSamples, u_jets: torch.Tensor,
               load_factor: float | torch.Tensor = 1.0, *, grad: bool = True) -> EnergyResult:
        """The shell energy's `EnergyResult` (value, parts, density, gradient)."""
        if isinstance(load_factor, torch.Tensor):
            return ShellEnergy(self.material, self.loads).evaluate(
                samples, u_jets, grad=grad, load_factor=load_factor, stiffness=self.stiffness)
        # The one place a number load factor scales the loads: distributed and point forces.
        energy = ShellEnergy(self.material, self.loads.scaled(load_factor))
        if load_factor != 1.0:
            samples = samples.with_point_force(samples.point_force * float(load_factor))
        return energy.evaluate(samples, u_jets, grad=grad, stiffness=self.stiffness)

    def evaluate(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                 load_factor: float | torch.Tensor = 1.0, *, grad: bool = True
                 ) -> tuple[float, torch.Tensor | None]:
        result = self.result(samples, u_jets, load_factor, grad=grad)
        return result.total, result.grad_u_jets

    def tangent_length(self, samples: SurfaceSamples, u_jets: torch.Tensor) -> float:
        """The scale [m] of the strain steps at U = u_jets (`strain_hessian.tangent_length`):
        what `hessian_blocks(tangent=)` takes, computed once per state by a caller that asks
        the blocks chunk by chunk of rows."""
        return tangent_length(samples, u_jets)

    def hessian_blocks(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                       load_factor: float | torch.Tensor = 1.0, *, steps: torch.Tensor,
                       psd: bool = False, rows: slice | None = None,
                       tangent: float | None = None) -> torch.Tensor:
        """Per-point Hessian blocks d²Π/du_jets² (N, 6, 3, 6, 3) through the strains
        (`strain_energy_hessians`; the loads are linear in u: the load factor adds nothing).
        steps (6,): the jet channels' central-difference steps (`jet_steps`). psd: positive
        semi-definite by construction instead (`strain_energy_hessians`' psd). rows: those
        samples' blocks only (n, 6, 3, 6, 3). tangent: `tangent_length` at these samples and
        U (computed here where None)."""
        return strain_energy_hessians(self.material, samples, u_jets, steps=steps,
                                      stiffness=self.stiffness, psd=psd, rows=rows,
                                      tangent=tangent)

    def second_order_gradient(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                              step_jets: torch.Tensor) -> torch.Tensor:
        """The residual of Newton's second-order correction (N, 6, 3): the membrane stress of
        the step's second-order stretch pulled back at U (`membrane_second_order_gradient`)."""
        return membrane_second_order_gradient(self.material, samples, u_jets, step_jets,
                                              stiffness=self.stiffness)


class EndMomentTerm:
    """Conservative moment M [N·m] about +y on the end ξ¹ = max of a strip clamped at ξ¹ = min
    (positive M rolls the free end from +x towards +z): Π_M = −λ M/b ∫∫ θ_,1 dξ¹ dξ² over the
    strip of width b, θ the rotation of the tangent t = x_,1 in the x–z plane, so θ_,1 =
    (t_x t′_z − t_z t′_x)/|t|² with t′ = x_,11 (the roll-up benchmark; the
    `taichi_ndf.validation` docstring says why this rate)."""

    def __init__(self, moment: float, width: float):
        if not (math.isfinite(moment) and math.isfinite(width) and width > 0):
            raise ValueError(f"EndMoment: moment must be finite and width > 0, got "
                             f"{moment!r}, {width!r}")
        self.moment = float(moment)
        self.width = float(width)

    def evaluate(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                 load_factor: float = 1.0, *, grad: bool = True
                 ) -> tuple[float, torch.Tensor | None]:
        """Π_M [J] at the samples and dΠ_M/du_jets (N, 6, 3)."""
        if isinstance(load_factor, torch.Tensor):
            raise ValueError("the end moment takes one load factor, not one per sample")
        u = u_jets.detach().clone().requires_grad_(grad)
        x = samples.r_jets + u
        t, dt = x[:, jets.D1], x[:, jets.D11]
        rate = (t[:, 0] * dt[:, 2] - t[:, 2] * dt[:, 0]) / (t * t).sum(dim=1)
        potential = -(load_factor * self.moment / self.width) * (samples.weight * rate).sum()
        if not grad:
            return float(potential), None
        potential.backward()
        return float(potential.detach()), u.grad

    def end_rotation(self, samples: SurfaceSamples, u_jets: torch.Tensor) -> float:
        """Mean end rotation θ_end [rad] of the strip."""
        energy, _ = self.evaluate(samples, u_jets, 1.0, grad=False)
        return -energy * self.width / self.moment


class StitchTerm:
    """Zero-length springs joining pairs of sample points, the stitches of a seam:
    Π_s = ½ k Σ_p |x_a + u_a − x_b − u_b|², x the rest positions, u the displacements of the
    pair's two points (a_p, b_p), k [N/m] per stitch. Not scaled by the load factor (a seam is
    part of the material, not a load). Its Hessian couples the two points of each stitch
    (`coupled_hessian`; `taichi_ndf.objective.couplings`).

    pairs: (P, 2) int64 row numbers of the stitched points in the samples the term is
    evaluated on (for an `Assembly`, in its own order: `Assembly.order`)."""

    def __init__(self, pairs: torch.Tensor, stiffness: float):
        if pairs.dim() != 2 or pairs.shape[1] != 2 or pairs.dtype != torch.int64:
            raise ValueError(f"StitchTerm: pairs must be (P, 2) int64, got "
                             f"{tuple(pairs.shape)} {pairs.dtype}")
        if not (math.isfinite(stiffness) and stiffness > 0):
            raise ValueError(f"StitchTerm: stiffness must be finite and > 0, got {stiffness!r}")
        self.pairs = pairs
        self.stiffness = float(stiffness)

    def gaps(self, samples: SurfaceSamples, u_jets: torch.Tensor) -> torch.Tensor:
        """x_a + u_a − x_b − u_b (P, 3) [m] of every stitch."""
        x = samples.r_jets[:, jets.VALUE] + u_jets[:, jets.VALUE]
        return x[self.pairs[:, 0]] - x[self.pairs[:, 1]]

    def evaluate(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                 load_factor: float | torch.Tensor = 1.0, *, grad: bool = True
                 ) -> tuple[float, torch.Tensor | None]:
        """Π_s [J] and dΠ_s/du_jets (N, 6, 3)."""
        gap = self.gaps(samples, u_jets)
        value = 0.5 * self.stiffness * float((gap * gap).sum())
        if not grad:
            return value, None
        gradient = torch.zeros_like(u_jets)
        force = self.stiffness * gap.to(u_jets.dtype)
        gradient[:, jets.VALUE].index_add_(0, self.pairs[:, 0], force)
        gradient[:, jets.VALUE].index_add_(0, self.pairs[:, 1], -force)
        return value, gradient

    def coupled_hessian(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                        load_factor: float | torch.Tensor = 1.0) -> Couplings:
        """The stitches' pair blocks: k [[I, −I], [−I, I]] on the two value channels (exact:
        Π_s is quadratic)."""
        count = self.pairs.shape[0]
        blocks = u_jets.new_zeros(count, 2, jets.CHANNELS, 3, 2, jets.CHANNELS, 3)
        eye = self.stiffness * torch.eye(3, dtype=u_jets.dtype, device=u_jets.device)
        for a in range(2):
            for b in range(2):
                blocks[:, a, jets.VALUE, :, b, jets.VALUE, :] = eye if a == b else -eye
        return Couplings(self.pairs, blocks.reshape(count, 2 * 3 * jets.CHANNELS,
                                                    2 * 3 * jets.CHANNELS))


class FoundationTerm:
    """An elastic (Winkler) foundation: springs anchoring every point of the surface to its
    rest position, Π_f = ½ k ∫ |u|² dA = ½ k Σ w √a |u|² over the samples (w the parameter-area
    weights, √a the reference area element), k [N/m³] the foundation modulus (pressure per
    displacement). Not scaled by the load factor (a support, not a load). A flat plate with
    free edges under a uniform pressure p settles by the translation u = p/k along the
    normal: the strains stay zero."""

    def __init__(self, stiffness: float):
        if not (math.isfinite(stiffness) and stiffness > 0):
            raise ValueError(f"FoundationTerm: stiffness must be finite and > 0, got "
                             f"{stiffness!r}")
        self.stiffness = float(stiffness)

    def _density(self, samples: SurfaceSamples, dtype: torch.dtype) -> torch.Tensor:
        """k w √a (N,) [N/m]: each sample's spring constant."""
        r = samples.r_jets
        sqrt_a = torch.linalg.cross(r[:, jets.D1], r[:, jets.D2], dim=-1).norm(dim=-1)
        return (self.stiffness * samples.weight * sqrt_a).to(dtype)

    def evaluate(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                 load_factor: float | torch.Tensor = 1.0, *, grad: bool = True
                 ) -> tuple[float, torch.Tensor | None]:
        """Π_f [J] and dΠ_f/du_jets (N, 6, 3)."""
        spring = self._density(samples, u_jets.dtype)
        u = u_jets[:, jets.VALUE]
        value = 0.5 * float((spring * (u * u).sum(dim=1)).sum())
        if not grad:
            return value, None
        gradient = torch.zeros_like(u_jets)
        gradient[:, jets.VALUE] = spring[:, None] * u
        return value, gradient

    def hessian_blocks(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                       load_factor: float | torch.Tensor = 1.0, *,
                       steps: torch.Tensor | None = None) -> torch.Tensor:
        """Per-point blocks (N, 6, 3, 6, 3): k w √a I on the value channel (exact: Π_f is
        quadratic)."""
        n = u_jets.shape[0]
        blocks = u_jets.new_zeros(n, jets.CHANNELS, 3, jets.CHANNELS, 3)
        eye = torch.eye(3, dtype=u_jets.dtype, device=u_jets.device)
        blocks[:, jets.VALUE, :, jets.VALUE, :] = self._density(samples, u_jets.dtype)[:, None,
                                                                                        None] * eye
        return blocks
