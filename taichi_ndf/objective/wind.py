"""The wind's force over one time step as an energy term: the drag law (`problem.wind`)
linearised in the cloth's velocity about the step's start, on the normals of the step's start.

Per point q (weight w_q of parameter area, deformed area element |x_,1 × x_,2| at the start)
the force over the step is f_q = (p₀ − dp/ds (v'_q − v₀_q)·n_q) n_q da_q with p₀, dp/ds the
pressure and its slope at the start's relative normal velocity s₀ = (w − v₀)·n_q: a constant
part F_q = (p₀ + dp/ds v₀·n) n da and a drag on the new normal velocity −c_q (v'·n) n,
c_q = dp/ds da [N·s/m]. The scheme's new velocity is affine in the step's end,
v' = k (x − y) (k [1/s] and y [m] from the integrator's `StepMap`), so the force is the
negative gradient of

    E = −Σ_q F_q·u_q + ½ Σ_q k c_q ((u_q − y_q)·n_q)²   [J],

a per-point term (value channel) whose Hessian k c_q n_q n_qᵀ is positive semi-definite: the
drag is implicit in the velocity (stable at any step), the normals and the drag's slope are
lagged (explicit) over the step. Not a potential of the motion (the wind does work; E is
only the step's): T + Π of a run with wind is not conserved.
"""

from __future__ import annotations

import torch

from taichi_ndf import jets
from taichi_ndf.problem.sampling import SurfaceSamples
from taichi_ndf.problem.wind import Wind


class WindTerm:
    """E = −Σ F_q·u_q + ½ Σ κ_q ((u_q − y_q)·n_q)² [J] (module docstring).

    force: F_q (N, 3) [N]; stiffness: κ_q = k c_q (N,) [N/m] ≥ 0; normal: n_q (N, 3), unit;
    origin: y (N, 6, 3) [m] jets (only the value channel is read). Rows beyond the given
    points (e.g. contact check points appended to a round's samples) carry no force. Not
    scaled by the load factor (the wind has its own time law)."""

    def __init__(self, force: torch.Tensor, stiffness: torch.Tensor, normal: torch.Tensor,
                 origin: torch.Tensor):
        count = force.shape[0]
        if force.shape != (count, 3) or stiffness.shape != (count,) or \
                normal.shape != (count, 3) or origin.shape[1:] != (jets.CHANNELS, 3) or \
                origin.shape[0] < count:
            raise ValueError(f"WindTerm: force (N, 3), stiffness (N,), normal (N, 3) and origin "
                             f"(M >= N, 6, 3), got {tuple(force.shape)}, "
                             f"{tuple(stiffness.shape)}, {tuple(normal.shape)}, "
                             f"{tuple(origin.shape)}")
        if bool((stiffness < 0).any()):
            raise ValueError("WindTerm: stiffness must be >= 0")
        self.force, self.stiffness, self.normal, self.origin = force, stiffness, normal, origin

    def _parts(self, u_jets: torch.Tensor):
        n = self.force.shape[0]
        if u_jets.shape[0] != self.origin.shape[0]:
            raise ValueError(f"WindTerm: {u_jets.shape[0]} points, but the origin has "
                             f"{self.origin.shape[0]}")
        u = u_jets[:n, jets.VALUE]
        normal = self.normal.to(u.dtype)
        along = ((u - self.origin[:n, jets.VALUE].to(u.dtype)) * normal).sum(dim=1)
        return u, normal, along

    def evaluate(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                 load_factor: float | torch.Tensor = 1.0, *, grad: bool = True
                 ) -> tuple[float, torch.Tensor | None]:
        """E [J] and dE/du_jets (N, 6, 3) [N]."""
        u, normal, along = self._parts(u_jets)
        stiffness, force = self.stiffness.to(u.dtype), self.force.to(u.dtype)
        value = float(-(force * u).sum() + 0.5 * (stiffness * along * along).sum())
        if not grad:
            return value, None
        gradient = torch.zeros_like(u_jets)
        gradient[:len(u), jets.VALUE] = -force + (stiffness * along)[:, None] * normal
        return value, gradient

    def hessian_blocks(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                       load_factor: float | torch.Tensor = 1.0, *,
                       steps: torch.Tensor | None = None, rows: slice | None = None
                       ) -> torch.Tensor:
        """κ_q n_q n_qᵀ on the value channel (N, 6, 3, 6, 3) (exact: E is quadratic); rows:
        only those points' blocks (n, 6, 3, 6, 3)."""
        _, normal, _ = self._parts(u_jets)
        points = torch.arange(u_jets.shape[0], device=u_jets.device)
        points = points if rows is None else points[rows]
        acting = points < len(normal)  # the wind acts on the first len(normal) points
        at = points[acting]
        blocks = u_jets.new_zeros(len(points), jets.CHANNELS, 3, jets.CHANNELS, 3)
        blocks[acting, jets.VALUE, :, jets.VALUE, :] = (
            self.stiffness.to(u_jets.dtype)[at, None, None] * normal[at, :, None]
            * normal[at, None, :])
        return blocks


def wind_term(wind: Wind, t: float, samples: SurfaceSamples, u_jets: torch.Tensor,
              velocity: torch.Tensor, rate: float, origin: torch.Tensor) -> WindTerm:
    """The step's `WindTerm` from the state at its start: the air at w(t) (t [s], the step's
    end), displacement jets u (N, 6, 3) [m] and velocities v₀ (N, 3) [m/s] at the samples
    (normals n = x_,1 × x_,2 / |…| and the deformed area da = |x_,1 × x_,2| w_q of the
    start), the scheme's k = rate [1/s] and y = origin (M ≥ N, 6, 3) [m] (v' = k (x − y))."""
    x = samples.r_jets.to(u_jets.dtype) + u_jets
    cross = torch.linalg.cross(x[:, jets.D1], x[:, jets.D2], dim=-1)
    length = cross.norm(dim=1)
    normal = cross / length[:, None]
    area = length * samples.weight.to(u_jets.dtype)
    air = torch.tensor(wind.at(t), dtype=u_jets.dtype)
    along = (velocity * normal).sum(dim=1)
    pressure, slope = wind.pressure(((air - velocity) * normal).sum(dim=1))
    force = ((pressure + slope * along) * area)[:, None] * normal
    return WindTerm(force, rate * slope * area, normal, origin)
