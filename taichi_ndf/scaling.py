"""Dimensional estimate of a scene's displacement, used to scale the field's output.

The field's raw output is O(1) at initialisation-scale weights; multiplying it by a
characteristic displacement keeps Adam's step sizes meaningful across scenes whose
displacements differ by orders of magnitude (a pinched cylinder moves 1e-5, a napkin 1 m).
The estimate needs only the order of magnitude.
"""

from __future__ import annotations

import numpy as np
import torch

from taichi_ndf.boundary import ClampedEdge, Handle, HingedEdge, RimRotation
from taichi_ndf.line_loads import quadrature
from taichi_ndf.model import ShellModel
from taichi_ndf.shell.materials import ClydeFabric, LinearIsotropic, OrthotropicStVK


def membrane_and_bending_stiffness(material) -> tuple[float, float]:
    """Representative (D [N/m], B [N·m]) of any material law at small strain."""
    if isinstance(material, ClydeFabric):
        material = material.small_strain()
    if isinstance(material, LinearIsotropic):
        return material.membrane_stiffness, material.bending_stiffness
    if isinstance(material, OrthotropicStVK):
        d = 0.5 * (material.a11 + material.a22)
        return d, d * material.thickness**2 / 12
    raise TypeError(f"unknown material type {type(material).__name__}")


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


def characteristic_displacement(model: ShellModel) -> float:
    """Order of magnitude of the displacement [m]: the smaller of the bending estimate
    f L⁴ / (8 B), the membrane estimate (f L⁴ / D)^{1/3} and the size L, where f is the load
    per unit area (point and line loads spread over the surface); at least the largest prescribed
    displacement; 1e-3 L if nothing loads the shell."""
    length = model.characteristic_length()
    d, b = membrane_and_bending_stiffness(model.material)
    f = load_per_area(model)
    prescribed = 0.0
    for c in model.boundary.constraints:
        if isinstance(c, (ClampedEdge, HingedEdge, Handle)):
            prescribed = max(prescribed, float(np.linalg.norm(c.displacement)))
        elif isinstance(c, RimRotation):
            prescribed = max(prescribed, abs(c.angle) * length / 2)
    if f == 0.0:
        return max(prescribed, 1e-3 * length)
    bending = f * length**4 / (8 * b)
    membrane = (f * length**4 / d) ** (1 / 3)
    return max(min(bending, membrane, length), prescribed)

