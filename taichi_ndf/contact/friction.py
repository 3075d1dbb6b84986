"""Lagged, smoothed Coulomb friction against the rigid obstacles (IPC, Li et al. 2020 §5).

A dissipative potential over the barrier's quadrature points i and obstacles k:

    D = Σ_ik μ_k λ_ik f₀(|T_ik|),   T_ik = (I − n_ik n_ikᵀ)((x_i − t m_k) − (x⁰_i − t⁰ m_k)),

with, *lagged* (held fixed while Newton minimises, updated between solves by `lag`):
λ_ik [N] the barrier's normal force on the point (κ w √a |b'(g)|), n_ik the obstacle's normal
there, and x⁰_i the point's position at the start of the load step (load factor t⁰; m_k the
obstacle's motion per unit load factor, so T is the displacement relative to the obstacle).
f₀ smooths |T| over the distance ε (μ λ f₁ is the friction force, f₁ = f₀′):

    f₁(y) = 2y/ε − y²/ε²,  f₀(y) = y²/ε − y³/(3ε²)      for y < ε,
    f₁(y) = 1,             f₀(y) = y − ε/3             for y ≥ ε,

(IPC's f₀ less its constant ε/3, so D = 0 without slip). So a point sticks (creeps less than
ε) while the tangential force it carries is below μ λ and slides above it. Hessian blocks
μ λ [f₁′(y) t̂t̂ᵀ + f₁(y)/y (P − t̂t̂ᵀ)] (t̂ = T/|T|, P = I − nnᵀ): both coefficients are ≥ 0,
so the exact blocks are positive semi-definite (the lagged quantities held fixed).
"""

from __future__ import annotations

import torch

from taichi_ndf import jets
from taichi_ndf.contact.barrier import ContactTerm, barrier
from taichi_ndf.problem.sampling import SurfaceSamples


def smoothed_friction(y: torch.Tensor, smoothing: float
                      ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """f₀(y) [m], f₁(y)/y [1/m] and f₁′(y) [1/m] of tangential slips y ≥ 0 (any shape) [m]
    (module docstring; f₁/y and f₁′ are both 2/ε at y = 0)."""
    eps = smoothing
    inside = y < eps
    ys = torch.where(inside, y, torch.full_like(y, eps))  # no division by 0 below
    f0 = torch.where(inside, ys * ys / eps - ys ** 3 / (3 * eps * eps), y - eps / 3)
    f1_over_y = torch.where(inside, 2 / eps - ys / (eps * eps), 1 / y.clamp(min=eps))
    df1 = torch.where(inside, 2 / eps - 2 * ys / (eps * eps), torch.zeros_like(y))
    return f0, f1_over_y, df1


class FrictionTerm:
    """D of the module docstring; the `Term` protocol of `taichi_ndf.objective`.

    contact: the `ContactTerm` whose barrier gives the normal forces; friction: μ per obstacle;
    smoothing: ε [m]. Call `lag` on the samples the term will be evaluated on before use."""

    def __init__(self, contact: ContactTerm, friction: tuple[float, ...], smoothing: float):
        if len(friction) != len(contact.obstacles):
            raise ValueError(f"friction: one coefficient per obstacle ({len(contact.obstacles)})"
                             f", got {len(friction)}")
        if not smoothing > 0:
            raise ValueError(f"friction smoothing must be > 0, got {smoothing!r}")
        self.contact = contact
        self.friction = tuple(float(m) for m in friction)
        self.smoothing = float(smoothing)
        self._lagged: tuple | None = None

    def _motion(self, like: torch.Tensor) -> torch.Tensor:
        return like.new_tensor([o.motion for o in self.contact.obstacles])  # (K, 3)

    def lag(self, samples: SurfaceSamples, u_jets: torch.Tensor, load_factor: float,
            start: torch.Tensor, start_load_factor: float) -> torch.Tensor:
        """Hold the normal forces and normals of the state u_jets (N, 6, 3) [m] at the samples
        and the start-of-step positions `start` (N, 3) [m] (at `start_load_factor`); returns
        the normal forces μ λ (N, K) [N] (friction capacities)."""
        x = samples.r_jets[:, jets.VALUE] + u_jets[:, jets.VALUE]
        gap, normal = self.contact.gaps(x, load_factor)
        _, db, _ = barrier(gap, self.contact.activation)
        force = self.contact.weights(samples)[:, None] * (-db).clamp(min=0)
        capacity = force * force.new_tensor(self.friction)
        reference = start[:, None, :] - start_load_factor * self._motion(start)
        self._lagged = (len(samples), capacity, normal, reference)
        return capacity

    def _slip(self, samples: SurfaceSamples, u_jets: torch.Tensor, load_factor: float):
        if self._lagged is None or self._lagged[0] != len(samples):
            raise ValueError("friction: lag() was not called on these samples")
        _, capacity, normal, reference = self._lagged
        x = samples.r_jets[:, jets.VALUE] + u_jets[:, jets.VALUE]
        relative = x[:, None, :] - load_factor * self._motion(x) - reference  # (N, K, 3)
        tangential = relative - (relative * normal).sum(-1, keepdim=True) * normal
        return capacity, normal, tangential, tangential.norm(dim=-1)

    def evaluate(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                 load_factor: float | torch.Tensor = 1.0, *, grad: bool = True
                 ) -> tuple[float, torch.Tensor | None]:
        """D [J] and dD/du_jets (N, 6, 3) (value channel only)."""
        if isinstance(load_factor, torch.Tensor):
            raise ValueError("friction takes one load factor, not one per sample")
        capacity, _, tangential, y = self._slip(samples, u_jets, load_factor)
        f0, f1_over_y, _ = smoothed_friction(y, self.smoothing)
        value = float((capacity * f0).sum())
        if not grad:
            return value, None
        out = torch.zeros_like(u_jets)
        out[:, jets.VALUE] = ((capacity * f1_over_y)[..., None] * tangential).sum(dim=1)
        return value, out

    def hessian_blocks(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                       load_factor: float = 1.0, *, steps: torch.Tensor | None = None
                       ) -> torch.Tensor:
        """d²D/du_jets² blocks (N, 6, 3, 6, 3) with the lagged quantities fixed, positive
        semi-definite (module docstring), in the value channel. steps: unused."""
        capacity, normal, tangential, y = self._slip(samples, u_jets, load_factor)
        _, f1_over_y, df1 = smoothed_friction(y, self.smoothing)
        eye = torch.eye(3, dtype=u_jets.dtype, device=u_jets.device)
        projector = eye - normal[..., :, None] * normal[..., None, :]
        t = tangential / y.clamp(min=torch.finfo(y.dtype).tiny)[..., None]
        along = t[..., :, None] * t[..., None, :]
        block = capacity[..., None, None] * (df1[..., None, None] * along
                                             + f1_over_y[..., None, None] * (projector - along))
        blocks = u_jets.new_zeros(u_jets.shape[0], jets.CHANNELS, 3, jets.CHANNELS, 3)
        blocks[:, jets.VALUE, :, jets.VALUE, :] = block.sum(dim=1)
        return blocks
