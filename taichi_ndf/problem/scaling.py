"""Dimensional scales of a model, without solving anything: the load per area, the largest
prescribed displacement, and the dimensional estimate of the displacement
(`characteristic_displacement`, from the material's `small_strain_stiffness`), with the
names a scene gives the output-scale estimates of a SIREN field (`SCALE_ESTIMATES`).

The estimates that solve (a linear solve, a coarse nonlinear equilibrium) and the choice
among them at run start are in `taichi_ndf.solve.output_scale` (the solve layer); the contact
barrier's default stiffness takes `load_per_area` (`contact.config`).
"""

from __future__ import annotations

import numpy as np
import torch

from taichi_ndf.boundary import ClampedEdge, Handle, HingedEdge, RimRotation
from taichi_ndf.problem.line_loads import quadrature
from taichi_ndf.problem.model import ShellModel

# output_scale estimates a scene may name: "equilibrium" and "linear" solve at run start
# (`taichi_ndf.solve.output_scale`), each falling back to the cheaper ones after it; "dimensional"
# is `characteristic_displacement`. "auto" is AUTO_ESTIMATE: the equilibrium one, the
# displacement of a coarse projected-Newton solve (docs/scenes.md, "Field output scale":
# measured against the dimensional guess, which is off by up to 260× on a cantilever). A
# longer Adam step (lr × scale) than the dimensional one made flag and napkin_handles diverge;
# the learning-rate backoff (`taichi_ndf.minimise.backoff`) answers that.
SCALE_ESTIMATES = ("auto", "equilibrium", "linear", "dimensional")
AUTO_ESTIMATE = "equilibrium"


def load_per_area(model: ShellModel) -> float:
    """Load per unit area f [N/m²]: |ρ_A g + body force| + |pressure| + (Σ|P_k| + Σ|line load
    resultants|) / L² (point and line loads spread over the surface of size L =
    `model.characteristic_length()`)."""
    length = model.characteristic_length()
    loads = model.loads
    f = float(np.linalg.norm(loads.distributed_force(model.material.areal_density)))
    f += abs(loads.pressure)
    f += sum(float(np.linalg.norm(p.force)) for p in loads.point_loads) / length**2
    _, line_forces = quadrature(model.surface, loads.line_loads, dtype=torch.float64)
    return f + float(line_forces.norm(dim=1).sum()) / length**2


def prescribed_displacement(model: ShellModel) -> float:
    """The largest prescribed displacement [m] of the boundary (a rim rotation counts angle ×
    L/2), 0 without."""
    length = model.characteristic_length()
    prescribed = 0.0
    for c in model.boundary.constraints:
        if isinstance(c, (ClampedEdge, HingedEdge, Handle)):
            prescribed = max(prescribed, float(np.linalg.norm(c.displacement)))
        elif isinstance(c, RimRotation):
            prescribed = max(prescribed, abs(c.angle) * length / 2)
    return prescribed


def characteristic_displacement(model: ShellModel) -> float:
    """Order of magnitude of the displacement [m]: the smaller of the bending estimate
    f L⁴ / (8 B), the membrane estimate (f L⁴ / D)^{1/3} and the size L, where f is the load
    per unit area (point and line loads spread over the surface); at least the largest prescribed
    displacement; 1e-3 L if nothing loads the shell."""
    length = model.characteristic_length()
    d, b = model.material.small_strain_stiffness()
    f = load_per_area(model)
    prescribed = prescribed_displacement(model)
    if f == 0.0:
        return max(prescribed, 1e-3 * length)
    bending = f * length**4 / (8 * b)
    membrane = (f * length**4 / d) ** (1 / 3)
    return max(min(bending, membrane, length), prescribed)

